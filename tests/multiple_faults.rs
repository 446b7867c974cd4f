//! Several faults per run, each with its own channels, start and end: the oracle follows each
//! fault's window, the detector raises an alarm per fault (the same group again once it has
//! re-admitted the channel), and the metrics are reported per fault.

mod common;

use aift::scenario::Method;
use aift::scenario::calibrate::calibrate;
use common::{at, run_recorded};

/// The healthy paper scenario with the given faults appended (TOML snippets).
fn with_faults(faults: &[&str], duration: f64) -> aift::scenario::RunSetup {
    let duration = format!("duration={duration}");
    common::with_faults(
        "paper_healthy.toml",
        faults,
        &[duration.as_str(), "name=\"two_faults\""],
    )
}

const ENC1_FREEZE: &str = r#"[[faults]]
channel = "enc1"
kind = "freeze"
start = 8.0
end = 12.0"#;

const CAM_BIAS: &str = r#"[[faults]]
channel = "cam"
kind = "bias"
offset = 0.04
start = 10.0
end = 14.0"#;

#[test]
fn the_oracle_follows_each_faults_window_and_readmits_the_channels() {
    let s = with_faults(&[ENC1_FREEZE, CAM_BIAS], 18.0);
    let (r, rec) = run_recorded(&s, Method::Oracle, 1, None);
    for (t, enc1, cam) in [
        (7.9, 1.0, 1.0),
        (9.0, 0.0, 1.0),
        (11.0, 0.0, 0.0),
        (13.0, 1.0, 0.0),
        (15.0, 1.0, 1.0),
    ] {
        assert_eq!(at(&rec, "health_enc1", t), enc1, "enc1 at {t} s");
        assert_eq!(at(&rec, "health_cam_u", t), cam, "cam_u at {t} s");
        assert_eq!(at(&rec, "health_cam_v", t), cam, "cam_v at {t} s");
    }
    assert_eq!(r.final_health, vec![1.0; 6]);
    assert!(r.max_final_error < 0.01, "{}", r.max_final_error);
    // Per-fault metrics: one entry per fault, in file order.
    assert_eq!(r.faults.len(), 2);
    assert_eq!(r.faults[0].label, "enc1");
    assert_eq!(r.faults[0].joints, vec![0]);
    assert_eq!(r.faults[1].label, "cam");
    assert_eq!(r.faults[1].kind, "bias");
    assert!(r.faults[1].joints.is_empty());
    for f in &r.faults {
        let mse = f.mse_during.unwrap();
        assert!(mse.is_finite() && mse < 1e-5, "{f:?}");
    }
    // The single-fault summaries stay: faulty joint 1, post-fault MSE from 8 s.
    assert_eq!(r.faulty_joints, vec![0]);
    assert!(r.mse_post_fault_per_joint.is_some());
}

#[test]
fn the_detector_alarms_again_after_it_readmits_a_channel() {
    // An intermittent encoder bias, twice: the deterministic method isolates encoder 1, re-admits
    // it once its innovation has been quiet for a second, and isolates it again.
    let first =
        "[[faults]]\nchannel = \"enc1\"\nkind = \"bias\"\noffset = 0.05\nstart = 8.0\nend = 9.0";
    let second =
        "[[faults]]\nchannel = \"enc1\"\nkind = \"bias\"\noffset = 0.05\nstart = 13.0\nend = 14.0";
    let s = with_faults(&[first, second], 16.0);
    let cal = calibrate(&s, 50).unwrap();
    let (r, rec) = run_recorded(&s, Method::Deterministic, 1, Some(&cal));
    eprintln!(
        "detections: {:?}",
        r.detections
            .iter()
            .map(|d| (d.t, d.channels.clone()))
            .collect::<Vec<_>>()
    );
    for f in &r.faults {
        eprintln!("{f:?}");
    }
    assert!(r.detections.len() >= 2, "{:?}", r.detections);
    for f in &r.faults {
        assert_eq!(f.isolated.as_deref(), Some("enc1"), "{f:?}");
        assert_eq!(f.isolation_correct, Some(true));
        assert!(f.delay.unwrap() < 0.05, "{f:?}");
    }
    // Encoder 1 is back in use between the faults and after the second.
    assert_eq!(at(&rec, "health_enc1", 8.5), 0.0);
    assert_eq!(at(&rec, "health_enc1", 12.0), 1.0);
    assert_eq!(at(&rec, "health_enc1", 13.5), 0.0);
    assert_eq!(at(&rec, "health_enc1", 15.9), 1.0);
    assert_eq!(r.false_alarms, 0);
    assert!(r.max_final_error < 0.01, "{}", r.max_final_error);
}
