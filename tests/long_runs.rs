//! Long runs: a run's memory does not grow with its length (the trajectory streams to its file,
//! every `record_every`-th tick), so a 2500 s run at 1 kHz needs what a 250 s run needs.

use std::process::{Command, Stdio};

/// Runs `aift run` with the overrides and returns (peak resident memory in MB, trajectory rows).
fn peak_memory_mb(overrides: &[&str]) -> (f64, usize) {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_aift"));
    cmd.arg("run")
        .args(["--out", out.to_str().unwrap()])
        .env("AIFT_CACHE_DIR", "off")
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    for o in overrides {
        cmd.args(["--set", o]);
    }
    #[allow(clippy::zombie_processes)] // reaped by wait4 below, which also gives its rusage
    let child = cmd.spawn().unwrap();
    let mut status = 0;
    // SAFETY: a zeroed rusage is a valid value; wait4 fills it for our own child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = unsafe { libc::wait4(child.id() as i32, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as i32);
    assert!(libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0);
    let rows = std::fs::read_to_string(out.join("trajectory.csv"))
        .unwrap()
        .lines()
        .count()
        - 1;
    // ru_maxrss is in kilobytes on Linux.
    (usage.ru_maxrss as f64 / 1024.0, rows)
}

#[test]
fn a_2500_s_run_at_1_khz_runs_in_bounded_memory() {
    let (short, short_rows) = peak_memory_mb(&["duration=250.0", "record_every=100"]);
    let (long, long_rows) = peak_memory_mb(&["duration=2500.0", "record_every=100"]);
    eprintln!(
        "peak resident memory: {short:.1} MB for 250 s ({short_rows} rows), {long:.1} MB for \
         2500 s ({long_rows} rows, 2.5e6 ticks)"
    );
    assert_eq!(short_rows, 2500);
    assert_eq!(long_rows, 25_000);
    // Ten times the ticks, the same memory (a few MB of allocator noise allowed).
    assert!(long < short + 8.0, "{long} MB vs {short} MB");
    assert!(long < 200.0, "{long} MB");
}
