//! The plant commands: `check-urdf` and `simulate`, exit codes, list spellings, determinism.

mod common;

use std::process::Command;

use common::repo;

fn aift() -> Command {
    Command::new(env!("CARGO_BIN_EXE_aift"))
}

#[test]
fn check_urdf_prints_the_arm_and_exits_0() {
    let out = aift()
        .args(["check-urdf"])
        .arg(repo("urdf/planar_2dof.urdf"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0));
    let text = String::from_utf8_lossy(&out.stdout);
    for needle in [
        "joint1",
        "joint2",
        "axis (0, -1, 0)",
        "2.1368",
        "total mass",
        "end effector: ee",
    ] {
        assert!(text.contains(needle), "missing {needle:?} in\n{text}");
    }
}

/// Without a link named `ee`, check-urdf says where `init` would put the end effector (its
/// rule: a tool-point name on the last joint's body, else that body's last link).
#[test]
fn check_urdf_names_inits_end_effector_when_none_is_named_ee() {
    let dir = tempfile::tempdir().unwrap();
    let urdf = dir.path().join("arm.urdf");
    let text = std::fs::read_to_string(repo("urdf/planar_2dof.urdf"))
        .unwrap()
        .replace("\"ee\"", "\"tool_tip\"");
    assert!(text.contains("tool_tip"));
    std::fs::write(&urdf, text).unwrap();
    let out = aift().args(["check-urdf"]).arg(&urdf).output().unwrap();
    assert_eq!(out.status.code(), Some(0));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("none named 'ee'; `init` would put it on 'tool_tip'"),
        "{text}"
    );
}

#[test]
fn check_urdf_bad_inputs_exit_2_with_the_file_named() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("broken.urdf");
    std::fs::write(&bad, "<robot name='x'><link name='a'/></robot>").unwrap();
    for (args, needle) in [
        (vec![bad.to_str().unwrap().to_string()], "broken.urdf"),
        (vec!["/no/such/file.urdf".to_string()], "file.urdf"),
        (
            vec![
                repo("urdf/planar_2dof.urdf").to_str().unwrap().to_string(),
                "--ee".into(),
                "gripper".into(),
            ],
            "gripper",
        ),
    ] {
        let out = aift().arg("check-urdf").args(&args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(needle), "{err}");
    }
}

fn simulate(q0_args: &[&str], out: &std::path::Path) -> std::process::Output {
    aift()
        .args(["simulate", "--urdf"])
        .arg(repo("urdf/planar_2dof.urdf"))
        .args(q0_args)
        .args(["--torque", "10,-2", "--duration", "0.05", "--out"])
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn simulate_accepts_negative_lists_in_both_spellings_and_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.csv");
    let b = dir.path().join("b.csv");
    let o1 = simulate(&["--q0", "-1.2,0.8"], &a);
    assert_eq!(
        o1.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o1.stderr)
    );
    let o2 = simulate(&["--q0=-1.2,0.8"], &b);
    assert_eq!(
        o2.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o2.stderr)
    );
    let ta = std::fs::read(&a).unwrap();
    let tb = std::fs::read(&b).unwrap();
    assert_eq!(ta, tb, "same inputs give bit-identical CSVs");
    let text = String::from_utf8(ta).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next().unwrap(), "t,q1,q2,qd1,qd2,ee_x,ee_y,ee_z");
    let first: Vec<f64> = lines
        .next()
        .unwrap()
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    assert_eq!(first[0], 0.0);
    assert_eq!(first[1], -1.2);
    assert_eq!(first[2], 0.8);
    assert_eq!(text.lines().count(), 1 + 51);
}

#[test]
fn simulate_bad_inputs_exit_2_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never.csv");
    for args in [
        vec!["--q0", "-1.2,0.8,0.1"],
        vec!["--q0", "-1.2,abc"],
        vec!["--q0", "nan,0"],
        vec!["--q0", "0,0", "--dt", "-0.001"],
        vec!["--q0", "0,0", "--dt", "0"],
    ] {
        let o = simulate(&args, &out);
        assert_eq!(
            o.status.code(),
            Some(2),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(!out.exists(), "{args:?} wrote an output");
    }
}

/// Within the step bound (1e9) but over the trajectory file's bound (4 GiB at 24 bytes per
/// value): refused before any step, nothing written (it once reserved 80 GB and aborted).
#[test]
fn simulate_refuses_a_file_over_the_size_bound_before_any_step() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never.csv");
    let o = aift()
        .args(["simulate", "--urdf"])
        .arg(repo("urdf/planar_2dof.urdf"))
        .args(["--q0", "0,0", "--dt", "1e-6", "--duration", "1000", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("would exceed 4 GiB"), "{err}");
    assert!(!out.exists());
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        0,
        "leftovers"
    );
}
