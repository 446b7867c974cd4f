//! Hostile and careless input through the CLI (issue 13), one test per class: counts beyond their
//! bounds, reads of devices, FIFOs and folders, silent wrong results made loud (limits, late
//! faults and targets, duplicated methods, a blown-up simulation, dt beyond the duration), errors
//! naming the right key (and `--set` when the value came from it), bad output locations, the URDF
//! items, and a calibration accepted whatever its alpha or isolation; round three (issue 30):
//! outputs that are devices, FIFOs or links, closed and full stdout, merge records checked
//! against their config, grids counted, named and deduplicated before expansion, bounded thread
//! counts, init's refusals, damaged report inputs. Every refusal is exit 2, before any work, with
//! nothing written. (Half-written folders: tests/output_folders.rs; fuzzing:
//! tests/scenario_fuzz.rs and tests/urdf_validation.rs.)

mod common;

use std::path::Path;

use common::aift_in as aift;

/// Runs a command that must be refused: exit 2, stderr containing every needle, nothing at
/// `out`. (That the command's own inputs are refused before the GP's fit is checked by order,
/// not by the clock: `a_commands_own_inputs_are_checked_before_the_camera_model`.)
fn refused(args: &[&str], needles: &[&str], dir: &Path, out: &str) {
    let o = aift(args, dir);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {stderr}");
    for n in needles {
        assert!(stderr.contains(n), "{args:?}: lacks {n:?}: {stderr}");
    }
    assert!(!dir.join(out).exists(), "{args:?} wrote {out}");
}

fn scenario(name: &str) -> String {
    common::repo(&format!("assets/scenarios/{name}"))
        .to_string_lossy()
        .into_owned()
}

#[test]
fn counts_beyond_their_bounds_are_refused_before_any_work() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let urdf = common::repo("urdf/planar_2dof.urdf");
    let urdf = urdf.to_str().unwrap();
    for (args, needles) in [
        (
            vec![
                "run",
                "--set",
                "detector.calibration_runs=1000000000",
                "--out",
                "o",
            ],
            vec!["detector.calibration_runs", "10000"],
        ),
        (
            vec![
                "run",
                "--set",
                "robot.solver_iterations=100000000",
                "--out",
                "o",
            ],
            vec!["robot.solver_iterations"],
        ),
        (
            vec!["table", "--seeds", "1000000000", "--out", "o"],
            vec!["--seeds"],
        ),
        (vec!["bench", "--ticks", "100000000000"], vec!["--ticks"]),
        (
            vec!["run", "--set", "duration=1e12", "--out", "o"],
            vec!["duration"],
        ),
        (
            vec!["run", "--set", "gp.points=100000000", "--out", "o"],
            vec!["gp.points"],
        ),
        (
            // A huge restart count once panicked (capacity overflow) after minutes of fits.
            vec![
                "run",
                "--set",
                "gp.restarts=9000000000000000000",
                "--out",
                "o",
            ],
            vec!["--set gp.restarts", "1..=100"],
        ),
        (
            vec!["campaign", "--seeds", "0", "--out", "o"],
            vec!["--seeds 0", "1..=10000"],
        ),
        (
            vec![
                "simulate",
                "--urdf",
                urdf,
                "--ee",
                "ee",
                "--q0",
                "0,0",
                "--duration",
                "1",
                "--iterations",
                "100000000",
                "--out",
                "o",
            ],
            vec!["--iterations"],
        ),
    ] {
        refused(&args, &needles, d, "o");
    }
}

#[test]
fn devices_fifos_and_folders_are_not_read() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let fifo = d.join("fifo.toml");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: creates a FIFO in our temporary folder.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    for path in ["/dev/zero", fifo.to_str().unwrap(), d.to_str().unwrap()] {
        refused(&["run", path, "--out", "o"], &[path], d, "o");
        refused(&["check-urdf", path], &[path], d, "o");
    }
    // A scenario whose URDF is a device: named with its key.
    refused(
        &["run", "--set", "robot.urdf=\"/dev/zero\"", "--out", "o"],
        &["robot.urdf", "/dev/zero"],
        d,
        "o",
    );
}

