//! Output folders are all or nothing: `aift run` and `aift table` killed (SIGKILL, SIGTERM) at
//! random moments never leave a partial or mixed folder; `--force` replaces the old folder only
//! when the new one is complete; a second process writing the same folder fails at once
//! (exit 2) and the other's folder is whole; a full disk leaves nothing behind.

mod common;

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use rand::{RngExt, SeedableRng};

fn aift() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_aift"));
    c.env("AIFT_CACHE_DIR", "off");
    c
}

const RUN_FILES: [&str; 11] = [
    ".aift-output",
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

const TABLE_FILES: [&str; 6] = [
    ".aift-output",
    "report.html",
    "runs.csv",
    "table.csv",
    "table.json",
    "table.md",
];

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn sorted(files: &[&str]) -> Vec<String> {
    let mut v: Vec<String> = files.iter().map(|s| s.to_string()).collect();
    v.sort();
    v
}

/// A run folder is complete: exactly the run's files, the trajectory has every row, the summary
/// parses. Returns its seed.
fn complete_run(dir: &Path, ticks: usize) -> u64 {
    assert_eq!(names(dir), sorted(&RUN_FILES), "{}", dir.display());
    let rows = std::fs::read_to_string(dir.join("trajectory.csv"))
        .unwrap()
        .lines()
        .count();
    assert_eq!(rows, ticks + 1, "{}", dir.display());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    summary["seed"].as_u64().unwrap()
}

/// A table folder is complete; returns its first seed.
fn complete_table(dir: &Path) -> u64 {
    assert_eq!(names(dir), sorted(&TABLE_FILES), "{}", dir.display());
    let table: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("table.json")).unwrap()).unwrap();
    table["seeds"][0].as_u64().unwrap()
}

fn run_cmd(out: &Path, seed: u64, force: bool) -> Command {
    let mut c = aift();
    c.args([
        "run",
        "--set",
        "duration=2.0",
        "--seed",
        &seed.to_string(),
        "--out",
        out.to_str().unwrap(),
    ]);
    if force {
        c.arg("--force");
    }
    c.stdout(Stdio::null()).stderr(Stdio::null());
    c
}

fn table_cmd(out: &Path, seed: u64, force: bool) -> Command {
    let mut c = aift();
    c.args([
        "table",
        "--seeds",
        "2",
        "--methods",
        "no-ft,pl-always",
        "--set",
        "duration=2.0",
        "--set",
        &format!("seed={seed}"),
        "--out",
        out.to_str().unwrap(),
    ]);
    if force {
        c.arg("--force");
    }
    c.stdout(Stdio::null()).stderr(Stdio::null());
    c
}

/// How long a command takes when it is not killed.
fn duration_of(mut cmd: Command) -> Duration {
    let start = Instant::now();
    assert!(cmd.status().unwrap().success());
    start.elapsed()
}

fn kill(child: &mut Child, signal: i32) {
    // SAFETY: sends a signal to our own child process.
    unsafe {
        libc::kill(child.id() as i32, signal);
    }
    let _ = child.wait();
}

