//! Camera faults at 8 s: a +0.04 m bias (the ECC fault) and a freeze. The learners take the
//! camera's weight away and the arm still reaches its target.

mod common;

use aift::scenario::Method;
use aift::scenario::calibrate::calibrate;
use common::{min_between, run_recorded, setup};

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
    let cal = calibrate(&s, 50).unwrap();
    for method in [
        Method::PlAlways,
        Method::PlDetect,
        Method::Deterministic,
        Method::Bayes,
        Method::Window,
        Method::Oracle,
    ] {
        let (r, rec) = run_recorded(&s, method, 1, Some(&cal));
        let worst = r.mse_per_joint.iter().copied().fold(0.0, f64::max);
        eprintln!(
            "{method}: camera health {:.2e} / {:.2e}, final error {:.4}, worst-joint MSE {worst:.3e}",
            r.final_health[4], r.final_health[5], r.max_final_error
        );
        assert!(r.max_final_error <= 0.02, "{method}: {}", r.max_final_error);
        assert!(worst <= 1e-5, "{method}: {worst}");
        // The channels that did not fail keep their weight over the last 5 s.
        for name in ["enc1", "enc2", "tach1", "tach2"] {
            let h = min_between(&rec, &format!("health_{name}"), 15.0, 20.0);
            assert!(h > 0.5, "{method}: {name} health fell to {h}");
        }
    }
}
