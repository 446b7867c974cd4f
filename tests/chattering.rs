//! A loop unstable in discrete time is a failure, not a completed run: a joint whose derivative
//! gain is too large for its inertia at the tick rate oscillates at 1/(2 dt) under effort
//! saturation, and the run ends `chattering`, naming the joint (docs/method.md, "Metrics").

mod common;

use std::process::Command;

use common::repo;

fn run(kd_last: f64, out: &std::path::Path) -> serde_json::Value {
    let kd = format!("controller.gains.kd=[20.42, 37.31, 16.25, 11.16, 0.0, 0.0, {kd_last:?}]");
    let o = Command::new(env!("CARGO_BIN_EXE_aift"))
        .args(["run", "assets/scenarios/panda_healthy.toml", "--set", &kd])
        .args([
            "--set",
            "duration=0.6",
            "--set",
            "plant.engine=\"articulated\"",
        ])
        .args(["--set", "precision.method=\"no-ft\"", "--force", "--out"])
        .arg(out)
        .current_dir(repo(""))
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let text = std::fs::read_to_string(out.join("summary.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

#[test]
fn a_derivative_gain_too_large_for_the_wrist_chatters_and_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    // kd dt / I well above 2 for the wrist's small inertia at dt = 1 ms.
    let s = run(30.0, &dir.path().join("high"));
    assert_eq!(s["outcome"], "chattering", "{s}");
    let what = s["chattering"].as_str().unwrap();
    assert!(what.starts_with("joint 7 chatters at"), "{what}");
    // The same arm with the gain `init` chose for the wrist (none) completes.
    let s = run(0.0, &dir.path().join("low"));
    assert_eq!(s["outcome"], "completed", "{s}");
    assert!(s["chattering"].is_null(), "{s}");
}