#[test]
fn silent_wrong_results_become_errors_or_warnings() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let spatial = scenario("spatial3_healthy.toml");
    // Outside the joint limits: the physics would clamp it silently.
    refused(
        &[
            "run",
            &spatial,
            "--set",
            "initial.q=[5.0, 0.0, 0.0]",
            "--out",
            "o",
        ],
        &["initial.q[0]", "limits", "--set initial.q"],
        d,
        "o",
    );
    refused(
        &[
            "run",
            &spatial,
            "--set",
            "targets[0].q=[0.0, 0.0, 9.0]",
            "--out",
            "o",
        ],
        &["targets[0].q[2]", "limits"],
        d,
        "o",
    );
    // A scenario for a 3-joint arm without `[controller.gains]`: the default gains are the paper
    // arm's 2 joints, and the message says so and where gains come from.
    let no_gains = d.join("no_gains.toml");
    let text = std::fs::read_to_string(&spatial).unwrap();
    let start = text
        .find("[controller.gains]")
        .expect("the scenario has gains");
    let end = start + text[start..].find("\n\n").unwrap_or(text.len() - start);
    let mut cut = text.clone();
    cut.replace_range(start..end, "");
    let cut = cut.replace(
        "urdf = \"",
        &format!(
            "urdf = \"{}/",
            Path::new(&spatial).parent().unwrap().display()
        ),
    );
    std::fs::write(&no_gains, cut).unwrap();
    refused(
        &["run", no_gains.to_str().unwrap(), "--out", "o"],
        &[
            "no_gains.toml",
            "controller.gains",
            "paper's 2-joint arm",
            "3 joints",
            "aift init",
        ],
        d,
        "o",
    );
    // Two identical methods would claim twice the seeds.
    refused(
        &["table", "--methods", "no-ft,no-ft", "--out", "o"],
        &["no-ft", "twice"],
        d,
        "o",
    );
    // dt beyond the duration is blamed on the duration, not on a learner's window.
    refused(
        &[
            "run",
            "--set",
            "dt=0.05",
            "--set",
            "duration=0.01",
            "--out",
            "o",
        ],
        &["`duration`"],
        d,
        "o",
    );
    // A fault after the end: a warning, and the run reports no faulty joint.
    let o = aift(
        &[
            "run",
            &scenario("paper_encoder_freeze.toml"),
            "--set",
            "duration=5.0",
            "--out",
            "late",
        ],
        d,
    );
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(
        stderr.contains("warning") && stderr.contains("`faults[0].start`"),
        "{stderr}"
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("late/summary.json")).unwrap())
            .unwrap();
    assert!(summary["mse_faulty"].is_null(), "{summary}");
    assert_eq!(summary["faulty_joints"], serde_json::json!([]));
    // A simulation that blows up is an error, not a success with 1e296 in the file.
    let urdf = common::repo("urdf/planar_2dof_undamped.urdf");
    refused(
        &[
            "simulate",
            "--urdf",
            urdf.to_str().unwrap(),
            "--ee",
            "ee",
            "--q0",
            "0,0",
            "--torque",
            "1e200,1e200",
            "--duration",
            "1",
            "--out",
            "blow.csv",
        ],
        &["blew up", "nothing written"],
        d,
        "blow.csv",
    );
}

#[test]
fn errors_name_the_key_and_the_set_that_gave_it() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    refused(
        &["run", "--set", "robot.ee_link=\"nolink\"", "--out", "o"],
        &["--set robot.ee_link", "`robot.ee_link`", "nolink"],
        d,
        "o",
    );
    refused(
        &["run", "--set", "camera.sigma=1e300", "--out", "o"],
        &["camera.sigma"],
        d,
        "o",
    );
    refused(
        &["run", "--set", "precision.kappa_zeta=-1", "--out", "o"],
        &["--set precision.kappa_zeta", "`precision.kappa_zeta`"],
        d,
        "o",
    );
    // The hybrid's propagated prior (throughout, or once a tachometer fails) needs the
    // Gauss-Newton update, like the controller's; the refusal names the prior given.
    for prior in ["propagated", "fixed-until-tachometer-fails"] {
        let set = format!("hybrid.prior=\"{prior}\"");
        refused(
            &[
                "run",
                "--set",
                &set,
                "--set",
                "belief.update=\"gradient\"",
                "--out",
                "o",
            ],
            &["hybrid.prior", prior, "gauss-newton"],
            d,
            "o",
        );
    }
    // The hybrid's actuator hypotheses need the white model error: with the model-error state
    // (the default) a locked joint would be explained as model error.
    refused(
        &["run", "--set", "hybrid.actuators=true", "--out", "o"],
        &["hybrid.actuators", "hybrid.model_error_state = false"],
        d,
        "o",
    );
    // The Kalman baselines' process model: a typed choice, and the model's settings bounded.
    refused(
        &["run", "--set", "kalman.process_model=\"rk4\"", "--out", "o"],
        &["kalman.process_model", "rk4"],
        d,
        "o",
    );
    refused(
        &["run", "--set", "model.mass_scale=0.0", "--out", "o"],
        &["model.mass_scale", "(0, 100]"],
        d,
        "o",
    );
    refused(
        &["run", "--set", "model.relative_error=-1.0", "--out", "o"],
        &["model.relative_error"],
        d,
        "o",
    );
    // A key that moved says where to.
    refused(
        &["run", "--set", "kalman.mass_scale=0.5", "--out", "o"],
        &["kalman.mass_scale", "moved to `model.mass_scale`"],
        d,
        "o",
    );
    // A newline in a --set value would smuggle in a second key.
    refused(
        &["run", "--set", "seed=2\nduration=1.0", "--out", "o"],
        &["--set", "newline"],
        d,
        "o",
    );
    // The end-effector error says it once.
    let o = aift(
        &["run", "--set", "robot.ee_link=\"nolink\"", "--out", "o"],
        d,
    );
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(stderr.matches("does not exist").count(), 1, "{stderr}");
}

#[test]
fn bad_output_locations_are_input_errors_found_before_the_work() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    std::fs::write(d.join("file"), "x").unwrap();
    std::fs::create_dir(d.join("folder")).unwrap();
    for (args, out) in [
        (vec!["run", "--out", "/proc/aift-out"], "/proc/aift-out"),
        (vec!["run", "--out", "file/below"], "file/below"),
        (
            vec!["calibrate", "--runs", "2", "--out", "folder"],
            "folder/x",
        ),
        (vec!["train-gp", "--out", "/proc/gp.json"], "/proc/gp.json"),
    ] {
        refused(&args, &[args[args.len() - 1]], d, out);
    }
}

