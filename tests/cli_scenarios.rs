//! The scenario commands end to end: `run`, `table`, `calibrate`, `train-gp`, `bench`; outputs,
//! determinism, thread-count invariance, and bad input (exit 2, the key named, nothing written).

mod common;

use std::path::Path;
use std::process::{Command, Output};

use common::repo;

fn aift(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_aift"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

fn ok(out: &Output) {
    assert_eq!(
        out.status.code(),
        Some(0),
        "stdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Every file a run writes (detector methods add calibration.json).
const RUN_FILES: [&str; 10] = [
    "report.html",
    "trajectory.csv",
    "summary.json",
    "scenario.resolved.toml",
    "joints.svg",
    "health.svg",
    "detector.svg",
    "free_energy.svg",
    "robot.urdf",
    "gp.json",
];

fn scenario(name: &str) -> String {
    repo(&format!("assets/scenarios/{name}"))
        .to_string_lossy()
        .into_owned()
}

#[test]
fn run_writes_every_output_and_reruns_bit_identically_from_its_folder() {
    let tmp = tempfile::tempdir().unwrap();
    // The embedded default scenario, from a folder that has no scenario files.
    let out = aift(&["run", "--out", "a"], tmp.path());
    ok(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("faulty-joint MSE") && stdout.contains("joints.svg"),
        "{stdout}"
    );
    let a = tmp.path().join("a");
    for file in RUN_FILES {
        assert!(a.join(file).is_file(), "{file} missing");
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(a.join("summary.json")).unwrap()).unwrap();
    for key in [
        "mse_per_joint",
        "mse_faulty",
        "mse_healthy",
        "final_error_per_joint",
        "max_final_error",
        "detected_at",
        "isolated_channel",
        "outcome",
        "mse_post_fault_per_joint",
        "ticks_per_second",
        "scenario",
        "method",
        "seed",
        "aift_version",
    ] {
        assert!(summary.get(key).is_some(), "summary lacks {key}");
    }
    assert_eq!(summary["method"], "pl-always");
    assert_eq!(summary["outcome"], "completed");
    let trajectory = std::fs::read_to_string(a.join("trajectory.csv")).unwrap();
    let header = trajectory.lines().next().unwrap();
    for column in [
        "t",
        "q1",
        "qd2",
        "mu1",
        "mu_p2",
        "target1",
        "u2",
        "y_enc1",
        "y_cam_v",
        "precision_tach1",
        "health_cam_u",
        "F",
        "alarm",
    ] {
        assert!(
            header.split(',').any(|h| h == column),
            "no column {column} in {header}"
        );
    }
    assert_eq!(trajectory.lines().count(), 1 + 20_000);
    // Re-run from the run folder alone.
    ok(&aift(
        &["run", "scenario.resolved.toml", "--out", "../b"],
        &a,
    ));
    let b = tmp.path().join("b");
    assert_eq!(
        std::fs::read(a.join("trajectory.csv")).unwrap(),
        std::fs::read(b.join("trajectory.csv")).unwrap()
    );
    // Same scenario and seed again: bit-identical; a non-empty folder needs --force.
    let again = aift(&["run", "--out", "a"], tmp.path());
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("--force"));
    ok(&aift(&["run", "--out", "a", "--force"], tmp.path()));
    assert_eq!(
        std::fs::read(a.join("trajectory.csv")).unwrap(),
        std::fs::read(b.join("trajectory.csv")).unwrap()
    );
}

#[test]
fn aift_without_a_command_runs_the_default_scenario() {
    let tmp = tempfile::tempdir().unwrap();
    let out = aift(&[], tmp.path());
    ok(&out);
    assert!(
        tmp.path()
            .join("runs/paper_encoder_freeze-pl-always-1/summary.json")
            .is_file()
    );
    // Again: the folder is not empty, so it needs --force, and nothing is touched.
    let again = aift(&[], tmp.path());
    assert_eq!(again.status.code(), Some(2));
}

#[test]
fn a_run_that_fails_after_loading_leaves_no_folder() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("bad.json"), "{}").unwrap();
    let out = aift(
        &[
            "run",
            "--method",
            "deterministic",
            "--calib",
            "bad.json",
            "--out",
            "never",
        ],
        tmp.path(),
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(!tmp.path().join("never").exists());
}

#[test]
fn three_dof_run_reaches_its_target_after_the_freeze() {
    let tmp = tempfile::tempdir().unwrap();
    ok(&aift(
        &[
            "run",
            &scenario("planar3_encoder_freeze.toml"),
            "--method",
            "pl-always",
            "--out",
            "r",
        ],
        tmp.path(),
    ));
    for file in RUN_FILES {
        assert!(tmp.path().join("r").join(file).is_file(), "{file} missing");
    }
    let header = std::fs::read_to_string(tmp.path().join("r/trajectory.csv"))
        .unwrap()
        .lines()
        .next()
        .unwrap()
        .to_string();
    assert!(header.split(',').any(|h| h == "mu3") && header.split(',').any(|h| h == "y_tach3"));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("r/summary.json")).unwrap())
            .unwrap();
    let err = summary["max_final_error"].as_f64().unwrap();
    assert!(err <= 0.02, "3-DOF final error {err}");
    assert_eq!(summary["mse_per_joint"].as_array().unwrap().len(), 3);
}

