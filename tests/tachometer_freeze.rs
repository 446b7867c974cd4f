//! A frozen tachometer: the open case (docs/method.md, "Studies"). Measured, not solved: the learners
//! blame the healthy encoder and camera. What holds, and is checked here: no fault tolerance
//! survives it, and recovery needs the coupled prediction (even the oracle fails without it).

mod common;

use aift::scenario::Method;
use common::{run_recorded, setup};

#[test]
fn the_oracle_recovers_only_with_the_coupled_prediction() {
    let coupled = setup(
        "paper_tachometer_freeze.toml",
        &["controller.prediction=\"coupled\""],
    );
    let paper = setup(
        "paper_tachometer_freeze.toml",
        &["controller.prediction=\"paper\""],
    );
    let (c, _) = run_recorded(&coupled, Method::Oracle, 1, None);
    let (p, _) = run_recorded(&paper, Method::Oracle, 1, None);
    eprintln!(
        "oracle, tachometer-1 freeze: coupled MSE {:.2e} final {:.4}; paper MSE {:.2e} final {:.4}",
        c.mse_faulty.unwrap(),
        c.max_final_error,
        p.mse_faulty.unwrap(),
        p.max_final_error
    );
    assert!(c.mse_faulty.unwrap() <= 1e-5 && c.max_final_error <= 0.02);
    assert!(p.mse_faulty.unwrap() > 100.0 * c.mse_faulty.unwrap());
}

#[test]
fn no_fault_tolerance_survives_and_every_method_returns_a_result() {
    let s = setup("paper_tachometer_freeze.toml", &[]);
    let (no_ft, _) = run_recorded(&s, Method::NoFt, 1, None);
    assert!(no_ft.max_final_error < 0.1, "{}", no_ft.max_final_error);
    for m in [Method::PlAlways, Method::Bayes, Method::Window] {
        let (r, _) = run_recorded(&s, m, 1, None);
        eprintln!(
            "{m}: outcome {}, faulty MSE {:.2e}, final error {:.3}, health {:?}",
            r.outcome.name(),
            r.mse_faulty.unwrap(),
            r.max_final_error,
            r.final_health
        );
        assert!(r.mse_per_joint.iter().all(|v| v.is_finite()));
    }
}
