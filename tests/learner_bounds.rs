//! Long healthy runs: no learner drifts. Over 200 s every channel's precision stays within
//! [0.5, 1] x nominal, for every method (the detector methods with a 16-run calibration: they
//! must not false-alarm either).

mod common;

use aift::scenario::Method;
use common::{run_recorded, setup};

#[test]
fn precisions_stay_within_half_and_full_nominal_over_200_s() {
    let s = setup("paper_healthy.toml", &["duration=200.0"]);
    let cal = aift::scenario::calibrate::calibrate(&s, 16).unwrap();
    let methods = Method::ALL;
    std::thread::scope(|scope| {
        let handles: Vec<_> = methods
            .iter()
            .map(|&m| {
                let (s, cal) = (&s, &cal);
                scope.spawn(move || {
                    let (r, rec) = run_recorded(s, m, 3, Some(cal));
                    assert_eq!(r.outcome.name(), "completed");
                    let mut lowest = (f64::INFINITY, String::new());
                    for name in rec.header.iter().filter(|h| h.starts_with("health_")) {
                        let low = rec
                            .series(name)
                            .unwrap()
                            .into_iter()
                            .fold(f64::INFINITY, f64::min);
                        if low < lowest.0 {
                            lowest = (low, name.clone());
                        }
                        let p = rec.series(&name.replace("health_", "precision_")).unwrap();
                        let nominal = p[0];
                        assert!(
                            p.iter().all(|w| *w <= nominal * (1.0 + 1e-12)),
                            "{m}: {name} above nominal"
                        );
                    }
                    eprintln!(
                        "{m}: lowest health over 200 s {:.3} ({})",
                        lowest.0, lowest.1
                    );
                    assert!(lowest.0 >= 0.5, "{m}: {} fell to {}", lowest.1, lowest.0);
                })
            })
            .collect();
        for h in handles {
            h.join().unwrap();
        }
    });
}