#[test]
fn bad_scenarios_exit_2_name_the_key_and_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let base = std::fs::read_to_string(scenario("paper_encoder_freeze.toml"))
        .unwrap()
        .replace("../../urdf/", &format!("{}/", repo("urdf").display()));
    let cases = [
        (
            "typo",
            base.replace("duration = 20.0", "duraton = 20.0"),
            "duraton",
        ),
        (
            "negative_dt",
            base.replace("dt = 0.001", "dt = -0.001"),
            "dt",
        ),
        (
            "nan",
            base.replace("duration = 20.0", "duration = nan"),
            "duration",
        ),
        (
            "missing_urdf",
            base.replace("planar_2dof.urdf", "no_such_arm.urdf"),
            "no_such_arm.urdf",
        ),
        (
            "unknown_method",
            base.replace("method = \"pl-always\"", "method = \"pl-sometimes\""),
            "pl-sometimes",
        ),
        (
            "bad_fault",
            base.replace("kind = \"freeze\"", "kind = \"frozen\""),
            "`faults[0]`",
        ),
        (
            "wrong_length",
            base.replace("q = [-0.2, 0.5]", "q = [-0.2, 0.5, 0.1]"),
            "targets[0].q",
        ),
        ("section_typo", base.replace("[gp]", "[gpp]"), "gpp"),
    ];
    for (name, text, needle) in cases {
        let file = tmp.path().join(format!("{name}.toml"));
        std::fs::write(&file, text).unwrap();
        let out_dir = tmp.path().join(format!("out_{name}"));
        let out = aift(
            &[
                "run",
                file.to_str().unwrap(),
                "--out",
                out_dir.to_str().unwrap(),
            ],
            tmp.path(),
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{name}: {stderr}");
        assert!(
            stderr.contains(needle),
            "{name}: message lacks {needle:?}: {stderr}"
        );
        assert!(
            stderr.contains(&format!("{name}.toml")) || name == "missing_urdf",
            "{name}: file not named: {stderr}"
        );
        assert!(!out_dir.exists(), "{name}: wrote {}", out_dir.display());
    }
    // Bad command-line values too.
    for (args, needle) in [
        (vec!["run", "--method", "magic", "--out", "x"], "magic"),
        (
            vec!["run", "--set", "controller.stepp=0.5", "--out", "x"],
            "stepp",
        ),
        (vec!["run", "--set", "dt=nan", "--out", "x"], "dt"),
        (
            vec!["run", "/no/such/scenario.toml", "--out", "x"],
            "scenario.toml",
        ),
    ] {
        let out = aift(&args, tmp.path());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: {stderr}");
        assert!(!tmp.path().join("x").exists());
    }
}

#[test]
fn table_is_identical_for_one_and_two_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let mut tables = Vec::new();
    for threads in ["1", "2"] {
        let out = Command::new(env!("CARGO_BIN_EXE_aift"))
            .args([
                "table",
                "--seeds",
                "3",
                "--methods",
                "no-ft,pl-always,deterministic,oracle",
                "--set",
                "duration=10.0",
                "--set",
                "detector.calibration_runs=8",
                "--out",
                threads,
            ])
            .env("RAYON_NUM_THREADS", threads)
            // Calibrate in each process: the calibration's thread invariance is under test too.
            .env("AIFT_CACHE_DIR", "off")
            .current_dir(tmp.path())
            .output()
            .unwrap();
        ok(&out);
        let dir = tmp.path().join(threads);
        for file in ["table.csv", "table.md", "table.json", "runs.csv"] {
            assert!(dir.join(file).is_file(), "{file}");
        }
        tables.push((
            std::fs::read(dir.join("table.csv")).unwrap(),
            std::fs::read(dir.join("runs.csv")).unwrap(),
        ));
    }
    assert_eq!(
        tables[0], tables[1],
        "table.csv and runs.csv depend on the thread count"
    );
}

