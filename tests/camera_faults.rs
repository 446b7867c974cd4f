//! Camera faults at 8 s: a +0.04 m bias (the ECC fault) and a freeze. The learners take the
//! camera's weight away and the arm still reaches its target.

mod common;

use aift::scenario::Method;
use common::{run_recorded, setup};

#[test]
fn camera_bias_loses_the_camera_its_weight_and_the_arm_reaches() {
    let s = setup("paper_camera_bias.toml", &[]);
    for method in [Method::PlAlways, Method::Bayes, Method::Window] {
        let (r, _) = run_recorded(&s, method, 1, None);
        let cam = r.final_health[4].max(r.final_health[5]);
        eprintln!(
            "{method}: camera health {:.3} / {:.3}, final error {:.4}, MSE {:?}",
            r.final_health[4], r.final_health[5], r.max_final_error, r.mse_per_joint
        );
        assert!(cam < 0.1, "{method}: camera health {cam}");
        assert!(r.max_final_error <= 0.02, "{method}: {}", r.max_final_error);
    }
}

#[test]
fn camera_freeze_recovers_like_an_encoder_freeze() {
    let s = setup("paper_camera_freeze.toml", &[]);
    for method in [
        Method::PlAlways,
        Method::Bayes,
        Method::Window,
        Method::Oracle,
    ] {
        let (r, _) = run_recorded(&s, method, 1, None);
        let worst = r.mse_per_joint.iter().copied().fold(0.0, f64::max);
        eprintln!(
            "{method}: camera health {:.2e} / {:.2e}, final error {:.4}, worst-joint MSE {worst:.3e}",
            r.final_health[4], r.final_health[5], r.max_final_error
        );
        assert!(r.max_final_error <= 0.02, "{method}: {}", r.max_final_error);
        assert!(worst <= 1e-5, "{method}: {worst}");
    }
}
