//! Methods of the caller's in campaigns: a method defined outside the library runs in every cell
//! and reaching task under its own name, through the same loop and metrics as the built-in ones;
//! its records merge, render and compare like theirs; the command line, which cannot run it,
//! refuses a campaign that lists one before any work.

mod common;

use std::path::{Path, PathBuf};

use aift::report::campaign_files;
use std::sync::atomic::{AtomicUsize, Ordering};

use aift::scenario::campaign::{
    Campaign, CampaignConfig, CampaignRecords, Journal, JournalMode, Shard, compare_all,
    run_campaign_with,
};
use aift::scenario::method::{ExternalMethod, MethodContext, MethodId, MethodParts, build};
use aift::scenario::{Method, RunSetup, ScenarioError};

/// The tests' campaign: no-FT and the oracle on the paper arm's encoder freeze (one seed), the
/// healthy cell and one reaching task.
fn campaign_file(dir: &Path) -> PathBuf {
    let text = common::tiny_campaign("outside", "\n[reaching]\ntasks = 1\nduration = 2.0\n");
    let path = dir.join("outside.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// The library's no-FT built from outside, as a user would build any method of their own.
fn no_ft_parts(setup: &RunSetup, seed: u64, _place: &str) -> Result<MethodParts, ScenarioError> {
    let nominal = setup.nominal_precisions();
    build(
        Method::NoFt,
        &MethodContext {
            setup,
            model: setup.estimator_model(seed),
            layout: &setup.layout,
            nominal: &nominal,
            calibration: None,
        },
    )
}

fn campaign_with_external(path: &Path) -> Campaign {
    let mut config = CampaignConfig::load(path).unwrap();
    config.external_methods = vec!["my-no-ft".into()];
    Campaign::from_config(config, path, &[]).unwrap()
}

fn run(campaign: &Campaign, shard: Shard) -> CampaignRecords {
    let external = [ExternalMethod::new("my-no-ft", &no_ft_parts)];
    run_campaign_with(campaign, shard, None, &|_, _| {}, None, &external).unwrap()
}

#[test]
fn an_external_method_runs_every_cell_and_task_as_a_built_in_one_would() {
    let tmp = tempfile::tempdir().unwrap();
    let campaign = campaign_with_external(&campaign_file(tmp.path()));
    let mine = MethodId::External("my-no-ft".into());
    assert_eq!(
        campaign.methods,
        vec![Method::NoFt.into(), Method::Oracle.into(), mine.clone()]
    );
    let records = run(&campaign, Shard::WHOLE);
    // Every cell (encoder 1 frozen, healthy) x 3 methods x 1 seed.
    assert_eq!(campaign.cells.len(), 2);
    assert_eq!(records.runs.len(), campaign.cells.len() * 3);
    let external: Vec<_> = records.runs.iter().filter(|r| r.method == mine).collect();
    assert_eq!(external.len(), campaign.cells.len());
    // The same parts as the built-in no-FT: the same numbers, bit for bit.
    for r in &external {
        let builtin = records
            .runs
            .iter()
            .find(|b| b.cell == r.cell && b.seed == r.seed && b.method == Method::NoFt)
            .unwrap();
        assert_eq!(r.mse_post.to_bits(), builtin.mse_post.to_bits());
        assert_eq!(
            (r.verdict, r.detected, r.false_alarms, r.recover_time),
            (
                builtin.verdict,
                builtin.detected,
                builtin.false_alarms,
                builtin.recover_time
            )
        );
    }
    let reach: Vec<_> = records.reaching.iter().map(|r| &r.method).collect();
    assert_eq!(reach.len(), 3, "one reaching task x 3 methods: {reach:?}");
    let (a, b) = (&records.reaching[0], &records.reaching[2]);
    assert_eq!((&b.method, a.method.name()), (&mine, "no-ft"));
    assert_eq!(a.belief_rmse.to_bits(), b.belief_rmse.to_bits());
    // Twice: the same records.
    assert_eq!(run(&campaign, Shard::WHOLE), records);
    // Compared with every other method; against no-FT it is never better nor worse.
    let pairs = compare_all(&campaign, &records.runs, 0.05);
    let vs_no_ft: Vec<_> = pairs
        .iter()
        .filter(|p| p.a == Method::NoFt && p.b == mine)
        .collect();
    assert_eq!(vs_no_ft.len(), campaign.cells.len());
    assert!(vs_no_ft.iter().all(|p| p.median_log10_ratio == 0.0));
}

#[test]
fn its_records_merge_render_and_compare_by_name_and_the_cli_refuses_to_run_it() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let file = campaign_file(d);
    let campaign = campaign_with_external(&file);
    let whole = run(&campaign, Shard::WHOLE);
    std::fs::create_dir(d.join("whole")).unwrap();
    campaign_files::write_campaign(&d.join("whole"), &campaign, &whole).unwrap();
    for k in 1..=2 {
        let shard = Shard { index: k, count: 2 };
        let dir = d.join(format!("s{k}"));
        std::fs::create_dir(&dir).unwrap();
        campaign_files::write_shard(&dir, &run(&campaign, shard)).unwrap();
    }
    common::aift_ok(&["merge", "s1", "s2", "--out", "merged"], d);
    for name in [
        "campaign.csv",
        "campaign.json",
        "campaign.md",
        "reaching.csv",
    ] {
        let text = std::fs::read_to_string(d.join("whole").join(name)).unwrap();
        assert!(text.contains("my-no-ft"), "{name} names the method");
        assert_eq!(
            text,
            std::fs::read_to_string(d.join("merged").join(name)).unwrap(),
            "{name}"
        );
    }
    let out = common::aift_ok(&["compare", "merged", "my-no-ft", "no-ft", "--json"], d);
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(doc["a"], "my-no-ft");
    assert_eq!(doc["cells"], campaign.cells.len());
    assert_eq!(
        (doc["a_better"].as_u64(), doc["b_better"].as_u64()),
        (Some(0), Some(0))
    );
    common::aift_ok(&["report", "merged"], d);
    let page = std::fs::read_to_string(d.join("merged/report.html")).unwrap();
    assert!(page.contains("my-no-ft"));
    // The command line cannot run a method of the caller's: exit 2 naming the key, no folder.
    let mut text = std::fs::read_to_string(&file).unwrap();
    text = text.replace(
        "methods = [\"no-ft\", \"oracle\"]",
        "methods = [\"no-ft\"]\nexternal_methods = [\"my-no-ft\"]",
    );
    std::fs::write(d.join("listed.toml"), text).unwrap();
    let out = common::aift_in(&["campaign", "listed.toml", "--out", "never"], d);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("external_methods") && err.contains("my-no-ft"),
        "{err}"
    );
    assert!(!d.join("never").exists());
}