#[test]
fn calibrate_writes_a_file_that_run_accepts_and_a_mismatch_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let out = aift(
        &[
            "calibrate",
            "--runs",
            "6",
            "--set",
            "duration=6.0",
            "--out",
            "cal.json",
        ],
        tmp.path(),
    );
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("false alarms"));
    ok(&aift(
        &[
            "run",
            "--method",
            "deterministic",
            "--set",
            "duration=6.0",
            "--calib",
            "cal.json",
            "--out",
            "r",
        ],
        tmp.path(),
    ));
    assert!(tmp.path().join("r/calibration.json").is_file());
    // Another schedule: refused before anything is written.
    let out = aift(
        &[
            "run",
            "--method",
            "deterministic",
            "--set",
            "duration=6.0",
            "--set",
            "targets[1].time=5.0",
            "--calib",
            "cal.json",
            "--out",
            "s",
        ],
        tmp.path(),
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("fingerprint"));
    assert!(!tmp.path().join("s").exists());
}

#[test]
fn train_gp_saves_a_model_that_a_scenario_can_load() {
    let tmp = tempfile::tempdir().unwrap();
    let out = aift(
        &["train-gp", "--points", "60", "--out", "gp.json"],
        tmp.path(),
    );
    ok(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    for needle in ["length scales", "held-out error", "RMS", "trained"] {
        assert!(stdout.contains(needle), "{stdout}");
    }
    let model = tmp.path().join("gp.json");
    let set = format!("gp.model=\"{}\"", model.display());
    let out = aift(
        &["run", "--set", &set, "--set", "duration=2.0", "--out", "r"],
        tmp.path(),
    );
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("loaded from"));
}

#[test]
fn bench_prints_name_value_lines() {
    let tmp = tempfile::tempdir().unwrap();
    let out = aift(
        &["bench", "--ticks", "500", "--set", "duration=1.0"],
        tmp.path(),
    );
    ok(&out);
    let stdout = String::from_utf8_lossy(&out.stdout);
    for name in [
        "closed_loop_ticks_per_s",
        "physics_ticks_per_s",
        "controller_tick_us",
        "gp_predict_us",
        "real_time_factor",
    ] {
        let line = stdout
            .lines()
            .find(|l| l.starts_with(&format!("{name}: ")))
            .unwrap_or_else(|| panic!("no {name} line in\n{stdout}"));
        let value: f64 = line.split(": ").nth(1).unwrap().parse().unwrap();
        assert!(value.is_finite() && value > 0.0, "{line}");
    }
}

/// The timed closed loop is the method asked for, by `--method` or by the scenario's
/// `precision.method`: its belief MSE (deterministic per method and seed) tells them apart.
#[test]
fn bench_times_the_method_it_is_given() {
    let tmp = tempfile::tempdir().unwrap();
    let mse = |extra: &[&str]| -> (String, f64) {
        let mut args = vec!["bench", "--ticks", "200", "--set", "duration=1.0"];
        args.extend_from_slice(extra);
        let out = aift(&args, tmp.path());
        ok(&out);
        let stdout = String::from_utf8_lossy(&out.stdout).to_string();
        let field = |name: &str| {
            stdout
                .lines()
                .find_map(|l| l.strip_prefix(&format!("{name}: ")))
                .unwrap_or_else(|| panic!("no {name} in\n{stdout}"))
                .to_string()
        };
        (
            field("method"),
            field("closed_loop_belief_mse").parse().unwrap(),
        )
    };
    let (m0, plain) = mse(&[]);
    let (m1, by_set) = mse(&["--set", "precision.method=\"no-ft\""]);
    let (m2, by_flag) = mse(&["--method", "no-ft"]);
    let (m3, ekf) = mse(&["--method", "ekf-gate"]);
    assert_eq!(
        [m0.as_str(), &m1, &m2, &m3],
        ["pl-always", "no-ft", "no-ft", "ekf-gate"]
    );
    assert_eq!(by_set, by_flag);
    assert_ne!(plain, by_set);
    assert_ne!(by_set, ekf);
}

#[test]
fn a_diverging_run_is_a_result_not_an_error() {
    let tmp = tempfile::tempdir().unwrap();
    // The paper's explicit gradient step with physical precisions: unstable (docs/method.md, "The u-AIC").
    let out = aift(
        &["run", "--set", "belief.update=\"gradient\"", "--out", "d"],
        tmp.path(),
    );
    ok(&out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("outcome: diverged"));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("d/summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["outcome"], "diverged");
    assert!(summary["diverged"]["t"].as_f64().unwrap() < 20.0);
    let rows = std::fs::read_to_string(tmp.path().join("d/trajectory.csv"))
        .unwrap()
        .lines()
        .count();
    assert!(
        rows > 1 && rows < 20_001,
        "the trajectory keeps what was logged: {rows} lines"
    );
}
