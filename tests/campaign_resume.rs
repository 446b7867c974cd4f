//! Campaigns that resume: a campaign (or shard) killed part way (SIGKILL, SIGTERM) keeps the jobs
//! it finished in its journal and never a partial output folder; running the same command again
//! redoes only the rest and writes the same bytes as an uninterrupted run. A torn journal line is
//! dropped, a journal of another configuration is replaced, `--resume` without a journal and
//! `--fresh` do what they say.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

/// About a hundred jobs of a few tens of milliseconds: long enough to be interrupted (the tiny
/// campaign at 12 seeds, 20 s, both joint sensor kinds, with a reaching benchmark).
fn write_campaign(dir: &Path) {
    let text = common::tiny_campaign("resume", "\n[reaching]\ntasks = 4\nduration = 4.0\n")
        .replace("seeds = 1", "seeds = 12")
        .replace("duration = 9.0", "duration = 20.0")
        .replace(r#"channels = ["enc*"]"#, r#"channels = ["enc*", "tach*"]"#);
    assert!(text.contains("seeds = 12") && text.contains("\"tach*\""));
    std::fs::write(dir.join("c.toml"), text).unwrap();
}

/// Every file under `dir`, by relative path, with its bytes.
fn tree(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

fn journal_lines(path: &Path) -> usize {
    std::fs::read(path)
        .map(|b| b.iter().filter(|c| **c == b'\n').count())
        .unwrap_or(0)
}

/// Starts `aift campaign c.toml --out OUT EXTRA...`, waits until its journal holds `lines` lines
/// (header included), sends `signal`, and waits for it to end. Returns false if the campaign
/// finished before it could be interrupted.
fn interrupt(dir: &Path, out: &str, extra: &[&str], lines: usize, signal: &str) -> bool {
    let mut args = vec!["campaign", "c.toml", "--out", out];
    args.extend_from_slice(extra);
    let mut child = common::aift_command(&args, dir)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let journal = dir.join(format!(".{out}.aift-journal"));
    let deadline = Instant::now() + Duration::from_secs(120);
    while journal_lines(&journal) < lines {
        if child.try_wait().unwrap().is_some() {
            return false;
        }
        assert!(Instant::now() < deadline, "no progress in the journal");
        std::thread::sleep(Duration::from_millis(5));
    }
    let status = std::process::Command::new("kill")
        .args([signal, &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let ended = child.wait().unwrap();
    assert!(
        !ended.success(),
        "{signal}: the campaign was not interrupted"
    );
    true
}

/// Runs the same command again: it must resume, and write what `reference` holds.
fn resume_and_compare(dir: &Path, out: &str, extra: &[&str], reference: &Path) {
    let journal = dir.join(format!(".{out}.aift-journal"));
    let before = journal_lines(&journal);
    assert!(before >= 2, "the journal kept no finished job");
    assert!(
        !dir.join(out).exists(),
        "a partial output folder is in place"
    );
    let mut args = vec!["campaign", "c.toml", "--out", out];
    args.extend_from_slice(extra);
    let o = common::aift_ok(&args, dir);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(&format!("{} of", before - 1)) && err.contains("already done"),
        "{err}"
    );
    assert!(err.contains("s of work kept"), "{err}");
    assert!(
        !journal.exists(),
        "the journal outlived the finished campaign"
    );
    let (a, b) = (tree(reference), tree(&dir.join(out)));
    assert_eq!(
        a.keys().collect::<Vec<_>>(),
        b.keys().collect::<Vec<_>>(),
        "{out}: other files"
    );
    for (name, bytes) in &a {
        assert!(
            b[name] == *bytes,
            "{out}: {} differs from the uninterrupted run's",
            name.display()
        );
    }
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(&format!(".{out}.aift-")))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn a_killed_campaign_resumes_to_the_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_campaign(dir);
    common::aift_ok(&["campaign", "c.toml", "--out", "whole"], dir);
    let reference = dir.join("whole");
    let total = std::fs::read_to_string(reference.join("campaign.csv"))
        .unwrap()
        .lines()
        .count();
    assert!(total > 50, "{total}");
    let mut interrupted = 0;
    for (k, (signal, lines)) in [("-KILL", 3), ("-TERM", 30), ("-KILL", 70)]
        .into_iter()
        .enumerate()
    {
        let out = format!("run{k}");
        if interrupt(dir, &out, &[], lines, signal) {
            interrupted += 1;
            resume_and_compare(dir, &out, &[], &reference);
        }
    }
    assert!(
        interrupted >= 2,
        "the campaign ran out before it could be killed"
    );
}

#[test]
fn a_killed_shard_resumes_and_a_torn_line_is_dropped() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_campaign(dir);
    let shard = ["--shard", "2/3"];
    common::aift_ok(
        &["campaign", "c.toml", "--out", "whole", "--shard", "2/3"],
        dir,
    );
    assert!(interrupt(dir, "part", &shard, 8, "-KILL"));
    // A kill in the middle of a write leaves a line without its end: it is dropped.
    let journal = dir.join(".part.aift-journal");
    let mut bytes = std::fs::read(&journal).unwrap();
    let kept = journal_lines(&journal);
    bytes.extend_from_slice(b"{\"job\": 4, \"seconds\": 0.1, \"run\": {\"job\"");
    std::fs::write(&journal, bytes).unwrap();
    assert_eq!(journal_lines(&journal), kept);
    resume_and_compare(dir, "part", &shard, &dir.join("whole"));
}

#[test]
fn journals_of_other_runs_are_replaced_and_the_flags_do_what_they_say() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_campaign(dir);
    // Nothing to resume.
    let o = common::aift_in(&["campaign", "c.toml", "--out", "a", "--resume"], dir);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--resume") && err.contains("no journal"),
        "{err}"
    );
    assert!(!dir.join("a").exists() && !dir.join(".a.aift-journal").exists());
    // A journal of the campaign with other settings is not used.
    assert!(interrupt(dir, "a", &["--set", "duration=19.0"], 5, "-KILL"));
    let o = common::aift_in(&["campaign", "c.toml", "--out", "a", "--resume"], dir);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let o = common::aift_ok(&["campaign", "c.toml", "--out", "a", "--seeds", "1"], dir);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("starting afresh") && err.contains("another configuration"),
        "{err}"
    );
    // --fresh discards a matching journal.
    assert!(interrupt(dir, "b", &[], 5, "-KILL"));
    let o = common::aift_ok(&["campaign", "c.toml", "--out", "b", "--fresh"], dir);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("already done"), "{err}");
    assert!(!dir.join(".b.aift-journal").exists());
    // A journal another build wrote (its source digest in the header) is never resumed: the
    // version stays the same between commits, the code does not.
    assert!(interrupt(dir, "c", &[], 5, "-KILL"));
    let journal = dir.join(".c.aift-journal");
    let text = std::fs::read_to_string(&journal).unwrap();
    let (header, rest) = text.split_once('\n').unwrap();
    let mut header: serde_json::Value = serde_json::from_str(header).unwrap();
    let ours = header["build"].as_str().unwrap().to_string();
    assert_eq!(ours.len(), 16, "{header}");
    header["build"] = serde_json::Value::from("0123456789abcdef");
    std::fs::write(&journal, format!("{header}\n{rest}")).unwrap();
    let o = common::aift_in(&["campaign", "c.toml", "--out", "c", "--resume"], dir);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("another build of aift"), "{err}");
    let o = common::aift_ok(&["campaign", "c.toml", "--out", "c"], dir);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("starting afresh") && err.contains(&ours) && !err.contains("already done"),
        "{err}"
    );
}
