//! The tree follows the method's data flow (ARCHITECTURE.md): each stage of `src/` uses only the
//! stages before it, so there are no circles between them. Checked from the code's own `crate::`
//! paths (comments left out).

use std::collections::BTreeSet;
use std::path::Path;

/// The stages in data-flow order; `fsio` and `settings` sit below them all.
const STAGES: &[&str] = &[
    "fsio",
    "settings",
    "arm",
    "plant",
    "sensors",
    "gp",
    "estimation",
    "control",
    "precision",
    "scenario",
    "logs",
    "report",
];

/// The `crate::NAME` paths a file's code (not its comments) uses.
fn uses(path: &Path) -> BTreeSet<String> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut out = BTreeSet::new();
    for line in text.lines() {
        let code = line.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(i) = rest.find("crate::") {
            let name: String = rest[i + 7..]
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            // `crate::SettingError`, `crate::tick_at` and `crate::error_chain` are the crate
            // root's (settings, fsio).
            let name = match name.as_str() {
                "SettingError" | "tick_at" | "check_window" => "settings".to_string(),
                "error_chain" => "fsio".to_string(),
                _ => name,
            };
            out.insert(name);
            rest = &rest[i + 7..];
        }
    }
    out
}

fn files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let p = entry.unwrap().path();
        if p.is_dir() {
            files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn each_stage_uses_only_the_stages_before_it() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut violations = Vec::new();
    for (rank, stage) in STAGES.iter().enumerate() {
        let mut paths = Vec::new();
        let dir = src.join(stage);
        if dir.is_dir() {
            files(&dir, &mut paths);
        } else {
            paths.push(src.join(format!("{stage}.rs")));
        }
        assert!(!paths.is_empty() && paths[0].exists(), "stage {stage}");
        for path in paths {
            for used in uses(&path) {
                match STAGES.iter().position(|s| *s == used) {
                    Some(r) if r <= rank => {}
                    Some(_) => violations.push(format!(
                        "{} uses crate::{used}, a later stage",
                        path.display()
                    )),
                    None => violations.push(format!(
                        "{} uses crate::{used}, which is no stage",
                        path.display()
                    )),
                }
            }
        }
    }
    assert!(violations.is_empty(), "{violations:#?}");
}