#[test]
fn urdf_negative_dynamics_and_a_second_robot_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let base = std::fs::read_to_string(common::repo("urdf/spatial_3dof.urdf")).unwrap();
    for (name, text, needle) in [
        (
            "negative_damping",
            base.replacen("damping=\"", "damping=\"-", 1),
            "damping",
        ),
        (
            "negative_effort",
            base.replacen("effort=\"", "effort=\"-", 1),
            "effort",
        ),
        (
            "second_robot",
            format!("{base}\n<robot name=\"again\"></robot>\n"),
            "robot",
        ),
    ] {
        let file = d.join(format!("{name}.urdf"));
        std::fs::write(&file, &text).unwrap();
        assert_ne!(text, base, "{name}: the edit did not apply");
        refused(
            &["check-urdf", file.to_str().unwrap()],
            &[needle, &format!("{name}.urdf")],
            d,
            "o",
        );
    }
}

#[test]
fn a_calibration_is_accepted_whatever_alpha_isolation_or_test() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let s = scenario("paper_encoder_freeze.toml");
    let o = aift(
        &[
            "calibrate",
            &s,
            "--runs",
            "4",
            "--set",
            "duration=9.0",
            "--out",
            "cal.json",
        ],
        d,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = aift(
        &[
            "run",
            &s,
            "--method",
            "pl-detect",
            "--calib",
            "cal.json",
            "--set",
            "duration=9.0",
            "--set",
            "detector.alpha=0.05",
            "--set",
            "detector.isolation=\"group\"",
            "--set",
            "detector.test=\"cusum\"",
            "--out",
            "r",
        ],
        d,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // What the data depend on (the schedule) still has to match.
    refused(
        &[
            "run",
            &s,
            "--method",
            "pl-detect",
            "--calib",
            "cal.json",
            "--set",
            "duration=10.0",
            "--out",
            "r2",
        ],
        &["cal.json"],
        d,
        "r2",
    );
}

/// The file type of `path` without following a link: (is_fifo, is_symlink, is_char_device).
fn file_type(path: &Path) -> (bool, bool, bool) {
    use std::os::unix::fs::FileTypeExt;
    let t = std::fs::symlink_metadata(path).unwrap().file_type();
    (t.is_fifo(), t.is_symlink(), t.is_char_device())
}

#[test]
fn outputs_never_replace_devices_fifos_or_links() {
    // Issue 30, class 1: as root, the atomic rename replaced /dev/null with an empty file. The
    // targets here are the test's own: a FIFO, a link to /dev/null and, where the test may create
    // one, a character device (the null device) in a temporary folder.
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let mut targets = Vec::new();
    let fifo = d.join("fifo");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: creates a FIFO in our temporary folder.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    targets.push(fifo);
    let link = d.join("link");
    std::os::unix::fs::symlink("/dev/null", &link).unwrap();
    targets.push(link);
    let dev = d.join("null-device");
    let c = std::ffi::CString::new(dev.to_str().unwrap()).unwrap();
    // SAFETY: creates a device node for the null device (1, 3) in our temporary folder; only
    // root may, and then it is tested too.
    if unsafe { libc::mknod(c.as_ptr(), libc::S_IFCHR | 0o600, libc::makedev(1, 3)) } == 0 {
        targets.push(dev);
    }
    let urdf = common::repo("urdf/planar_2dof.urdf");
    let urdf = urdf.to_str().unwrap();
    let healthy = scenario("paper_healthy.toml");
    for target in &targets {
        let before = file_type(target);
        let t = target.to_str().unwrap();
        let commands: Vec<Vec<&str>> = vec![
            vec!["calibrate", &healthy, "--runs", "2", "--out", t],
            vec!["train-gp", &healthy, "--out", t],
            vec![
                "simulate",
                "--urdf",
                urdf,
                "--ee",
                "ee",
                "--q0",
                "0,0",
                "--duration",
                "0.01",
                "--out",
                t,
            ],
            vec!["init", "--urdf", urdf, "--out", t, "--force"],
            vec!["gen-arm", "--seed", "3", "--out", t, "--force"],
            vec!["run", &healthy, "--out", t, "--force"],
        ];
        for args in commands {
            let o = aift(&args, d);
            let stderr = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{args:?}: {stderr}");
            assert!(stderr.contains(t), "{args:?}: {stderr}");
            assert_eq!(file_type(target), before, "{args:?} replaced {t}");
        }
    }
    // A folder, or a path ending in `/`, is not a file: exit 2 before the question of --force.
    std::fs::create_dir(d.join("sdir")).unwrap();
    for out in ["sdir", "sdir/", "new/"] {
        let o = aift(&["init", "--urdf", urdf, "--out", out], d);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{out}: {stderr}");
        assert!(!stderr.contains("--force"), "{out}: {stderr}");
    }
    assert!(!d.join("new").exists());
    // Nothing was left beside them (staging, locks).
    let left: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".aift-"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

/// Runs aift with its stdout the write end of a pipe whose read end is already closed.
fn with_closed_stdout(args: &[&str], dir: &Path) -> std::process::Output {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    common::aift_command(args, dir)
        .stdout(writer)
        .stderr(std::process::Stdio::piped())
        .output()
        .unwrap()
}

#[test]
fn a_closed_pipe_ends_the_output_and_a_full_one_is_an_error_never_a_panic() {
    // Issue 30, class 4.
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let urdf = common::repo("urdf/panda_7dof.urdf");
    let urdf = urdf.to_str().unwrap();
    let healthy = scenario("paper_healthy.toml");
    let short = "duration=0.5";
    let quick: Vec<Vec<&str>> = vec![
        vec!["check-urdf", urdf],
        vec!["check-urdf", urdf, "--json"],
        vec!["schema"],
        vec!["schema", "--markdown"],
        vec!["completions", "bash"],
        vec!["gen-arm", "--seed", "5"],
        vec!["--help"],
    ];
    for args in &quick {
        let o = with_closed_stdout(args, d);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(0), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    }
    // Work that writes files finishes them though nobody reads its lines.
    let o = with_closed_stdout(
        &["run", &healthy, "--set", short, "--out", "r", "--json"],
        d,
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(d.join("r/summary.json").is_file());
    let o = with_closed_stdout(
        &[
            "table",
            &healthy,
            "--set",
            short,
            "--seeds",
            "1",
            "--methods",
            "no-ft",
            "--out",
            "t",
        ],
        d,
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(d.join("t/table.json").is_file());

    // A full stdout is a write error: exit 1 naming stdout, never a panic; a full stderr is
    // ignored (the exit code still tells).
    if Path::new("/dev/full").exists() {
        let full = || {
            std::fs::OpenOptions::new()
                .write(true)
                .open("/dev/full")
                .unwrap()
        };
        for args in &quick[..5] {
            let o = common::aift_command(args, d)
                .stdout(full())
                .output()
                .unwrap();
            let stderr = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(1), "{args:?}: {stderr}");
            assert!(stderr.contains("writing to stdout"), "{args:?}: {stderr}");
        }
        let o = common::aift_command(&["check-urdf", "missing.urdf"], d)
            .stderr(full())
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2));
        let o = common::aift_command(&["run", &healthy, "--set", short, "--out", "r2"], d)
            .stderr(full())
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(0));
        assert!(d.join("r2/summary.json").is_file());
    }
}

