//! Healthy reaching on the paper arm: the u-AIC reaches each target, its belief tracks the truth,
//! and the calibrated detector stays quiet on fresh healthy seeds.

mod common;

use aift::scenario::Method;
use aift::scenario::calibrate::calibrate;
use aift::scenario::table::run_table;
use common::{at, run_recorded, setup};

#[test]
fn reaches_each_target_with_an_accurate_belief() {
    let s = setup("paper_healthy.toml", &[]);
    for method in [
        Method::NoFt,
        Method::PlAlways,
        Method::Bayes,
        Method::Window,
    ] {
        let (r, rec) = run_recorded(&s, method, 1, None);
        assert_eq!(r.outcome.name(), "completed");
        // Each target held at the end of its segment: 7.5 s and 20 s.
        for (t, target) in [(7.499, [-0.2, 0.5]), (19.999, [-0.6, 0.2])] {
            for j in 0..2 {
                let q = at(&rec, &format!("q{}", j + 1), t);
                assert!(
                    (q - target[j]).abs() <= 0.01,
                    "{method}: joint {} at {t} s is {q}, target {}",
                    j + 1,
                    target[j]
                );
            }
        }
        for (j, mse) in r.mse_per_joint.iter().enumerate() {
            eprintln!("{method}: joint {} belief MSE {mse:.3e}", j + 1);
            assert!(*mse <= 1e-7, "{method}: joint {} MSE {mse}", j + 1);
        }
    }
}

#[test]
fn no_false_alarm_in_20_fresh_healthy_seeds() {
    let s = setup("paper_healthy.toml", &[]);
    let cal = calibrate(&s, 50).unwrap();
    let seeds: Vec<u64> = (100..120).collect();
    let table = run_table(&s, &[Method::Deterministic], &seeds, Some(&cal), &|| {}).unwrap();
    let alarms: Vec<_> = table.runs.iter().filter(|r| r.false_alarm).collect();
    let peak = table
        .runs
        .iter()
        .map(|r| r.mse_per_joint[0])
        .fold(0.0, f64::max);
    eprintln!(
        "false alarms: {} of 20; largest joint-1 MSE {peak:.2e}",
        alarms.len()
    );
    assert!(
        alarms.is_empty(),
        "{:?}",
        alarms
            .iter()
            .map(|r| (r.seed, r.detected_at))
            .collect::<Vec<_>>()
    );
}
