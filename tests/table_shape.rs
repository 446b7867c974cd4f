//! The shape of the paper's Table 1 over 10 seeds: no fault tolerance fails, precision learning
//! and the deterministic baseline recover; where bayes and window land, each against the oracle.

mod common;

use aift::scenario::Method;
use aift::scenario::calibrate::calibrate;
use aift::scenario::table::run_table;
use common::setup;

#[test]
fn table_1_shape_on_10_seeds() {
    let s = setup("paper_encoder_freeze.toml", &[]);
    let cal = calibrate(&s, 50).unwrap();
    let seeds: Vec<u64> = (1..=10).collect();
    let table = run_table(&s, &Method::ALL, &seeds, Some(&cal), &|| {}).unwrap();
    let row = |m: Method| table.rows.iter().find(|r| r.method == Some(m)).unwrap();
    for r in &table.rows {
        eprintln!(
            "{:14} faulty {:.3e} healthy {:.3e} x oracle {:.2} diverged {}",
            r.name,
            r.mse_faulty_mean.unwrap(),
            r.mse_healthy_mean.unwrap(),
            r.ratio_to_oracle.unwrap(),
            r.diverged
        );
        assert_eq!(r.seeds, 10);
        assert_eq!(r.false_alarms, 0, "{}", r.name);
    }
    assert!(row(Method::NoFt).mse_faulty_mean.unwrap() >= 1e-3);
    for m in [Method::PlAlways, Method::PlDetect, Method::Deterministic] {
        assert!(row(m).mse_faulty_mean.unwrap() <= 1e-5, "{m}");
        assert_eq!(row(m).diverged, 0, "{m}");
    }
    // Measured, not prescribed: bayes and window recover too, within a small factor of the oracle.
    for m in [Method::Bayes, Method::Window] {
        let ratio = row(m).ratio_to_oracle.unwrap();
        assert!(ratio.is_finite() && ratio < 100.0, "{m}: {ratio} x oracle");
    }
}
