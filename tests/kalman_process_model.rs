//! The Kalman baselines with the arm's dynamics as their transition model
//! (`kalman.process_model = "dynamics"`, the model the hybrid's bank uses): a hard start on the
//! low-damping spatial arm that the constant-velocity `ekf-gate` loses, kept by all three
//! baselines with the model.

mod common;

use aift::scenario::Method;
use common::{repo, run_recorded};

/// The low-damping spatial arm reaching, from its start, the healthy reaching benchmark's task 6
/// (`assets/campaigns/reaching.toml`): the first tick asks joint 3 for about 800 rad/s^2.
fn hard_start(overrides: &[&str]) -> aift::scenario::RunSetup {
    let text = std::fs::read_to_string(repo("assets/scenarios/spatial3low_healthy.toml"))
        .unwrap()
        .replace("../../urdf/", &format!("{}/", repo("urdf").display()));
    let first = text.find("[[targets]]").expect("the template has targets");
    let camera = text.find("[camera]").expect("the template has a camera");
    let text = format!(
        "{}[[targets]]\ntime = 0.0\nq = [-0.1911377836074838, -1.417529397155611, 1.167179702605133]\n\n{}",
        &text[..first],
        &text[camera..]
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hard_start.toml");
    std::fs::write(&path, text).unwrap();
    let mut all = vec![
        "plant.engine=\"articulated\"".to_string(),
        "duration=4.0".to_string(),
    ];
    all.extend(overrides.iter().map(|s| s.to_string()));
    let loaded = aift::scenario::LoadedScenario::from_file(&path, &all).unwrap();
    aift::scenario::RunSetup::prepare(loaded).unwrap()
}

#[test]
fn the_arm_model_keeps_the_kalman_baselines_through_a_hard_start() {
    // Constant velocity: the gate takes the tachometer's jump for a fault (tick 2), then the
    // encoder, and the belief of joint 3 is lost for a second.
    let s = hard_start(&[]);
    let (r, _) = run_recorded(&s, Method::EkfGate, 1, None);
    eprintln!(
        "ekf-gate, constant velocity: belief MSE {:?}, {} alarms",
        r.mse_per_joint, r.false_alarms
    );
    assert!(r.mse_per_joint[2] > 1e-4, "{:?}", r.mse_per_joint);
    assert!(r.false_alarms > 0);

    let s = hard_start(&["kalman.process_model=\"dynamics\""]);
    let (no_ft, _) = run_recorded(&s, Method::NoFt, 1, None);
    for method in [Method::EkfGate, Method::VbAkf, Method::Imm] {
        let (r, _) = run_recorded(&s, method, 1, None);
        eprintln!(
            "{method}, dynamics: belief MSE {:?}, {} alarms, final error {:?}",
            r.mse_per_joint, r.false_alarms, r.final_error_per_joint
        );
        assert_eq!(r.outcome.name(), "completed");
        for (j, mse) in r.mse_per_joint.iter().enumerate() {
            assert!(*mse < 1e-7, "{method}: joint {} belief MSE {mse}", j + 1);
        }
        assert_eq!(r.false_alarms, 0, "{method}: {:?}", r.detections);
        // The motion is the controller's: the same final error as without fault tolerance.
        assert!(
            (r.max_final_error - no_ft.max_final_error).abs() < 1e-3,
            "{method}: {:?} against no-FT's {:?}",
            r.final_error_per_joint,
            no_ft.final_error_per_joint
        );
    }
}
