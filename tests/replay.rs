//! `aift replay`: a method run over recorded readings and applied torques. A run's own
//! trajectory.csv replayed gives its belief, precisions and detections bit for bit; its
//! run.mcap the same detections; readings at another rate enter at the next tick; bad logs are
//! refused with exit 2, the file and the field named, and no folder written. (The replay of a
//! bag written by an independent writer, PyPI's rosbags: python/tests/test_logs.py.)

mod common;

use std::path::Path;

use aift::scenario::TrajectoryRecorder;

/// paper_encoder_freeze.toml cut to 10 s, written into `dir` as s.toml.
fn scenario(dir: &Path) {
    let text = common::scenario_text("paper_encoder_freeze.toml")
        .replace("duration = 20.0", "duration = 10.0");
    std::fs::write(dir.join("s.toml"), text).unwrap();
}

fn summary(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

/// `aift replay LOG --scenario s.toml --method hybrid --out OUT` in `dir`, with `extra`
/// arguments.
fn replay_hybrid(dir: &Path, log: &str, out: &str, extra: &[&str]) {
    let mut args = vec![
        "replay",
        log,
        "--scenario",
        "s.toml",
        "--method",
        "hybrid",
        "--out",
        out,
    ];
    args.extend_from_slice(extra);
    common::aift_ok(&args, dir);
}

#[test]
fn a_replayed_run_gives_its_belief_and_detections() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    scenario(d);
    common::aift_ok(
        &[
            "run", "s.toml", "--method", "hybrid", "--mcap", "--out", "live",
        ],
        d,
    );
    replay_hybrid(d, "live/trajectory.csv", "from-csv", &[]);
    let live = TrajectoryRecorder::read_csv(&d.join("live/trajectory.csv")).unwrap();
    let replayed = TrajectoryRecorder::read_csv(&d.join("from-csv/trajectory.csv")).unwrap();
    assert_eq!(live.rows.len(), replayed.rows.len());
    for name in ["mu1", "mu2", "mu_p1", "precision_enc1", "health_tach2", "F"] {
        let (a, b) = (live.series(name).unwrap(), replayed.series(name).unwrap());
        for (k, (x, y)) in a.iter().zip(&b).enumerate() {
            assert_eq!(x.to_bits(), y.to_bits(), "{name} at row {k}: {x} vs {y}");
        }
    }
    // The plant is not in a replay: its columns are NaN.
    assert!(replayed.series("q1").unwrap().iter().all(|x| x.is_nan()));
    let (s_live, s_csv) = (summary(&d.join("live")), summary(&d.join("from-csv")));
    assert_eq!(s_live["detected_at"], s_csv["detected_at"]);
    assert_eq!(s_live["isolated_channel"], s_csv["isolated_channel"]);
    assert_eq!(s_csv["replay"]["samples"], 10_000);
    assert_eq!(s_csv["replay"]["empty_ticks"], 0);
    assert!(s_csv["detected_at"].as_f64().is_some(), "{s_csv}");

    // From the run's MCAP: the same readings, so the same detections.
    replay_hybrid(d, "live/run.mcap", "from-mcap", &[]);
    let s_mcap = summary(&d.join("from-mcap"));
    assert_eq!(s_live["detected_at"], s_mcap["detected_at"]);
    assert_eq!(s_live["isolated_channel"], s_mcap["isolated_channel"]);
    assert!(d.join("from-mcap/report.html").is_file());
}

/// A method's own actuator alarms (the hybrid with `hybrid.actuators`) are replayed too: the
/// Panda with a locked joint, live and from its trajectory.csv (readings and applied torques),
/// gives the same alarms, and they name the locked motor.
#[test]
fn a_replayed_run_gives_its_actuator_alarms() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (joint, kind) = common::PANDA_ACTUATOR_FAULTS[0];
    let text = common::scenario_text("panda_healthy.toml")
        .replace("duration = 15.0", "duration = 9.0")
        + &format!("\n[[actuator_faults]]\njoint = {joint}\nstart = 7.6\n{kind}\n");
    std::fs::write(d.join("s.toml"), text).unwrap();
    let set = [
        "--set",
        "hybrid.actuators=true",
        "--set",
        "hybrid.model_error_state=false",
        "--set",
        "plant.engine=\"articulated\"",
    ];
    let mut live_args = vec![
        "run", "s.toml", "--method", "hybrid", "--seed", "5", "--out", "live",
    ];
    live_args.extend_from_slice(&set);
    common::aift_ok(&live_args, d);
    let mut replay_args = vec!["--seed", "5"];
    replay_args.extend_from_slice(&set);
    replay_hybrid(d, "live/trajectory.csv", "replayed", &replay_args);
    let (live, replayed) = (summary(&d.join("live")), summary(&d.join("replayed")));
    let alarms = &live["actuator_alarms"]["alarms"];
    assert!(
        alarms
            .as_array()
            .is_some_and(|a| a.iter().any(|x| x["joint"] == format!("motor{joint}"))),
        "{live}"
    );
    assert_eq!(alarms, &replayed["actuator_alarms"]["alarms"], "{replayed}");
}