/// Edits `DIR/records.json` of a copy of `shard` with `edit`; returns the copy's name.
fn edited_shard(
    d: &Path,
    shard: &str,
    name: &str,
    edit: impl Fn(&mut serde_json::Value),
) -> String {
    let copy = d.join(name);
    std::fs::create_dir_all(&copy).unwrap();
    let text = std::fs::read_to_string(d.join(shard).join("records.json")).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    edit(&mut v);
    std::fs::write(copy.join("records.json"), v.to_string()).unwrap();
    name.to_string()
}

#[test]
fn merge_checks_every_record_against_its_config() {
    // Issue 30, class 2: records.json was trusted (panics, an 8 TB allocation, silent extra seeds).
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let text = common::tiny_campaign(
        "merge_checks",
        "[reaching]\ntasks = 1\nduration = 1.0\ncalibration_runs = 2\n",
    )
    .replace("seeds = 1", "seeds = 2");
    std::fs::write(d.join("c.toml"), text).unwrap();
    for k in ["1", "2"] {
        common::aift_ok(
            &[
                "campaign",
                "c.toml",
                "--shard",
                &format!("{k}/2"),
                "--out",
                &format!("s{k}"),
            ],
            d,
        );
    }
    common::aift_ok(&["merge", "s1", "s2", "--out", "whole"], d);
    let first_run = |v: &serde_json::Value| v["runs"][0].clone();
    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let cases: Vec<(&str, Edit, &str)> = vec![
        (
            "cell",
            Box::new(|v| v["runs"][0]["cell"] = 999_999.into()),
            "cell 999999",
        ),
        (
            "arm",
            Box::new(|v| v["reaching"][0]["arm"] = 77.into()),
            "arm 77",
        ),
        (
            "no-arms",
            Box::new(|v| v["config"]["arms"] = serde_json::json!([])),
            "arms",
        ),
        (
            "shard0",
            Box::new(|v| v["shard"]["count"] = 0.into()),
            "shard",
        ),
        (
            "jobs",
            Box::new(|v| v["jobs"] = 1_000_000_000_000u64.into()),
            "jobs",
        ),
        (
            "twice",
            Box::new(move |v| {
                let r = first_run(v);
                v["runs"].as_array_mut().unwrap().push(r);
            }),
            "twice",
        ),
        (
            "method",
            Box::new(|v| v["runs"][0]["method"] = "hybrid".into()),
            "hybrid",
        ),
        (
            "seed",
            Box::new(|v| v["runs"][0]["seed"] = 7.into()),
            "seed 7",
        ),
        (
            "edited",
            Box::new(|v| v["config"]["verdict"]["tolerance"] = 9.0.into()),
            "edited",
        ),
        (
            "format",
            Box::new(|v| v["format_version"] = 99.into()),
            "format_version 99",
        ),
    ];
    for (name, edit, needle) in cases {
        let bad = edited_shard(d, "s1", name, edit);
        let o = aift(&["merge", &bad, "s2", "--out", "m"], d);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{name}: {stderr}");
        assert!(
            stderr.contains(needle),
            "{name}: lacks {needle:?}: {stderr}"
        );
        assert!(
            stderr.contains(&bad),
            "{name}: the shard is not named: {stderr}"
        );
        assert!(!d.join("m").exists(), "{name}");
    }
    // A diverged run is a result, not a damaged record: its non-finite numbers are written as
    // null (JSON has no NaN) and read back (merge refused such a shard until 2026-12-06).
    let diverged = edited_shard(d, "s1", "diverged", |v| {
        let r = &mut v["runs"][0];
        r["mse_post"] = serde_json::Value::Null;
        r["max_final_error"] = serde_json::Value::Null;
        r["outcome"] = "diverged".into();
        r["verdict"] = "diverged".into();
        let t = &mut v["reaching"][0];
        t["belief_rmse"] = serde_json::Value::Null;
        t["outcome"] = "diverged".into();
    });
    let o = aift(&["merge", &diverged, "s2", "--out", "with_diverged"], d);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let merged: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(d.join("with_diverged/records.json")).unwrap(),
    )
    .unwrap();
    assert!(
        merged["runs"]
            .as_array()
            .unwrap()
            .iter()
            .any(|r| r["verdict"] == "diverged" && r["mse_post"].is_null()),
        "{merged}"
    );
    let staging: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".aift-"))
        .collect();
    assert!(staging.is_empty(), "{staging:?}");
}

