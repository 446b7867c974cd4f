//! The documents' `aift ...` commands are accepted by this CLI (issue: documents that drift
//! from the program). Every line starting with `aift ` in a `sh`/`bash`/`console` code block of
//! README.md and docs/*.md must parse as the CLI parses it; every line of a `text` block (the
//! README's synopsis) must name a subcommand and only flags that subcommand has.

use clap::{CommandFactory, Parser};
use std::path::{Path, PathBuf};

use crate::args::Cli;

fn documents() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = vec![root.join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(root.join("docs"))
        .expect("docs/ exists")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    docs.sort();
    files.extend(docs);
    files
}

/// (language, lines joined over `\` continuations) of every fenced block.
fn code_blocks(text: &str) -> Vec<(String, Vec<String>)> {
    let mut blocks = Vec::new();
    let mut current: Option<(String, Vec<String>)> = None;
    for line in text.lines() {
        let trimmed = line.trim_start();
        if let Some(rest) = trimmed.strip_prefix("```") {
            match current.take() {
                Some(block) => blocks.push(block),
                None => current = Some((rest.trim().to_string(), Vec::new())),
            }
            continue;
        }
        if let Some((_, lines)) = current.as_mut() {
            match lines.last_mut() {
                Some(last) if last.ends_with('\\') => {
                    last.pop();
                    last.push(' ');
                    last.push_str(line.trim());
                }
                _ => lines.push(line.trim().to_string()),
            }
        }
    }
    blocks
}

/// The command of a shell line from `aift` to the first pipe, redirection, `&&`, `;` or comment,
/// with shell expansions replaced by a plain value.
fn aift_words(line: &str) -> Option<Vec<String>> {
    let line = line.trim().trim_start_matches("$ ");
    let start = line.find("aift ").filter(|&i| i == 0)?;
    let mut cmd = line[start..].to_string();
    for stop in [" #", " |", " >", " 2>", " &&", ";"] {
        if let Some(i) = cmd.find(stop) {
            cmd.truncate(i);
        }
    }
    // $((EXPR)) and $VAR become 1: the shapes of the values are what matters here.
    while let Some(i) = cmd.find("$((") {
        let end = cmd[i..].find("))").map(|j| i + j + 2).unwrap_or(cmd.len());
        cmd.replace_range(i..end, "1");
    }
    while let Some(i) = cmd.find('$') {
        let end = cmd[i + 1..]
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .map(|j| i + 1 + j)
            .unwrap_or(cmd.len());
        cmd.replace_range(i..end, "1");
    }
    shlex::split(&cmd)
}

#[test]
fn every_documented_command_parses() {
    let mut checked = 0;
    let mut failures = Vec::new();
    for file in documents() {
        let text = std::fs::read_to_string(&file).unwrap();
        for (lang, lines) in code_blocks(&text) {
            if !matches!(lang.as_str(), "sh" | "bash" | "console" | "shell") {
                continue;
            }
            for line in lines {
                let Some(words) = aift_words(&line) else {
                    continue;
                };
                checked += 1;
                if let Err(e) = Cli::try_parse_from(&words) {
                    failures.push(format!("{}: `{line}`: {}", file.display(), e.kind()));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(checked >= 5, "only {checked} commands found");
}

#[test]
fn the_synopsis_names_real_subcommands_and_flags() {
    let cli = Cli::command();
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md")).unwrap();
    let mut checked = 0;
    for (lang, lines) in code_blocks(&readme) {
        if lang != "text" {
            continue;
        }
        for line in lines {
            let Some(rest) = line.strip_prefix("aift ") else {
                continue;
            };
            let name = rest.split_whitespace().next().unwrap();
            let sub = cli
                .find_subcommand(name)
                .unwrap_or_else(|| panic!("synopsis `{line}`: no subcommand {name}"));
            let longs: Vec<String> = sub
                .get_arguments()
                .flat_map(|a| {
                    a.get_long_and_visible_aliases()
                        .unwrap_or_default()
                        .into_iter()
                        .map(str::to_string)
                })
                .collect();
            for flag in line
                .split(|c: char| c.is_whitespace() || "[]|()".contains(c))
                .filter_map(|w| w.strip_prefix("--"))
            {
                let flag = flag.split('=').next().unwrap();
                assert!(
                    longs.iter().any(|l| l == flag),
                    "synopsis `{line}`: `{name}` has no --{flag}"
                );
            }
            checked += 1;
        }
    }
    // every subcommand but `help` is in the synopsis
    assert_eq!(checked, cli.get_subcommands().count(), "synopsis lines");
}