#[test]
fn readings_at_another_rate_enter_at_the_next_tick() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    scenario(d);
    // Encoders only, every 2.5 ms (the scenario ticks at 1 ms), two rows in one tick at the
    // end; torques that hold the arm where it starts are not needed: the belief only predicts.
    let mut csv = String::from("t,applied1,applied2,y_enc1,y_enc2\n");
    let times = [0.0, 0.0025, 0.005, 0.0075, 0.0101, 0.0104];
    for t in times {
        csv += &format!("{t},0,0,-1.5707963,0.0\n");
    }
    std::fs::write(d.join("slow.csv"), csv).unwrap();
    let out = common::aift_ok(
        &[
            "replay",
            "slow.csv",
            "--scenario",
            "s.toml",
            "--method",
            "no-ft",
            "--out",
            "r",
            "--json",
        ],
        d,
    );
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // Ticks 0, 3 (2.5 ms -> the tick at 3 ms), 5, 8, 11, 11: 12 ticks, 7 without a sample, the
    // 10.4 ms row superseding two readings of the 10.1 ms row.
    assert_eq!(s["replay"]["ticks"], 12, "{s}");
    assert_eq!(s["replay"]["empty_ticks"], 7, "{s}");
    assert_eq!(s["replay"]["superseded"], 2, "{s}");
    let rec = TrajectoryRecorder::read_csv(&d.join("r/trajectory.csv")).unwrap();
    let enc1 = rec.series("y_enc1").unwrap();
    let tach1 = rec.series("y_tach1").unwrap();
    let present: Vec<usize> = (0..enc1.len()).filter(|&k| !enc1[k].is_nan()).collect();
    assert_eq!(present, [0, 3, 5, 8, 11]);
    assert!(
        tach1.iter().all(|x| x.is_nan()),
        "no tachometer column: missing"
    );
}

#[test]
fn bad_logs_are_refused_before_any_output() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    scenario(d);
    let ok_header = "t,applied1,applied2,y_enc1,y_enc2\n";
    let cases: Vec<(&str, String, &str)> = vec![
        (
            "no-applied.csv",
            "t,applied1,y_enc1\n0,0,0\n".into(),
            "applied2",
        ),
        (
            "no-t.csv",
            "time,applied1,applied2,y_enc1\n0,0,0,0\n".into(),
            "`t`",
        ),
        (
            "no-readings.csv",
            "t,applied1,applied2\n0,0,0\n".into(),
            "no reading column",
        ),
        (
            "backwards.csv",
            format!("{ok_header}0,0,0,0,0\n0.002,0,0,0,0\n0.001,0,0,0,0\n"),
            "line 4, column t",
        ),
        ("inf.csv", format!("{ok_header}0,0,0,inf,0\n"), "y_enc1"),
        (
            "nan-effort.csv",
            format!("{ok_header}0,0,NaN,0,0\n"),
            "applied2",
        ),
        (
            "text.csv",
            format!("{ok_header}0,0,0,abc,0\n"),
            "line 2, column y_enc1",
        ),
        ("empty.csv", ok_header.into(), "no data row"),
        (
            "forever.csv",
            format!("{ok_header}0,0,0,0,0\n1e300,0,0,0,0\n"),
            "ticks replayed",
        ),
        ("log.txt", "t\n".into(), "neither"),
        ("not.mcap", "not an mcap file".into(), "not an MCAP file"),
    ];
    for (name, text, named) in &cases {
        std::fs::write(d.join(name), text).unwrap();
        let out = common::aift_in(&["replay", name, "--scenario", "s.toml", "--out", "out"], d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{name}: {stderr}");
        assert!(stderr.contains(name), "{name}: the file is named: {stderr}");
        assert!(
            stderr.contains(named),
            "{name}: {stderr} does not name {named}"
        );
        assert!(!d.join("out").exists(), "{name}: nothing written");
    }
}

/// A JointState message: its time (ns), joint names and efforts.
type Message = (u64, Vec<String>, Vec<f64>);