#[test]
fn campaign_grids_are_counted_named_and_deduplicated_before_any_run() {
    // Issue 30, classes 3, 5, 6 and an empty grid (10): refused at once, exit 2, the key named.
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let base = common::tiny_campaign("grid_checks", "");
    let check = |name: &str, text: String, needles: &[&str]| {
        std::fs::write(d.join(format!("{name}.toml")), text).unwrap();
        refused(
            &["campaign", &format!("{name}.toml"), "--out", "o"],
            needles,
            d,
            "o",
        );
    };
    // 1e8 cells from a short file: 200 arms x 100 channels x 8 kinds x 3 onsets + ...
    let mut huge = base.replace("channels = [\"enc*\"]", &{
        let list: Vec<String> = (0..100).map(|i| format!("\"cam{i}\"")).collect();
        format!("channels = [{}]", list.join(","))
    });
    huge = huge.replace(
        "[[kinds]]\nkind = \"freeze\"\nonsets = [\"moving\"]",
        "[[kinds]]\nkind = \"freeze\"\nonsets = [\"moving\", \"rest\", \"rest-then-motion\"]",
    );
    for i in 0..999 {
        huge.push_str(&format!(
            "\n[[arms]]\nname = \"a{i}\"\nscenario = \"x.toml\"\njoints = [{}]\n",
            (1..=50)
                .map(|j| j.to_string())
                .collect::<Vec<_>>()
                .join(",")
        ));
    }
    huge = huge.replace("channels = [", "channels = [\"enc*\", ");
    let most = format!("at most {}", aift::scenario::campaign::MAX_CELLS);
    check("huge", huge, &["cells", &most]);
    check(
        "slash",
        base.replace("name = \"paper\"", "name = \"../up\""),
        &["arms[0].name"],
    );
    check(
        "empty_name",
        base.replace("name = \"paper\"", "name = \"\""),
        &["arms[0].name"],
    );
    let second_arm = format!(
        "\n[[arms]]\nname = \"paper\"\nscenario = \"{}\"\n",
        common::repo("assets/scenarios/paper_healthy.toml").display()
    );
    check(
        "same_arm",
        format!("{base}{second_arm}"),
        &["arms[1].name", "earlier arm"],
    );
    check(
        "channel_twice",
        base.replace("channels = [\"enc*\"]", "channels = [\"enc*\", \"enc1\"]"),
        &["channels[1]"],
    );
    check(
        "kind_twice",
        format!("{base}\n[[kinds]]\nkind = \"freeze\"\n"),
        &["kinds[1]", "twice"],
    );
    check(
        "onset_twice",
        base.replace("onsets = [\"moving\"]", "onsets = [\"moving\", \"moving\"]"),
        &["kinds[0].onsets[1]"],
    );
    let pair = |label: &str, faults: &str| {
        format!("{base}\n[[pairs]]\nlabel = \"{label}\"\nfaults = {faults}\n")
    };
    let two = r#"[{ kind = "freeze", channel = "enc1", start = 8.0 }, { kind = "bias", channel = "cam", offset = 0.04, start = 8.5 }]"#;
    check("pair_healthy", pair("healthy", two), &["pairs[0].label"]);
    check(
        "pair_like_cell",
        pair("enc1 freeze moving", two),
        &["pairs[0].label"],
    );
    check("pair_empty", pair("nothing", "[]"), &["pairs[0].faults"]);
    check(
        "empty",
        base.replace("[[kinds]]\nkind = \"freeze\"\nonsets = [\"moving\"]", "")
            .replace(
                "name = \"grid_checks\"",
                "name = \"grid_checks\"\nhealthy = false",
            ),
        &["empty"],
    );
}

/// A small URDF: base, three revolute joints in a chain (l1, l2, ee), and `extra` joints and
/// links; `j2` as given.
fn small_urdf(j2: &str, extra: &str) -> String {
    let link = |name: &str| {
        format!(
            r#"<link name="{name}"><inertial><mass value="1.0"/><origin xyz="0 0 0.15"/>
<inertia ixx="0.01" iyy="0.01" izz="0.002" ixy="0" ixz="0" iyz="0"/></inertial>
<collision><origin xyz="0 0 0.15"/><geometry><box size="0.05 0.05 0.3"/></geometry></collision></link>"#
        )
    };
    format!(
        r#"<robot name="small">
<link name="base"/>
{l1}{l2}{ee}
<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/>
<axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="100" velocity="2"/><dynamics damping="1"/></joint>
{j2}
<joint name="j3" type="revolute"><parent link="l2"/><child link="ee"/><origin xyz="0 0 0.3"/>
<axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="100" velocity="2"/><dynamics damping="1"/></joint>
{extra}
</robot>"#,
        l1 = link("l1"),
        l2 = link("l2"),
        ee = link("ee"),
    )
}

