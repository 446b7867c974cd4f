//! The fault campaign: the grid expands as the file says; shards merged write the same files as
//! the unsharded run, byte for byte; a cell is flagged "worse than no-FT" exactly when the rule
//! says so; false alarms per hour are counted on healthy cells.

mod common;

use std::path::Path;
use std::process::Command;

use aift::scenario::campaign::{
    CampaignConfig, Onset, Verdict, expand, summarise, worse_than_no_ft,
};

fn small_campaign(dir: &Path) -> std::path::PathBuf {
    let text = format!(
        r#"
name = "small"
seeds = 2
methods = ["no-ft", "oracle", "deterministic", "pl-always"]
defaults = {{ duration = 10.0, plant = {{ engine = "articulated" }}, detector = {{ calibration_runs = 8 }} }}
channels = ["enc*", "tach*"]

[[arms]]
name = "paper"
scenario = "{}"

[[kinds]]
kind = "freeze"
onsets = ["moving", "rest"]

[[pairs]]
label = "enc freeze, then cam bias"
faults = [
    {{ channel = "enc*", kind = "freeze", start = 8.0 }},
    {{ channel = "cam", kind = "bias", offset = 0.04, start = 9.0 }},
]

[reaching]
tasks = 2
duration = 3.0
calibration_runs = 4
"#,
        common::repo("assets/scenarios/paper_healthy.toml").display()
    );
    let path = dir.join("small.toml");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn the_grid_expands_as_the_file_says() {
    let text = r#"
name = "g"
channels = ["enc*", "tach*", "cam", "enc2"]
arms = [
  { name = "a", scenario = "x.toml", joints = [1, 3] },
  { name = "b", scenario = "y.toml" },
]
[[kinds]]
kind = "freeze"
onsets = ["moving", "rest", "rest-then-motion"]
[[kinds]]
kind = "bias"
offset = { enc = 0.05, tach = 0.1, cam = 0.04 }
[[pairs]]
label = "p"
faults = [{ channel = "tach*", kind = "freeze", start = 8.0 }]
"#;
    let config: CampaignConfig = toml::from_str(text).unwrap();
    let cells = expand(&config, &config.onsets);
    // Arm a: channels enc1, enc3, tach1, tach3, cam, enc2 (6); b: enc1, tach1, cam, enc2 (4).
    // Per channel 3 freeze onsets + 1 bias; a healthy cell and one pair per arm.
    assert_eq!(cells.len(), (1 + 6 * 4 + 1) + (1 + 4 * 4 + 1));
    let a: Vec<&str> = cells
        .iter()
        .filter(|c| c.arm == 0)
        .map(|c| c.label.as_str())
        .collect();
    assert_eq!(a[0], "healthy");
    assert!(a.contains(&"enc3 freeze rest-then-motion"));
    assert!(a.contains(&"tach3 bias moving"));
    assert!(a.contains(&"cam freeze rest"));
    let rest = cells
        .iter()
        .find(|c| c.label == "enc1 freeze rest")
        .unwrap();
    assert!(rest.rest && rest.onset == Some(Onset::Rest));
    assert_eq!(rest.faults[0].start, 5.0);
    let moving = cells
        .iter()
        .find(|c| c.label == "tach1 bias moving")
        .unwrap();
    assert!(!moving.rest);
    assert_eq!(moving.faults[0].start, 8.0);
    assert_eq!(
        moving.faults[0].kind,
        aift::sensors::FaultKind::Bias { offset: 0.1 }
    );
    let pair = cells.iter().find(|c| c.label == "p" && c.arm == 0).unwrap();
    assert_eq!(pair.faults[0].channel.label(), "tach1");
    // A size per group goes to the channel's group.
    let cam = cells.iter().find(|c| c.label == "cam bias moving").unwrap();
    assert_eq!(
        cam.faults[0].kind,
        aift::sensors::FaultKind::Bias { offset: 0.04 }
    );
}

/// The timing kinds expand like the others; garbage's range is per sensor group.
#[test]
fn timing_kinds_expand_with_their_parameters() {
    use aift::sensors::FaultKind;
    let text = r#"
name = "t"
channels = ["enc*", "tach*", "cam"]
arms = [{ name = "a", scenario = "x.toml" }]
[[kinds]]
kind = "delayed"
delay = 0.05
[[kinds]]
kind = "slow"
period = 0.1
onsets = ["rest"]
[[kinds]]
kind = "intermittent"
period = 0.2
duty = 0.5
[[kinds]]
kind = "garbage"
low = { enc = -3.0, tach = -10.0, cam = 0.0 }
high = { enc = 3.0, tach = 10.0, cam = 1.0 }
"#;
    let config: CampaignConfig = toml::from_str(text).unwrap();
    let cells = expand(&config, &config.onsets);
    assert_eq!(cells.len(), 1 + 3 * 4);
    let kind = |label: &str| cells.iter().find(|c| c.label == label).unwrap().faults[0].kind;
    assert_eq!(
        kind("enc1 delayed moving"),
        FaultKind::Delayed { delay: 0.05 }
    );
    assert_eq!(kind("cam slow rest"), FaultKind::Slow { period: 0.1 });
    assert_eq!(
        kind("tach1 intermittent moving"),
        FaultKind::Intermittent {
            period: 0.2,
            duty: 0.5
        }
    );
    assert_eq!(
        kind("tach1 garbage moving"),
        FaultKind::Garbage {
            low: -10.0,
            high: 10.0
        }
    );
    assert_eq!(
        kind("cam garbage moving"),
        FaultKind::Garbage {
            low: 0.0,
            high: 1.0
        }
    );
}

/// Actuator kinds expand over each arm's joints and the actuator onsets; disturbance cells are
/// one per arm; neither is healthy.
#[test]
fn actuator_and_disturbance_cells_expand() {
    use aift::plant::ActuatorFaultKind;
    let text = r#"
name = "a"
channels = []
arms = [{ name = "a", scenario = "x.toml", joints = [1, 3] }]
actuator_kinds = [{ kind = "locked" }, { kind = "effectiveness", factor = 0.5 }]
actuator_onsets = ["moving", "rest"]
[[disturbance_cells]]
label = "push"
disturbances = [{ kind = "push", link = "ee", start = 8.0, end = 8.2, force = [0.0, 0.0, 50.0] }]
"#;
    let config: CampaignConfig = toml::from_str(text).unwrap();
    let cells = expand(&config, &config.onsets);
    assert_eq!(cells.len(), 1 + 2 * 2 * 2 + 1);
    let locked = cells
        .iter()
        .find(|c| c.label == "motor3 locked rest")
        .unwrap();
    assert!(locked.rest && !locked.is_healthy());
    assert_eq!(locked.kind, "actuator-locked");
    assert_eq!(locked.actuator_faults[0].start, 5.0);
    assert_eq!(locked.actuator_faults[0].kind, ActuatorFaultKind::Locked {});
    let eff = cells
        .iter()
        .find(|c| c.label == "motor1 effectiveness moving")
        .unwrap();
    assert_eq!(eff.actuator_faults[0].start, 8.0);
    let push = cells.iter().find(|c| c.label == "push").unwrap();
    assert!(!push.is_healthy() && push.faults.is_empty() && push.actuator_faults.is_empty());
    assert_eq!(push.kind, "disturbance");
}

/// The bundled campaign files parse and expand to the grids their comments promise.
#[test]
fn the_bundled_campaigns_expand_to_their_grids() {
    let load = |name: &str| -> CampaignConfig {
        let path = common::repo(&format!("assets/campaigns/{name}"));
        toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
    };
    let default = load("default.toml");
    assert_eq!(expand(&default, &default.onsets).len(), 234);
    assert_eq!(default.arms.len(), 6);
    let actuators = load("actuators.toml");
    // Per arm: healthy + 5 channels x 4 timing kinds + 2 joints x 6 actuator kinds + 3
    // disturbance cells (one with an obstacle on the path).
    let cells = expand(&actuators, &actuators.onsets);
    assert_eq!(cells.len(), 2 * (1 + 20 + 12 + 3));
    assert_eq!(cells.iter().filter(|c| c.contact.is_some()).count(), 2);
    let reaching = load("reaching.toml");
    let cells = expand(&reaching, &reaching.onsets);
    assert_eq!(cells.len(), 6);
    assert!(cells.iter().all(|c| c.label == "healthy"));
    assert_eq!(reaching.reaching.as_ref().unwrap().tasks, 100);
}

#[test]
fn merged_shards_equal_the_unsharded_run_byte_for_byte() {
    let tmp = tempfile::tempdir().unwrap();
    let file = small_campaign(tmp.path());
    let file = file.to_str().unwrap();
    common::aift_ok(&["campaign", file, "--out", "whole"], tmp.path());
    for k in 1..=3 {
        common::aift_ok(
            &[
                "campaign",
                file,
                "--shard",
                &format!("{k}/3"),
                "--out",
                &format!("s{k}"),
            ],
            tmp.path(),
        );
    }
    common::aift_ok(&["merge", "s1", "s2", "s3", "--out", "merged"], tmp.path());
    let whole = tmp.path().join("whole");
    let merged = tmp.path().join("merged");
    let mut names: Vec<String> = std::fs::read_dir(&whole)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    for expected in [
        "campaign.csv",
        "campaign.json",
        "campaign.md",
        "heatmap_paper.svg",
        "reaching.csv",
        "records.json",
    ] {
        assert!(
            names.iter().any(|n| n == expected),
            "{expected} missing: {names:?}"
        );
    }
    for name in &names {
        assert_eq!(
            std::fs::read(whole.join(name)).unwrap(),
            std::fs::read(merged.join(name)).unwrap(),
            "{name} differs"
        );
    }
    // Incomplete or repeated shards are refused (exit 2).
    let out = Command::new(env!("CARGO_BIN_EXE_aift"))
        .args(["merge", "s1", "s2", "--out", "bad"])
        .current_dir(tmp.path())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing"));
    let out = Command::new(env!("CARGO_BIN_EXE_aift"))
        .args(["merge", "s1", "s1", "s2", "s3", "--out", "bad"])
        .current_dir(tmp.path())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(!tmp.path().join("bad").exists());
}

#[test]
fn flags_and_false_alarms_follow_their_definitions() {
    let tmp = tempfile::tempdir().unwrap();
    let file = small_campaign(tmp.path());
    // A detector this permissive (alpha 0.9) false-alarms on healthy runs.
    let campaign = aift::scenario::campaign::Campaign::load(
        &file,
        &[
            "detector.alpha=0.9".to_string(),
            "detector.rearm_ticks=50".to_string(),
        ],
    )
    .unwrap();
    let records = aift::scenario::campaign::run_campaign(
        &campaign,
        aift::scenario::campaign::Shard::WHOLE,
        None,
        &|_, _| {},
    )
    .unwrap();
    let (cells, methods) = summarise(&campaign, &records.runs);
    let tolerance = campaign.config.verdict.tolerance;
    let mut flagged = 0;
    for s in &cells {
        let no_ft = cells
            .iter()
            .find(|o| o.cell == s.cell && o.method == aift::scenario::Method::NoFt)
            .unwrap();
        let expected = s.method != aift::scenario::Method::NoFt
            && worse_than_no_ft(
                s.mse_post_mean,
                s.final_error_mean,
                no_ft.mse_post_mean,
                no_ft.final_error_mean,
                tolerance,
            );
        assert_eq!(s.worse_than_no_ft, expected, "{s:?}");
        flagged += usize::from(expected);
        // The worst seed's verdict.
        let worst = records
            .runs
            .iter()
            .filter(|r| r.cell == s.cell && r.method == s.method)
            .map(|r| r.verdict)
            .max()
            .unwrap();
        assert_eq!(s.verdict, worst);
    }
    eprintln!("{flagged} cells flagged worse than no-FT");
    // Healthy cell: false alarms per hour = alarms / simulated hours.
    let healthy = campaign.cells.iter().position(|c| c.is_healthy()).unwrap();
    let det = cells
        .iter()
        .find(|s| s.cell == healthy && s.method == aift::scenario::Method::Deterministic)
        .unwrap();
    let runs: Vec<_> = records
        .runs
        .iter()
        .filter(|r| r.cell == healthy && r.method == aift::scenario::Method::Deterministic)
        .collect();
    let alarms: usize = runs.iter().map(|r| r.false_alarms).sum();
    let hours: f64 = runs.iter().map(|r| r.hours).sum();
    eprintln!(
        "deterministic at alpha 0.9 on the healthy cell: {alarms} alarms in {hours:.4} h = {:.1}/h",
        det.false_alarms_per_hour
    );
    assert!(alarms > 0);
    assert!((det.false_alarms_per_hour - alarms as f64 / hours).abs() < 1e-9);
    assert!((hours - 2.0 * 10.0 / 3600.0).abs() < 1e-12);
    let summary = methods
        .iter()
        .find(|m| m.method == aift::scenario::Method::Deterministic)
        .unwrap();
    assert!(summary.false_alarms_per_hour > 0.0);
    // The oracle recovers the encoder freeze at rest.
    let cell = campaign
        .cells
        .iter()
        .position(|c| c.label == "enc1 freeze rest")
        .unwrap();
    let oracle = cells
        .iter()
        .find(|s| s.cell == cell && s.method == aift::scenario::Method::Oracle)
        .unwrap();
    assert_eq!(oracle.verdict, Verdict::Recovered);
    assert_eq!(oracle.ratio_to_oracle, Some(1.0));
}

/// A campaign's scenario keys are typed by the scenario's schema when laid over a template: a
/// bad one is refused before any run, naming the campaign file and `defaults.KEY` (or the arm's
/// `overrides`); the old `set = [...]` strings are refused with the way to write them now.
#[test]
fn campaign_scenario_keys_are_typed_and_named_by_their_table() {
    let dir = tempfile::tempdir().unwrap();
    let template = common::repo("assets/scenarios/paper_healthy.toml");
    let write = |name: &str, keys: &str| {
        let path = dir.path().join(name);
        std::fs::write(
            &path,
            format!(
                "name = \"c\"\n{keys}\n[[arms]]\nname = \"paper\"\nscenario = \"{}\"\n\n[[kinds]]\nkind = \"freeze\"\n",
                template.display()
            ),
        )
        .unwrap();
        path
    };
    let err = |path: &Path| {
        aift::scenario::campaign::Campaign::load(path, &[])
            .err()
            .map(|e| aift::error_chain(&e))
            .unwrap_or_default()
    };
    let bad_default = write("a.toml", "defaults = { plant = { engine = \"warp\" } }");
    let e = err(&bad_default);
    assert!(
        e.contains("a.toml") && e.contains("`defaults.plant.engine`") && e.contains("warp"),
        "{e}"
    );
    let bad_arm = write("b.toml", "");
    let text = std::fs::read_to_string(&bad_arm).unwrap().replacen(
        "scenario = ",
        "overrides = { plant = { engine = \"warp\" } }\nscenario = ",
        1,
    );
    std::fs::write(&bad_arm, text).unwrap();
    let e = err(&bad_arm);
    assert!(e.contains("`arms[0].overrides.plant.engine`"), "{e}");
    // Values of the right type that a check refuses are blamed on the campaign file's key too,
    // not on the template (which never held them); a --set after them is blamed as such.
    let neg_default = write("d.toml", "defaults = { duration = -1.0 }");
    let e = err(&neg_default);
    assert!(
        e.contains("d.toml") && e.contains("`defaults.duration`") && e.contains("-1"),
        "{e}"
    );
    let neg_arm = write("e.toml", "");
    let text = std::fs::read_to_string(&neg_arm).unwrap().replacen(
        "scenario = ",
        "overrides = { duration = -1.0 }\nscenario = ",
        1,
    );
    std::fs::write(&neg_arm, text).unwrap();
    let e = err(&neg_arm);
    assert!(
        e.contains("e.toml") && e.contains("`arms[0].overrides.duration`"),
        "{e}"
    );
    let set = ["duration=-1".to_string()];
    let e = aift::scenario::campaign::Campaign::load(&neg_default, &set)
        .err()
        .expect("refused");
    assert_eq!(e.blamed_override(&set), Some("duration=-1"));
    let old = write("c.toml", "set = [\"duration=9.0\"]");
    let e = err(&old);
    assert!(
        e.contains("`set = [...]`") && e.contains("[defaults]"),
        "{e}"
    );
}

#[test]
fn a_campaign_of_the_reaching_benchmark_alone_writes_its_files_and_merges() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let text = format!(
        r#"
name = "reach_only"
seeds = 1
methods = ["oracle", "no-ft"]
healthy = false
kinds = []
defaults = {{ duration = 2.0, plant = {{ engine = "articulated" }} }}
[[arms]]
name = "paper"
scenario = "{}"
[reaching]
tasks = 3
duration = 1.0
"#,
        common::repo("assets/scenarios/paper_healthy.toml").display()
    );
    std::fs::write(d.join("c.toml"), text).unwrap();
    common::aift_ok(&["campaign", "c.toml", "--out", "whole"], d);
    for k in 1..=2 {
        let shard = format!("{k}/2");
        common::aift_ok(
            &[
                "campaign",
                "c.toml",
                "--shard",
                &shard,
                "--out",
                &format!("s{k}"),
            ],
            d,
        );
    }
    common::aift_ok(&["merge", "s1", "s2", "--out", "merged"], d);
    for name in ["reaching.csv", "campaign.json", "report.html"] {
        assert_eq!(
            std::fs::read(d.join("whole").join(name)).unwrap(),
            std::fs::read(d.join("merged").join(name)).unwrap(),
            "{name}"
        );
    }
    let csv = std::fs::read_to_string(d.join("whole/reaching.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 3 * 2);
}

/// A dead motor is judged on the other joints; a loss of effectiveness on every joint. On the
/// paper arm a dead joint 2 falls under gravity (its own final error is large) while joint 1 still
/// reaches its target: recovered. With joint 1 at 20 % effectiveness the shoulder sags: failed.
#[test]
fn a_dead_motor_is_judged_on_the_other_joints() {
    let tmp = tempfile::tempdir().unwrap();
    let text = format!(
        r#"
name = "dead"
seeds = 1
methods = ["no-ft"]
channels = []
healthy = false
actuator_kinds = [{{ kind = "dead" }}, {{ kind = "effectiveness", factor = 0.2 }}]
onsets = {{ moving = 1.0 }}
[defaults]
duration = 6.0
plant = {{ engine = "articulated" }}
targets = [{{ time = 0.0, q = [-0.2, 0.5] }}]
initial = {{ q = [-0.2, 0.5] }}
[[arms]]
name = "paper"
scenario = "{}"
joints = [1, 2]
"#,
        common::repo("assets/scenarios/paper_healthy.toml").display()
    );
    let file = tmp.path().join("dead.toml");
    std::fs::write(&file, text).unwrap();
    let campaign = aift::scenario::campaign::Campaign::load(&file, &[]).unwrap();
    let records = aift::scenario::campaign::run_campaign(
        &campaign,
        aift::scenario::campaign::Shard::WHOLE,
        None,
        &|_, _| {},
    )
    .unwrap();
    let verdict = |label: &str| {
        let cell = campaign
            .cells
            .iter()
            .position(|c| c.label == label)
            .unwrap();
        let run = records.runs.iter().find(|r| r.cell == cell).unwrap();
        (run.verdict.name(), run.max_final_error)
    };
    let (v, e) = verdict("motor2 dead moving");
    eprintln!("motor2 dead: {v}, largest final error over every joint {e}");
    assert_eq!(v, "recovered");
    assert!(e > 0.1, "joint 2 fell: {e}");
    let (v, e) = verdict("motor1 effectiveness moving");
    eprintln!("motor1 at 20 %: {v}, {e}");
    assert_eq!(v, "failed");
}
