//! Sensor groups come from the layout: with a three-output position tracker instead of the
//! two-output camera, the GP, the u-AIC, the detector, the learners, the trajectory columns and
//! the plots all follow, with nothing outside `sensors/` changed.

mod common;

use aift::scenario::Method;
use aift::scenario::calibrate::calibrate;
use aift::sensors::{CameraModel, SensorGroup};
use common::{run_recorded, setup};

#[test]
fn a_three_output_tracker_runs_through_every_stage() {
    let s = setup("paper_encoder_freeze.toml", &["camera.model=\"position\""]);
    assert_eq!(s.layout.camera_model(), CameraModel::Position);
    assert_eq!(s.layout.len(), 7);
    assert_eq!(s.layout.group_range(SensorGroup::Camera), 4..7);
    assert_eq!(s.gp.n_outputs, 3);
    assert_eq!(
        s.layout.names(),
        ["enc1", "enc2", "tach1", "tach2", "cam_x", "cam_y", "cam_z"]
    );
    let cal = calibrate(&s, 10).unwrap();
    assert_eq!(cal.groups[2].channels, vec![4, 5, 6]);
    for method in [Method::PlAlways, Method::Deterministic, Method::Oracle] {
        let (r, rec) = run_recorded(&s, method, 1, Some(&cal));
        eprintln!(
            "{method}: faulty MSE {:.2e}, final error {:.4}, isolated {:?}",
            r.mse_faulty.unwrap(),
            r.max_final_error,
            r.isolated_channel
        );
        assert_eq!(r.final_health.len(), 7);
        for column in ["y_cam_z", "health_cam_y", "precision_cam_x", "d_cam"] {
            assert!(rec.column(column).is_some(), "{column}");
        }
        assert!(r.max_final_error < 0.02, "{method}: {}", r.max_final_error);
        if method != Method::Oracle {
            assert_eq!(r.isolated_channel.as_deref(), Some("enc1"), "{method}");
        }
    }
    // A fault on the whole camera group hits its three channels.
    let s = setup(
        "paper_camera_freeze.toml",
        &["camera.model=\"position\"", "duration=12.0"],
    );
    assert_eq!(s.faults[0].channels, vec![4, 5, 6]);
}

#[test]
fn run_folders_follow_the_layout() {
    let tmp = tempfile::tempdir().unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_aift"))
        .args([
            "run",
            "--set",
            "camera.model=\"position\"",
            "--set",
            "duration=9.0",
            "--out",
            "r",
        ])
        .current_dir(tmp.path())
        .env("AIFT_CACHE_DIR", "off")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let header = std::fs::read_to_string(tmp.path().join("r/trajectory.csv")).unwrap();
    let header = header.lines().next().unwrap();
    assert!(header.contains("y_cam_x,y_cam_y,y_cam_z"), "{header}");
    let svg = std::fs::read_to_string(tmp.path().join("r/health.svg")).unwrap();
    assert!(svg.contains("cam_z"));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("r/summary.json")).unwrap())
            .unwrap();
    assert!(summary["final_health"]["cam_y"].is_number());
}