const J2: &str = r#"<joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.3"/>
<axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="100" velocity="2"/><dynamics damping="1"/></joint>"#;

#[test]
fn init_refuses_what_cannot_work_and_passes_warnings_on() {
    // Issue 30, class 8.
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let write = |name: &str, text: String| std::fs::write(d.join(name), text).unwrap();
    // The plain chain is accepted (the cases below differ from it in one thing each).
    write("chain.urdf", small_urdf(J2, ""));
    common::aift_ok(&["init", "--urdf", "chain.urdf", "--out", "chain.toml"], d);
    // A second branch (a finger on l1): its joint does not move the end effector.
    let finger = r#"<link name="finger"><inertial><mass value="0.1"/>
<inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial></link>
<joint name="finger_joint" type="revolute"><parent link="l1"/><child link="finger"/><origin xyz="0.05 0 0.2"/>
<axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="10" velocity="2"/></joint>"#;
    write("tree.urdf", small_urdf(J2, finger));
    refused(
        &["init", "--urdf", "tree.urdf", "--out", "t.toml"],
        &[
            "tree.urdf",
            "finger_joint",
            "serial",
            "branches at link 'l1'",
        ],
        d,
        "t.toml",
    );
    refused(
        &[
            "init",
            "--urdf",
            "tree.urdf",
            "--ee",
            "finger",
            "--out",
            "t.toml",
        ],
        &["--ee", "'j2'"],
        d,
        "t.toml",
    );
    // A scenario written by hand on the tree is refused too, by every command that loads it.
    let chain = std::fs::read_to_string(d.join("chain.toml")).unwrap();
    assert!(chain.contains("\"chain.urdf\""));
    write(
        "tree.toml",
        chain.replace("\"chain.urdf\"", "\"tree.urdf\""),
    );
    refused(
        &["run", "tree.toml", "--method", "no-ft", "--out", "tree-run"],
        &["tree.toml", "robot.ee_link", "finger_joint", "serial"],
        d,
        "tree-run",
    );
    // The end effector on the root.
    refused(
        &[
            "init",
            "--urdf",
            "chain.urdf",
            "--ee",
            "base",
            "--out",
            "t.toml",
        ],
        &["--ee", "fixed to the world"],
        d,
        "t.toml",
    );
    // A range of 1e-7 rad: targets would equal the start.
    write(
        "narrow.urdf",
        small_urdf(
            &J2.replace(r#"lower="-2" upper="2""#, r#"lower="0" upper="1e-7""#),
            "",
        ),
    );
    refused(
        &["init", "--urdf", "narrow.urdf", "--out", "t.toml"],
        &["joint 'j2' <limit>", "narrower"],
        d,
        "t.toml",
    );
    // A 30-joint chain whose derived loop does not settle: init's check run refuses it, naming
    // the joint, and --no-check writes it anyway.
    let mut chain = vec![r#"<link name="base"/>"#.to_string()];
    let mut parent = "base".to_string();
    for i in 1..=30 {
        let axis = if i % 2 == 1 { "0 0 1" } else { "0 1 0" };
        chain.push(format!(
            r#"<link name="c{i}"><inertial><origin xyz="0 0 0.05"/><mass value="0.3"/>
<inertia ixx="0.0005" iyy="0.0005" izz="0.0001" ixy="0" ixz="0" iyz="0"/></inertial>
<collision><origin xyz="0 0 0.05"/><geometry><box size="0.03 0.03 0.1"/></geometry></collision></link>
<joint name="q{i}" type="revolute"><parent link="{parent}"/><child link="c{i}"/><origin xyz="0 0 0.1"/>
<axis xyz="{axis}"/><limit lower="-2" upper="2" effort="200" velocity="3"/><dynamics damping="0.5"/></joint>"#
        ));
        parent = format!("c{i}");
    }
    write(
        "c30.urdf",
        format!("<robot name=\"c30\">{}</robot>", chain.join("\n")),
    );
    refused(
        &["init", "--urdf", "c30.urdf", "--out", "c30.toml"],
        &["c30.toml", "check run", "off its last target", "--no-check"],
        d,
        "c30.toml",
    );
    common::aift_ok(
        &[
            "init",
            "--urdf",
            "c30.urdf",
            "--out",
            "c30.toml",
            "--no-check",
        ],
        d,
    );
    // Loader warnings reach the user as they do in check-urdf and run.
    write(
        "mimic.urdf",
        small_urdf(
            &J2.replace("</joint>", r#"<mimic joint="j1"/></joint>"#),
            "",
        ),
    );
    let o = common::aift_ok(&["init", "--urdf", "mimic.urdf", "--out", "m.toml"], d);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("warning") && stderr.contains("<mimic> ignored"),
        "{stderr}"
    );
}

#[test]
fn report_refuses_damaged_files_naming_the_row_and_the_column() {
    // Issue 30, class 9: only the rows a page kept were parsed, and JSON of the wrong shape gave
    // an empty page.
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let healthy = scenario("paper_healthy.toml");
    common::aift_ok(
        &["run", &healthy, "--set", "duration=1.0", "--out", "run"],
        d,
    );
    common::aift_ok(
        &[
            "table",
            &healthy,
            "--set",
            "duration=1.0",
            "--seeds",
            "1",
            "--methods",
            "no-ft",
            "--out",
            "table",
        ],
        d,
    );
    std::fs::write(d.join("c.toml"), common::tiny_campaign("report_shapes", "")).unwrap();
    common::aift_ok(&["campaign", "c.toml", "--out", "campaign"], d);
    let copy = |from: &str, to: &str| {
        let dst = d.join(to);
        std::fs::create_dir_all(&dst).unwrap();
        for e in std::fs::read_dir(d.join(from)).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), dst.join(e.file_name())).unwrap();
        }
        dst
    };
    let trajectory = std::fs::read_to_string(d.join("run/trajectory.csv")).unwrap();
    let lines: Vec<&str> = trajectory.lines().collect();
    let header = lines[0];
    let last_line = format!("line {}", lines.len());
    let damaged: Vec<(&str, String, Vec<&str>)> = vec![
        (
            "late_text",
            {
                let mut l: Vec<String> = lines.iter().map(|x| x.to_string()).collect();
                let last = l.len() - 1;
                let mut values: Vec<&str> = l[last].split(',').collect();
                values[1] = "abc";
                l[last] = values.join(",");
                l.join("\n")
            },
            vec![&last_line, "column `q1`", "is not a number"],
        ),
        (
            "no_t",
            trajectory.replacen("t,", "time,", 1),
            vec!["no column `t`"],
        ),
        (
            "no_mu1",
            trajectory.replacen(",mu1,", ",muX,", 1),
            vec!["no column `mu1`"],
        ),
        ("header_only", format!("{header}\n"), vec!["no rows"]),
        (
            "cut_header",
            trajectory.replacen(header, &header[..header.len() / 2], 1),
            vec!["line 2", "the header has"],
        ),
    ];
    for (name, text, needles) in damaged {
        let dir = copy("run", name);
        std::fs::write(dir.join("trajectory.csv"), text).unwrap();
        let mut n = needles.clone();
        n.push("trajectory.csv");
        refused(
            &["report", name],
            &n,
            d,
            &format!("{name}/report.html.none"),
        );
    }
    let edit_json = |from: &str, to: &str, file: &str, edit: &dyn Fn(&mut serde_json::Value)| {
        let dir = copy(from, to);
        let path = dir.join(file);
        let mut v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        edit(&mut v);
        std::fs::write(&path, v.to_string()).unwrap();
    };
    edit_json("table", "t1", "table.json", &|v| {
        v["rows"][0]["mse_healthy_mean"] = "x".into()
    });
    refused(
        &["report", "t1"],
        &["table.json", "`rows[0]`.mse_healthy_mean"],
        d,
        "none",
    );
    edit_json("table", "t2", "table.json", &|v| {
        v["rows"] = serde_json::json!([])
    });
    refused(
        &["report", "t2"],
        &["table.json", "`rows`: empty"],
        d,
        "none",
    );
    edit_json("campaign", "c1", "campaign.json", &|v| {
        v["cells"][0]["results"][0]["verdict"] = 3.into()
    });
    refused(
        &["report", "c1"],
        &["campaign.json", "`cells[0]`.results[0].verdict"],
        d,
        "none",
    );
    edit_json("campaign", "c2", "campaign.json", &|v| {
        v["cells"] = "none".into()
    });
    refused(&["report", "c2"], &["campaign.json", "`cells`"], d, "none");
    edit_json("run", "r1", "summary.json", &|v| v["seed"] = "one".into());
    refused(&["report", "r1"], &["summary.json", "`seed`"], d, "none");
}