/// Kills `cmd` at random moments over its natural duration (`trials` times, alternating SIGKILL
/// and SIGTERM) and checks after each kill that the target is absent (first trials) or still
/// the complete old folder; then that a run to completion replaces it whole.
fn kill_trials(
    make: &dyn Fn(&Path, u64, bool) -> Command,
    check: &dyn Fn(&Path) -> u64,
    trials: usize,
    seed: u64,
) {
    let tmp = tempfile::tempdir().unwrap();
    let target = tmp.path().join("out");
    let natural = duration_of(make(&tmp.path().join("probe"), 1, false));
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut old_seed = None;
    for trial in 0..trials {
        if trial == trials / 2 {
            // From here on an old folder exists and --force runs try to replace it.
            assert!(make(&target, 100, true).status().unwrap().success());
            old_seed = Some(check(&target));
        }
        let force = old_seed.is_some();
        let wait = natural.mul_f64(rng.random_range(0.0..1.1));
        let mut child = make(&target, 200 + trial as u64, force).spawn().unwrap();
        std::thread::sleep(wait);
        let signal = if trial % 2 == 0 {
            libc::SIGKILL
        } else {
            libc::SIGTERM
        };
        kill(&mut child, signal);
        match (target.exists(), old_seed) {
            (false, None) => {}
            (true, None) => {
                // The run finished before the kill: then it is complete, and becomes the old one.
                let s = check(&target);
                assert_eq!(s, 200 + trial as u64);
                old_seed = Some(s);
            }
            (true, Some(old)) => {
                let s = check(&target);
                assert!(
                    s == old || s == 200 + trial as u64,
                    "trial {trial}: seed {s}"
                );
                old_seed = Some(s);
            }
            (false, Some(_)) => panic!("trial {trial}: the old folder vanished"),
        }
    }
    // A full run afterwards succeeds, replaces the folder and leaves no staging behind.
    assert!(make(&target, 999, true).status().unwrap().success());
    assert_eq!(check(&target), 999);
    let leftovers: Vec<String> = names(tmp.path())
        .into_iter()
        .filter(|n| n.contains(".aift-"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn killed_runs_never_leave_a_partial_or_mixed_folder() {
    kill_trials(&run_cmd, &|d| complete_run(d, 2000), 24, 1);
}

#[test]
fn killed_tables_never_leave_a_partial_or_mixed_folder() {
    kill_trials(&table_cmd, &complete_table, 20, 2);
}

#[test]
fn a_second_writer_of_the_same_folder_fails_and_the_first_folder_is_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let target = tmp.path().join("out");
    // Long enough that the second process (which trains its GP before it stages its output)
    // arrives while the first still writes.
    let long = ["--set", "duration=100.0", "--set", "record_every=10"];
    let mut first = aift();
    first
        .arg("run")
        .args(long)
        .args(["--out", target.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    let mut first = first.spawn().unwrap();
    // Wait until the first has staged its output (its lock exists).
    let lock = tmp.path().join(".out.aift-lock");
    let start = Instant::now();
    while !lock.exists() {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no lock appeared"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    let second = aift()
        .arg("run")
        .args(long)
        .args(["--seed", "7", "--out", target.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("another process is writing"), "{stderr}");
    assert!(first.wait().unwrap().success());
    assert_eq!(complete_run(&target, 10_000), 1);
    assert_eq!(names(tmp.path()), vec!["out".to_string()]);
}

#[test]
fn a_full_disk_leaves_no_folder_and_no_staging() {
    use std::os::unix::process::CommandExt;
    let tmp = tempfile::tempdir().unwrap();
    let target = tmp.path().join("out");
    let mut cmd = run_cmd(&target, 1, false);
    cmd.stderr(Stdio::piped());
    // SAFETY: only async-signal-safe calls between fork and exec: a file-size limit of 200 kB
    // (the trajectory is about 1 MB) stands in for a full disk, and SIGXFSZ is ignored so the
    // write fails with EFBIG instead of killing the process.
    unsafe {
        cmd.pre_exec(|| {
            let limit = libc::rlimit {
                rlim_cur: 200_000,
                rlim_max: 200_000,
            };
            libc::setrlimit(libc::RLIMIT_FSIZE, &limit);
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            Ok(())
        });
    }
    let out = cmd.output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("cannot write"), "{stderr}");
    assert!(!target.exists());
    assert!(names(tmp.path()).is_empty(), "{:?}", names(tmp.path()));
}

/// A single-file output (calibrate, train-gp, simulate) is written whole by an atomic rename:
/// killed at random moments it is absent or the complete old file, never a prefix.
fn file_version(path: &Path, read: &dyn Fn(&str) -> u64) -> u64 {
    let text = std::fs::read_to_string(path).unwrap();
    read(&text)
}

fn calibrate_cmd(out: &Path, version: u64, _force: bool) -> Command {
    let mut c = aift();
    // The version is in the calibration's tick count: duration 1 s + version ms.
    c.args([
        "calibrate",
        "--runs",
        "4",
        "--set",
        &format!("duration={}", 1.0 + version as f64 * 1e-3),
        "--out",
        out.to_str().unwrap(),
    ]);
    c.stdout(Stdio::null()).stderr(Stdio::null());
    c
}

fn calibration_version(path: &Path) -> u64 {
    file_version(path, &|t| {
        let v: serde_json::Value = serde_json::from_str(t).expect("whole JSON");
        v["ticks"].as_u64().unwrap() - 1000
    })
}

fn train_gp_cmd(out: &Path, version: u64, _force: bool) -> Command {
    let mut c = aift();
    c.args([
        "train-gp",
        "--points",
        "60",
        "--set",
        &format!("gp.seed={version}"),
        "--out",
        out.to_str().unwrap(),
    ]);
    c.stdout(Stdio::null()).stderr(Stdio::null());
    c
}

fn gp_version(path: &Path) -> u64 {
    file_version(path, &|t| {
        let v: serde_json::Value = serde_json::from_str(t).expect("whole JSON");
        v["seed"].as_u64().unwrap()
    })
}

fn simulate_cmd(out: &Path, version: u64, _force: bool) -> Command {
    let mut c = aift();
    let urdf = common::repo("urdf/planar_2dof.urdf");
    c.args([
        "simulate",
        "--urdf",
        urdf.to_str().unwrap(),
        "--q0",
        "0.1,0.2",
        "--duration",
        &format!("{}", 1.0 + version as f64 * 1e-3),
        "--out",
        out.to_str().unwrap(),
    ]);
    c.stdout(Stdio::null()).stderr(Stdio::null());
    c
}

fn simulation_version(path: &Path) -> u64 {
    file_version(path, &|t| {
        assert!(t.ends_with('\n'), "a whole CSV ends with a newline");
        // Header, the initial state and one row per tick.
        t.lines().count() as u64 - 2 - 1000
    })
}

/// A campaign folder, its version in the campaign's name.
fn campaign_cmd(out: &Path, version: u64, force: bool) -> Command {
    let file = out.with_file_name(format!("c{version}.toml"));
    let reaching = "\n[reaching]\ntasks = 1\nduration = 1.0\ncalibration_runs = 2\n";
    std::fs::write(
        &file,
        common::tiny_campaign(&format!("v{version}"), reaching),
    )
    .unwrap();
    let mut c = aift();
    c.args([
        "campaign",
        file.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    if force {
        c.arg("--force");
    }
    c.stdout(Stdio::null()).stderr(Stdio::null());
    c
}

fn campaign_version(dir: &Path) -> u64 {
    let mut files = names(dir);
    files.retain(|n| !n.starts_with("heatmap_"));
    assert_eq!(
        files,
        sorted(&[
            ".aift-output",
            "campaign.csv",
            "campaign.json",
            "campaign.md",
            "reaching.csv",
            "records.json",
            "report.html",
        ]),
        "{}",
        dir.display()
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("campaign.json")).unwrap()).unwrap();
    let name = v["campaign"].as_str().unwrap().to_string();
    name.trim_start_matches('v').parse().unwrap()
}

#[test]
fn killed_calibrations_gp_trainings_and_simulations_leave_the_old_file_or_none() {
    kill_trials(&calibrate_cmd, &calibration_version, 10, 3);
    kill_trials(&train_gp_cmd, &gp_version, 10, 4);
    kill_trials(&simulate_cmd, &simulation_version, 10, 5);
}

#[test]
fn killed_campaigns_never_leave_a_partial_or_mixed_folder() {
    kill_trials(&campaign_cmd, &campaign_version, 10, 6);
}
