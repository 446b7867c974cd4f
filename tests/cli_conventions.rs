//! Conventions users expect of a command line: `--json` prints one JSON document on stdout (the
//! file the command wrote, as written) with everything else on stderr, each document carries a
//! `format_version`, and `aift completions SHELL` prints a completion script.

mod common;

use std::path::Path;
use std::process::{Command, Output};

fn aift(args: &[&str], dir: &Path) -> Output {
    let out = Command::new(env!("CARGO_BIN_EXE_aift"))
        .args(args)
        .current_dir(dir)
        .env("AIFT_CACHE_DIR", "off")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// stdout parsed as exactly one JSON document.
fn json_of(out: &Output) -> serde_json::Value {
    let text = String::from_utf8(out.stdout.clone()).unwrap();
    let mut stream = serde_json::Deserializer::from_str(&text).into_iter::<serde_json::Value>();
    let doc = stream
        .next()
        .expect("a document")
        .unwrap_or_else(|e| panic!("stdout is not JSON ({e}):\n{text}"));
    assert!(stream.next().is_none(), "more than one document:\n{text}");
    doc
}

fn file_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn json_documents_are_the_files_written_and_nothing_else() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let scenario = common::repo("assets/scenarios/paper_encoder_freeze.toml");
    let scenario = scenario.to_str().unwrap();

    let urdf = common::repo("urdf/planar_2dof.urdf");
    let out = aift(&["check-urdf", urdf.to_str().unwrap(), "--json"], dir);
    let doc = json_of(&out);
    assert_eq!(doc["format_version"], 1);
    assert_eq!(doc["joints"].as_array().unwrap().len(), 2);
    assert_eq!(doc["end_effector"], "ee");
    assert!(doc["total_mass"].as_f64().unwrap() > 0.0);

    let out = aift(
        &[
            "run",
            scenario,
            "--set",
            "duration=9.0",
            "--out",
            "r",
            "--json",
        ],
        dir,
    );
    let doc = json_of(&out);
    assert_eq!(doc, file_json(&dir.join("r/summary.json")));
    assert!(doc["format_version"].is_u64());
    // The lines for people went to stderr.
    assert!(String::from_utf8_lossy(&out.stderr).contains("outcome: completed"));

    let out = aift(
        &[
            "table",
            scenario,
            "--set",
            "duration=9.0",
            "--seeds",
            "2",
            "--methods",
            "no-ft,pl-always",
            "--out",
            "t",
            "--json",
        ],
        dir,
    );
    let doc = json_of(&out);
    assert_eq!(doc, file_json(&dir.join("t/table.json")));
    assert!(doc["format_version"].is_u64());
}

#[test]
fn campaign_json_whole_and_sharded() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let file = dir.join("tiny.toml");
    std::fs::write(
        &file,
        format!(
            r#"
name = "tiny"
seeds = 1
methods = ["no-ft", "oracle"]
set = ["robot.engine=\"articulated\"", "duration=9.0"]
channels = ["enc*"]

[[arms]]
name = "paper"
scenario = "{}"

[[kinds]]
kind = "freeze"
onsets = ["moving"]
"#,
            common::repo("assets/scenarios/paper_healthy.toml").display()
        ),
    )
    .unwrap();
    let file = file.to_str().unwrap();
    let out = aift(&["campaign", file, "--out", "c", "--json"], dir);
    let doc = json_of(&out);
    assert_eq!(doc, file_json(&dir.join("c/campaign.json")));
    assert!(doc["format_version"].is_u64());

    let out = aift(
        &["campaign", file, "--shard", "1/2", "--out", "s1", "--json"],
        dir,
    );
    let doc = json_of(&out);
    assert_eq!(doc["shard"], "1/2");
    assert_eq!(doc["campaign"], "tiny");
    assert!(dir.join("s1/records.json").is_file());
}

#[test]
fn completion_scripts_for_every_shell() {
    let tmp = tempfile::tempdir().unwrap();
    for shell in ["bash", "zsh", "fish", "elvish", "powershell"] {
        let out = aift(&["completions", shell], tmp.path());
        let text = String::from_utf8(out.stdout).unwrap();
        assert!(
            text.contains("campaign") && text.contains("check-urdf"),
            "{shell}: the script names no subcommand"
        );
    }
    let bad = Command::new(env!("CARGO_BIN_EXE_aift"))
        .args(["completions", "tcsh"])
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
}