#[test]
fn a_huge_thread_count_is_bounded_with_a_warning() {
    // Issue 30, class 7: RAYON_NUM_THREADS=100000 spent minutes creating threads.
    let tmp = tempfile::tempdir().unwrap();
    let healthy = scenario("paper_healthy.toml");
    for asked in ["100000", "1000000000000"] {
        let args = ["run", &healthy, "--set", "duration=0.5", "--out", asked];
        let o = common::aift_command(&args, tmp.path())
            .env("RAYON_NUM_THREADS", asked)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(0), "{stderr}");
        let max = aift::max_worker_threads();
        assert!(
            stderr.contains(&format!("RAYON_NUM_THREADS={asked} is more than {max}")),
            "{stderr}"
        );
    }
}

/// A command's own inputs (the method's name, the seeds, a file a flag names, the output
/// location) are checked before the GP's fit: with a camera model file that cannot be read
/// (the first thing the fit's place reads), each refusal names its flag, not the model file.
#[test]
fn a_commands_own_inputs_are_checked_before_the_camera_model() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    std::fs::write(d.join("broken_gp.json"), "{ not a model").unwrap();
    std::fs::write(
        d.join("s.toml"),
        format!(
            "{}\n",
            common::scenario_text("paper_healthy.toml")
                .replace("[gp]\n", "[gp]\nmodel = \"broken_gp.json\"\n")
        ),
    )
    .unwrap();
    assert!(
        std::fs::read_to_string(d.join("s.toml"))
            .unwrap()
            .contains("broken_gp.json"),
        "the scenario names the broken model"
    );
    // The broken model itself is refused (so each case below is refused before reading it).
    refused(
        &["run", "s.toml", "--out", "o"],
        &["broken_gp.json"],
        d,
        "o",
    );
    std::fs::create_dir(d.join("taken")).unwrap();
    std::fs::write(d.join("taken/notes.txt"), "mine").unwrap();
    for (args, needles) in [
        (
            vec!["run", "s.toml", "--method", "hybird", "--out", "o"],
            vec!["--method", "hybird"],
        ),
        (
            vec!["run", "s.toml", "--calib", "missing.json", "--out", "o"],
            vec!["--calib", "missing.json", "no such file"],
        ),
        (
            vec!["run", "s.toml", "--out", "taken"],
            vec!["taken", "--force"],
        ),
        (
            vec!["table", "s.toml", "--seeds", "0", "--out", "o"],
            vec!["--seeds"],
        ),
        (
            vec!["table", "s.toml", "--methods", "no-ft,hybird", "--out", "o"],
            vec!["hybird"],
        ),
        (
            vec!["bench", "s.toml", "--method", "hybird"],
            vec!["--method"],
        ),
        (
            vec![
                "replay",
                "missing.mcap",
                "--scenario",
                "s.toml",
                "--out",
                "o",
            ],
            vec!["missing.mcap", "no such file or folder"],
        ),
    ] {
        let o = aift(&args, d);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!stderr.contains("broken_gp"), "{args:?}: {stderr}");
        refused(&args, &needles, d, "o");
    }
    // A scenario the arm refuses is refused before the default output's folder is made.
    refused(&["run", "--set", "duration=-5"], &["duration"], d, "runs");
    refused(&["table", "--set", "dt=0"], &["dt"], d, "tables");
}

