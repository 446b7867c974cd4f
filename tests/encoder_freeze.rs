//! Joint-1 encoder frozen at 8 s while the arm moves (target switch at 7.5 s): every method
//! against the oracle, on the paper arm and on the 3-DOF arm.

mod common;

use std::sync::OnceLock;

use aift::precision::Calibration;
use aift::scenario::calibrate::calibrate;
use aift::scenario::{Method, RunResult, RunSetup};
use common::{at, min_between, run_recorded, setup};

fn paper() -> &'static (RunSetup, Calibration) {
    static SETUP: OnceLock<(RunSetup, Calibration)> = OnceLock::new();
    SETUP.get_or_init(|| {
        let s = setup("paper_encoder_freeze.toml", &[]);
        let cal = calibrate(&s, 50).unwrap();
        (s, cal)
    })
}

fn oracle() -> &'static RunResult {
    static ORACLE: OnceLock<RunResult> = OnceLock::new();
    ORACLE.get_or_init(|| run_recorded(&paper().0, Method::Oracle, 1, None).0)
}

/// The recovery measure: reaches the second target within 0.02 rad, faulty-joint MSE <= 1e-5,
/// every channel but encoder 1 above half health over the last 5 s.
fn assert_recovers(method: Method) {
    let (s, cal) = paper();
    let (r, rec) = run_recorded(s, method, 1, Some(cal));
    let faulty = r.mse_faulty.unwrap();
    eprintln!(
        "{method}: faulty MSE {faulty:.3e} ({:.2} x oracle), healthy {:.3e}, final error {:.4}, detected {:?}",
        faulty / oracle().mse_faulty.unwrap(),
        r.mse_healthy.unwrap(),
        r.max_final_error,
        r.detected_at
    );
    assert!(
        r.max_final_error <= 0.02,
        "{method}: final error {}",
        r.max_final_error
    );
    assert!(faulty <= 1e-5, "{method}: faulty MSE {faulty}");
    for name in ["enc2", "tach1", "tach2", "cam_u", "cam_v"] {
        let h = min_between(&rec, &format!("health_{name}"), 15.0, 20.0);
        assert!(
            h > 0.5,
            "{method}: {name} health fell to {h} in the last 5 s"
        );
    }
}

#[test]
fn pl_always_recovers_and_blames_only_the_frozen_encoder() {
    assert_recovers(Method::PlAlways);
    let (r, rec) = run_recorded(&paper().0, Method::PlAlways, 1, None);
    assert!(
        r.final_health[0] < 0.01,
        "enc1 health {}",
        r.final_health[0]
    );
    for name in ["enc2", "tach1", "tach2", "cam_u", "cam_v"] {
        let h = min_between(&rec, &format!("health_{name}"), 0.0, 20.0);
        assert!(h > 0.5, "{name} health fell to {h}");
    }
    assert_eq!(r.isolated_channel.as_deref(), Some("enc1"));
}

#[test]
fn pl_detect_recovers() {
    assert_recovers(Method::PlDetect);
}

#[test]
fn bayes_recovers() {
    assert_recovers(Method::Bayes);
}

#[test]
fn window_recovers() {
    assert_recovers(Method::Window);
}

#[test]
fn deterministic_isolates_encoder_1_within_a_tenth_of_a_second() {
    let (s, cal) = paper();
    let (r, _) = run_recorded(s, Method::Deterministic, 1, Some(cal));
    let delay = r.detected_at.unwrap() - 8.0;
    eprintln!(
        "deterministic: isolated {:?} {delay:.3} s after the freeze, faulty MSE {:.3e}",
        r.isolated_channel,
        r.mse_faulty.unwrap()
    );
    assert_eq!(r.isolated_channel.as_deref(), Some("enc1"));
    assert!((0.0..=0.1).contains(&delay), "delay {delay}");
    assert_eq!(r.final_health[0], 0.0);
    assert!(r.max_final_error <= 0.02);
}

#[test]
fn without_fault_tolerance_the_arm_does_not_reach() {
    let (r, _) = run_recorded(&paper().0, Method::NoFt, 1, None);
    let faulty = r.mse_faulty.unwrap();
    eprintln!(
        "no-ft: final error {:.3}, faulty MSE {faulty:.3e} ({:.0} x oracle)",
        r.max_final_error,
        faulty / oracle().mse_faulty.unwrap()
    );
    assert!(r.max_final_error >= 0.05 || faulty >= 1e-3);
}

#[test]
fn the_oracle_zeroes_encoder_1_at_the_fault_and_recovers() {
    let (s, _) = paper();
    let (r, rec) = run_recorded(s, Method::Oracle, 1, None);
    assert_eq!(at(&rec, "precision_enc1", 7.999), 1e6);
    assert_eq!(at(&rec, "precision_enc1", 8.001), 0.0);
    assert!(r.max_final_error <= 0.02 && r.mse_faulty.unwrap() <= 1e-5);
}

/// pl-always reaches the final target and drops encoder 1; no-ft does not reach.
fn assert_other_arm_recovers(file: &str) {
    let s = setup(file, &[]);
    let (r, rec) = run_recorded(&s, Method::PlAlways, 1, None);
    eprintln!(
        "{file} pl-always: final errors {:?}, MSE {:?}",
        r.final_error_per_joint, r.mse_per_joint
    );
    assert!(r.max_final_error <= 0.02, "{:?}", r.final_error_per_joint);
    assert!(r.mse_faulty.unwrap() <= 1e-5);
    assert!(at(&rec, "health_enc1", 19.9) < 0.01);
    let (no_ft, _) = run_recorded(&s, Method::NoFt, 1, None);
    assert!(no_ft.max_final_error >= 0.05 || no_ft.mse_faulty.unwrap() >= 1e-3);
}

#[test]
fn three_dof_arm_reaches_its_target_after_its_encoder_freezes() {
    assert_other_arm_recovers("planar3_encoder_freeze.toml");
}

#[test]
fn spatial_arm_with_an_off_axis_camera_recovers_from_a_yaw_encoder_freeze() {
    assert_other_arm_recovers("spatial3_encoder_freeze.toml");
}