/// An MCAP file with these JointState messages on `topic`, written with the `mcap` crate and
/// aift's CDR encoder.
fn joint_state_mcap(path: &Path, topic: &str, messages: &[Message]) {
    use aift::logs::{cdr::CdrWriter, messages};
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(file)
        .unwrap();
    let ty = messages::joint_state_type();
    let schema = w
        .add_schema(ty.name, "ros2msg", ty.schema.as_bytes())
        .unwrap();
    let channel = w
        .add_channel(schema, topic, "cdr", &Default::default())
        .unwrap();
    let mut cdr = CdrWriter::new();
    for (seq, (ns, names, effort)) in messages.iter().enumerate() {
        let position = vec![0.1; names.len()];
        messages::joint_state(&mut cdr, *ns, names, &position, &[], effort);
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: channel,
                sequence: seq as u32,
                log_time: *ns,
                publish_time: *ns,
            },
            cdr.bytes(),
        )
        .unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn bad_mcap_logs_name_the_topic_message_and_joint() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    scenario(d);
    let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let good = names(&["joint1", "joint2"]);
    let cases: Vec<(&str, &str, Vec<Message>, &str)> = vec![
        (
            "unknown-joint.mcap",
            "/joint_states",
            vec![(1_000_000, names(&["joint1", "elbow"]), vec![0.0, 0.0])],
            "\"elbow\" is not a joint of the arm",
        ),
        (
            "no-effort.mcap",
            "/joint_states",
            vec![(1_000_000, good.clone(), vec![])],
            "effort",
        ),
        (
            "backwards.mcap",
            "/joint_states",
            vec![
                (2_000_000, good.clone(), vec![0.0, 0.0]),
                (1_000_000, good.clone(), vec![0.0, 0.0]),
            ],
            "message 1 (time)",
        ),
        (
            "two-topics.mcap",
            "/arm/joint_states",
            vec![(1_000_000, good.clone(), vec![0.0, 0.0])],
            "",
        ),
    ];
    for (name, topic, messages, named) in &cases {
        joint_state_mcap(&d.join(name), topic, messages);
        if named.is_empty() {
            // One JointState topic, not /joint_states: found.
            common::aift_ok(
                &["replay", name, "--scenario", "s.toml", "--out", "found"],
                d,
            );
            // A topic that is not there: named.
            let out = common::aift_in(
                &[
                    "replay",
                    name,
                    "--scenario",
                    "s.toml",
                    "--topic",
                    "/nope",
                    "--out",
                    "out",
                ],
                d,
            );
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(2), "{stderr}");
            assert!(
                stderr.contains("/nope") && stderr.contains("/arm/joint_states"),
                "{stderr}"
            );
            continue;
        }
        let out = common::aift_in(&["replay", name, "--scenario", "s.toml", "--out", "out"], d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{name}: {stderr}");
        assert!(stderr.contains(name), "{name}: {stderr}");
        assert!(
            stderr.contains(named),
            "{name}: {stderr} does not name {named}"
        );
        assert!(!d.join("out").exists(), "{name}: nothing written");
    }
}

#[test]
fn a_split_bag_is_read_in_time_order() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    scenario(d);
    let good = vec!["joint1".to_string(), "joint2".to_string()];
    let at = |ms: u64| {
        (
            1_700_000_000_000_000_000 + ms * 1_000_000,
            good.clone(),
            vec![0.0, 0.0],
        )
    };
    std::fs::create_dir(d.join("bag")).unwrap();
    // Names that sort against time: part_10 holds the first 5 ms, part_9 the next.
    joint_state_mcap(
        &d.join("bag/part_10.mcap"),
        "/joint_states",
        &[at(0), at(2), at(4)],
    );
    joint_state_mcap(&d.join("bag/part_9.mcap"), "/joint_states", &[at(6), at(8)]);
    let out = common::aift_ok(
        &[
            "replay",
            "bag",
            "--scenario",
            "s.toml",
            "--method",
            "no-ft",
            "--out",
            "r",
            "--json",
        ],
        d,
    );
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(s["replay"]["samples"], 5, "{s}");
    assert_eq!(s["replay"]["ticks"], 9, "{s}");
    assert_eq!(s["replay"]["empty_ticks"], 4, "{s}");
    // Files whose times overlap are refused.
    joint_state_mcap(&d.join("bag/part_8.mcap"), "/joint_states", &[at(3)]);
    let out = common::aift_in(&["replay", "bag", "--scenario", "s.toml", "--out", "x"], d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("overlap"), "{stderr}");
    assert!(!d.join("x").exists());
}
