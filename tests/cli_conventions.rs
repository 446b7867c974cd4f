//! Conventions users expect of a command line: `--json` prints one JSON document on stdout (the
//! file the command wrote, as written) with everything else on stderr, each document carries a
//! `format_version`, `aift completions SHELL` prints a completion script, a command the CLI
//! suggests can be pasted into a shell, a "wrote" line names the files written, and an option
//! that does nothing says so.

mod common;

use std::path::Path;
use std::process::{Command, Output};

use common::aift_ok as aift;

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
    std::fs::write(&file, common::tiny_campaign("tiny", "")).unwrap();
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

/// The schema's object for `schema`, following `$ref`s into `$defs`.
fn resolve<'a>(
    root: &'a serde_json::Value,
    schema: &'a serde_json::Value,
) -> &'a serde_json::Value {
    match schema.get("$ref").and_then(|r| r.as_str()) {
        Some(r) => {
            let name = r.trim_start_matches("#/$defs/");
            resolve(root, &root["$defs"][name])
        }
        None => schema,
    }
}

/// Every alternative a schema allows (anyOf / oneOf / allOf members, or itself).
fn alternatives<'a>(
    root: &'a serde_json::Value,
    schema: &'a serde_json::Value,
) -> Vec<&'a serde_json::Value> {
    let s = resolve(root, schema);
    let mut out = vec![s];
    for key in ["anyOf", "oneOf", "allOf"] {
        if let Some(list) = s.get(key).and_then(|l| l.as_array()) {
            for a in list {
                out.extend(alternatives(root, a));
            }
        }
    }
    out
}

/// Checks that every key of `value` is a property the schema names, recursively; returns the
/// paths of keys it does not know.
fn unknown_keys(
    root: &serde_json::Value,
    schema: &serde_json::Value,
    value: &toml::Value,
    path: &str,
    out: &mut Vec<String>,
) {
    let alts = alternatives(root, schema);
    match value {
        toml::Value::Table(t) => {
            for (k, v) in t {
                let sub: Vec<&serde_json::Value> = alts
                    .iter()
                    .filter_map(|a| a.get("properties").and_then(|p| p.get(k)))
                    .collect();
                if sub.is_empty() {
                    out.push(format!("{path}.{k}"));
                } else {
                    unknown_keys(root, sub[0], v, &format!("{path}.{k}"), out);
                }
            }
        }
        toml::Value::Array(items) => {
            if let Some(item_schema) = alts.iter().find_map(|a| a.get("items")) {
                for (i, v) in items.iter().enumerate() {
                    unknown_keys(root, item_schema, v, &format!("{path}[{i}]"), out);
                }
            }
        }
        _ => {}
    }
}

#[test]
fn the_schema_knows_every_key_of_every_bundled_scenario_and_refuses_others() {
    let tmp = tempfile::tempdir().unwrap();
    let out = aift(&["schema"], tmp.path());
    let schema = json_of(&out);
    assert!(
        schema["$schema"]
            .as_str()
            .unwrap()
            .contains("json-schema.org")
    );
    assert_eq!(schema["additionalProperties"], false);
    let mut files = 0;
    for entry in std::fs::read_dir(common::repo("assets/scenarios")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let value: toml::Value =
                toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
            let mut unknown = Vec::new();
            unknown_keys(&schema, &schema, &value, "", &mut unknown);
            assert!(unknown.is_empty(), "{}: {unknown:?}", path.display());
            files += 1;
        }
    }
    assert!(files >= 10);
    // A key the loader refuses is not in the schema either.
    let bad: toml::Value = toml::from_str("[robot]\nurdf = \"x\"\nsolver_iteration = 2\n").unwrap();
    let mut unknown = Vec::new();
    unknown_keys(&schema, &schema, &bad, "", &mut unknown);
    assert_eq!(unknown, vec![".robot.solver_iteration".to_string()]);
}

/// `init` into a path with a space suggests a run command a shell splits back into that path;
/// the run's "wrote" line names exactly the files its folder holds (not its hidden marker);
/// `--calib` with a method that needs no detector calibration is reported as unused (a
/// warning: the run goes on).
#[test]
fn suggested_commands_paste_wrote_lines_name_the_files_and_unused_options_say_so() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    std::fs::copy(common::repo("urdf/planar_2dof.urdf"), d.join("my arm.urdf")).unwrap();
    let o = aift(
        &[
            "init",
            "--urdf",
            "my arm.urdf",
            "--out",
            "my arm.toml",
            "--no-check",
        ],
        d,
    );
    let text = String::from_utf8_lossy(&o.stdout).into_owned();
    let suggested = text
        .split('`')
        .nth(1)
        .unwrap_or_else(|| panic!("no command in {text:?}"));
    assert_eq!(
        shlex::split(suggested).unwrap(),
        ["aift", "run", "my arm.toml"],
        "{text}"
    );
    std::fs::write(d.join("unused.json"), "{}").unwrap();
    let o = aift(
        &[
            "run",
            "my arm.toml",
            "--method",
            "no-ft",
            "--set",
            "duration=0.3",
            "--calib",
            "unused.json",
            "--out",
            "out",
        ],
        d,
    );
    let all = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        all.contains("--calib unused.json is not used") && all.contains("no-ft"),
        "{all}"
    );
    let wrote = all
        .lines()
        .find_map(|l| l.strip_prefix("wrote out/: "))
        .unwrap_or_else(|| panic!("no wrote line in {all}"));
    let mut files: Vec<String> = std::fs::read_dir(d.join("out"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| name != ".aift-output")
        .collect();
    files.sort();
    assert!(files.len() >= 5, "{files:?}");
    assert_eq!(wrote, files.join(", "));
    assert!(d.join("out/.aift-output").is_file());
}

/// A campaign warns, as `aift run` does, about a template's target that a shorter
/// `[defaults] duration` leaves after the run's end (it ran silently).
#[test]
fn a_campaign_warns_about_a_templates_target_after_the_runs_end() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let template = common::repo("assets/scenarios/paper_healthy.toml");
    std::fs::write(
        d.join("c.toml"),
        format!(
            "name = \"short\"\nseeds = 1\nmethods = [\"no-ft\"]\nchannels = [\"enc1\"]\n\n\
             [defaults]\nduration = 3.0\nplant = {{ engine = \"articulated\" }}\n\n\
             [onsets]\nrest = 1.5\n\n[[arms]]\nname = \"paper\"\nscenario = \"{}\"\n\n\
             [[kinds]]\nkind = \"freeze\"\nonsets = [\"rest\"]\n",
            template.display()
        ),
    )
    .unwrap();
    let o = aift(&["campaign", "c.toml", "--out", "o"], d);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{stderr}");
    assert!(
        stderr.contains("warning: arm paper (")
            && stderr.contains("`targets[1].time` 7.5 s is not before the run's end (3 s)"),
        "{stderr}"
    );
}