/// `init --force` never writes the scenario over the URDF it reads.
#[test]
fn init_does_not_write_over_its_own_urdf() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let urdf = d.join("arm.urdf");
    std::fs::copy(common::repo("urdf/planar_2dof.urdf"), &urdf).unwrap();
    let before = std::fs::read(&urdf).unwrap();
    for out in ["arm.urdf", "./arm.urdf"] {
        let o = aift(
            &[
                "init",
                "--urdf",
                "arm.urdf",
                "--out",
                out,
                "--force",
                "--no-check",
            ],
            d,
        );
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{out}: {stderr}");
        assert!(
            stderr.contains("--out") && stderr.contains("replace"),
            "{stderr}"
        );
        assert_eq!(std::fs::read(&urdf).unwrap(), before, "{out}");
    }
}

/// The same key set twice by `--set`: the refusal blames the later one, which set the value.
#[test]
fn a_refused_override_is_the_last_one_that_set_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    refused(
        &[
            "run",
            "--set",
            "duration=5",
            "--set",
            "duration=-5",
            "--out",
            "o",
        ],
        &["--set duration=-5"],
        tmp.path(),
        "o",
    );
    refused(
        &[
            "run",
            "--set",
            "targets[1].time=1.0",
            "--set",
            "targets=[]",
            "--out",
            "o",
        ],
        &["--set targets=[]"],
        tmp.path(),
        "o",
    );
}

/// A target scheduled at or after the run's end never acts (a warning says so): the final
/// error is taken against the target in force at the end, not the schedule's last.
#[test]
fn the_final_error_is_against_the_target_in_force_at_the_end() {
    use aift::scenario::{Method, Run};
    // The paper arm's second target comes at 7.5 s; the run ends at 7 s, settled on the first.
    let setup = common::with_faults("paper_healthy.toml", &[], &["duration=7.0"]);
    let first = setup.scenario().targets[0].q.clone();
    let last = setup.scenario().targets.last().unwrap().q.clone();
    assert!(first.iter().zip(&last).any(|(a, b)| (a - b).abs() > 0.1));
    let r = Run::new(&setup, Method::NoFt).execute().unwrap();
    assert!(r.max_final_error < 0.02, "{:?}", r.final_error_per_joint);
    for ((e, q), t) in r.final_error_per_joint.iter().zip(&r.q_final).zip(&first) {
        assert_eq!(*e, (q - t).abs());
    }
}

/// An error whose message already ends with its cause's prints that cause once.
#[test]
fn an_error_prints_its_cause_once() {
    let tmp = tempfile::tempdir().unwrap();
    let o = aift(&["run", "nosuch.toml", "--out", "o"], tmp.path());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("nosuch.toml"), "{stderr}");
    assert_eq!(stderr.matches("os error 2").count(), 1, "{stderr}");
}

/// Messages that once named the wrong thing (a new user's trial, 2026-12-06): an unknown key
/// under a table given by `--set` names the `--set`; an output path that is a file or a folder
/// says which; a calibration file the scenario names is blamed on the scenario's key.
#[test]
fn messages_name_what_is_wrong() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    refused(
        &["run", "--set", "nosuch.key=1", "--out", "o"],
        &["--set nosuch.key", "unknown field `nosuch`"],
        d,
        "o",
    );
    std::fs::write(d.join("file.toml"), "").unwrap();
    refused(
        &["run", "--set", "duration=1", "--out", "file.toml"],
        &["file.toml", "is a file, not a folder"],
        d,
        "o",
    );
    std::fs::create_dir(d.join("folder")).unwrap();
    let o = aift(&["gen-arm", "--seed", "3", "--out", "folder"], d);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("is a folder") && !stderr.contains("--force"),
        "{stderr}"
    );
    std::fs::write(d.join("not-a-calibration.json"), "nonsense").unwrap();
    refused(
        &[
            "run",
            "--method",
            "pl-detect",
            "--set",
            "detector.calibration=\"not-a-calibration.json\"",
            "--set",
            "duration=1",
            "--out",
            "o",
        ],
        &[
            "--set detector.calibration",
            "`detector.calibration`",
            "not a calibration",
        ],
        d,
        "o",
    );
}
