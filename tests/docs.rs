//! The documents stay true to the program: the scenario reference is the one the loader's types
//! generate, and every relative link in README.md, docs/ and results/README.md resolves.
//! (The README's `aift ...` commands are parsed by the CLI's own unit tests,
//! src/bin/aift/doc_commands.rs.)

use std::path::{Path, PathBuf};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn the_scenario_reference_is_current() {
    let committed = std::fs::read_to_string(root().join("docs/scenario.md")).unwrap();
    let generated = aift::scenario::scenario_reference_markdown();
    assert!(
        committed == generated,
        "docs/scenario.md is stale: regenerate it with `aift schema --markdown > docs/scenario.md`"
    );
}

fn markdown_files() -> Vec<PathBuf> {
    let mut files = vec![root().join("README.md"), root().join("ARCHITECTURE.md")];
    for dir in ["docs", "results"] {
        for entry in std::fs::read_dir(root().join(dir)).unwrap() {
            let p = entry.unwrap().path();
            if p.extension().is_some_and(|x| x == "md") {
                files.push(p);
            }
        }
    }
    files.sort();
    files
}

/// Targets of inline links `[text](target)` outside code spans and fenced blocks.
fn links(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        let mut rest = line;
        while let Some(i) = rest.find("](") {
            let after = &rest[i + 2..];
            let Some(end) = after.find(')') else { break };
            out.push(after[..end].to_string());
            rest = &after[end..];
        }
    }
    out
}

#[test]
fn every_relative_link_resolves() {
    let mut broken = Vec::new();
    let mut checked = 0;
    for file in markdown_files() {
        let text = std::fs::read_to_string(&file).unwrap();
        for target in links(&text) {
            if target.contains("://") || target.starts_with('#') || target.starts_with("mailto:") {
                continue;
            }
            let path = target.split('#').next().unwrap();
            checked += 1;
            if !file.parent().unwrap().join(path).exists() {
                broken.push(format!("{}: {target}", file.display()));
            }
        }
    }
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
    assert!(checked > 10, "only {checked} links found");
}

#[test]
fn the_readme_cites_this_version() {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let line = format!("version = {{{}}}", env!("CARGO_PKG_VERSION"));
    assert!(
        readme.contains(&line),
        "README.md's citation lacks `{line}`"
    );
}