#[test]
fn external_methods_are_checked_before_any_run() {
    let tmp = tempfile::tempdir().unwrap();
    let file = campaign_file(tmp.path());
    let config = CampaignConfig::load(&file).unwrap();
    let refused = |names: &[&str]| {
        let mut c = config.clone();
        c.external_methods = names.iter().map(|s| s.to_string()).collect();
        match c.check(&file) {
            Err(ScenarioError::Invalid { field, message, .. }) => {
                assert_eq!(field, "external_methods", "{message}");
                message
            }
            other => panic!("{names:?} accepted: {other:?}"),
        }
    };
    assert!(refused(&["hybrid"]).contains("built-in"));
    assert!(refused(&["a", "a"]).contains("twice"));
    assert!(refused(&["has space"]).contains("' '"));
    assert!(refused(&[""]).contains("1 to 64"));
    // A campaign that lists a method run without it, or given one it does not list: refused
    // before any job runs.
    let campaign = campaign_with_external(&file);
    let err = run_campaign_with(&campaign, Shard::WHOLE, None, &|_, _| {}, None, &[]).unwrap_err();
    assert!(err.to_string().contains("my-no-ft"), "{err}");
    let mine = ExternalMethod::new("my-no-ft", &no_ft_parts);
    let other = [mine, ExternalMethod::new("other", &no_ft_parts)];
    let err =
        run_campaign_with(&campaign, Shard::WHOLE, None, &|_, _| {}, None, &other).unwrap_err();
    assert!(err.to_string().contains("does not list"), "{err}");
    let twice = [
        ExternalMethod::new("my-no-ft", &no_ft_parts),
        ExternalMethod::new("my-no-ft", &no_ft_parts),
    ];
    let err =
        run_campaign_with(&campaign, Shard::WHOLE, None, &|_, _| {}, None, &twice).unwrap_err();
    assert!(err.to_string().contains("twice"), "{err}");
    // Only external methods: no built-in one runs.
    let mut c = CampaignConfig::load(&file).unwrap();
    c.methods = Some(vec![]);
    c.external_methods = vec!["my-no-ft".into()];
    assert_eq!(
        c.check(&file).unwrap(),
        vec![MethodId::External("my-no-ft".into())]
    );
}

/// A method that fails mid-campaign (as a Python exception does: the parts cannot return it)
/// stops the campaign with an error, and leaves in the journal no run from after its failure:
/// the campaign run again with the method mended resumes and ends with the records of an
/// uninterrupted run.
#[test]
fn a_failed_external_method_stops_the_campaign_and_its_journal_resumes_cleanly() {
    let tmp = tempfile::tempdir().unwrap();
    let campaign = campaign_with_external(&campaign_file(tmp.path()));
    let whole = run(&campaign, Shard::WHOLE);
    let built = AtomicUsize::new(0);
    // From its second run on it has failed, and its runs are another seed's (numbers unlike the
    // uninterrupted run's): if one of them were journaled, the resumed records would differ.
    let counting = |setup: &RunSetup, seed: u64, place: &str| {
        let k = built.fetch_add(1, Ordering::SeqCst);
        no_ft_parts(setup, if k >= 1 { seed + 1000 } else { seed }, place)
    };
    let failed = || built.load(Ordering::SeqCst) >= 2;
    let failing = [ExternalMethod {
        name: "my-no-ft".into(),
        build: &counting,
        failed: Some(&failed),
    }];
    let path = Journal::path_for(&tmp.path().join("out"));
    let (journal, _) = Journal::open(&path, &campaign, Shard::WHOLE, JournalMode::Fresh).unwrap();
    let err = run_campaign_with(
        &campaign,
        Shard::WHOLE,
        None,
        &|_, _| {},
        Some(&journal),
        &failing,
    )
    .unwrap_err();
    assert!(err.to_string().contains("failed in a run"), "{err}");
    drop(journal);
    let (journal, _) = Journal::open(&path, &campaign, Shard::WHOLE, JournalMode::Require).unwrap();
    let kept = (0..whole.runs.len())
        .filter(|&j| journal.run(j).is_some())
        .count();
    assert!(kept < whole.runs.len(), "every run journaled: {kept}");
    let external = [ExternalMethod::new("my-no-ft", &no_ft_parts)];
    let resumed = run_campaign_with(
        &campaign,
        Shard::WHOLE,
        None,
        &|_, _| {},
        Some(&journal),
        &external,
    )
    .unwrap();
    assert_eq!(resumed, whole);
}
