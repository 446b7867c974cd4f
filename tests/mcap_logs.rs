//! `aift run --mcap`: the run as ROS 2 messages in an MCAP file, read back with the `mcap`
//! crate's reader: the topics and schemas, a message per recorded tick, the readings equal to
//! trajectory.csv, the fault events at their times, the same bytes for the same seed.
//! (python/tests/test_logs.py reads the file with an independent decoder and checks every
//! value of every topic.)

mod common;

use std::collections::BTreeMap;

use aift::logs::messages::read_joint_state;
use aift::scenario::TrajectoryRecorder;

fn run_with_mcap(dir: &std::path::Path, out: &str) -> Vec<u8> {
    let scenario = dir.join("s.toml");
    let text = common::scenario_text("paper_encoder_freeze.toml")
        .replace("duration = 20.0", "duration = 9.0");
    std::fs::write(&scenario, format!("record_every = 2\n{text}")).unwrap();
    common::aift_ok(
        &[
            "run",
            "s.toml",
            "--method",
            "pl-always",
            "--mcap",
            "--out",
            out,
        ],
        dir,
    );
    std::fs::read(dir.join(out).join("run.mcap")).unwrap()
}

#[test]
fn a_run_as_ros2_messages_in_mcap() {
    let tmp = tempfile::tempdir().unwrap();
    let bytes = run_with_mcap(tmp.path(), "a");
    let rec = TrajectoryRecorder::read_csv(&tmp.path().join("a/trajectory.csv")).unwrap();
    let rows = rec.rows.len();
    assert_eq!(rows, 4500, "every 2nd of the 9000 ticks");
    let mut by_topic: BTreeMap<String, Vec<(u64, Vec<u8>)>> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let schema = m.channel.schema.as_ref().unwrap();
        assert_eq!(schema.encoding, "ros2msg");
        assert_eq!(m.channel.message_encoding, "cdr");
        if m.channel.topic.ends_with("joint_states") {
            assert_eq!(schema.name, "sensor_msgs/msg/JointState");
        }
        by_topic
            .entry(m.channel.topic.clone())
            .or_default()
            .push((m.log_time, m.data.into_owned()));
    }
    let topics: Vec<&str> = by_topic.keys().map(String::as_str).collect();
    let mut expected = aift::logs::TOPICS.to_vec();
    expected.sort();
    assert_eq!(topics, expected);
    for (topic, messages) in &by_topic {
        if topic != "/events" {
            assert_eq!(messages.len(), rows, "{topic}");
        }
    }
    let col = |name: &str| rec.series(name).unwrap();
    let (t, enc1, tach2, applied1) = (col("t"), col("y_enc1"), col("y_tach2"), col("applied1"));
    for (k, (time, data)) in by_topic["/joint_states"].iter().enumerate() {
        assert_eq!(*time, (t[k] * 1e9).round() as u64);
        let js = read_joint_state(data).unwrap();
        assert_eq!(js.stamp_ns, *time);
        assert_eq!(js.name, ["joint1", "joint2"]);
        assert_eq!(js.position[0].to_bits(), enc1[k].to_bits(), "row {k}");
        assert_eq!(js.velocity[1].to_bits(), tach2[k].to_bits(), "row {k}");
        assert_eq!(js.effort[0].to_bits(), applied1[k].to_bits(), "row {k}");
    }
    // The encoder freezes at 8 s: one WARN event then.
    let events = &by_topic["/events"];
    assert_eq!(events.len(), 1);
    assert_eq!(events[0].0, 8_000_000_000);
    let text = String::from_utf8_lossy(&events[0].1);
    assert!(text.contains(r#""kind":"freeze""#), "{text}");

    // Deterministic: the same scenario and seed, the same bytes; no file without --mcap.
    assert_eq!(run_with_mcap(tmp.path(), "b"), bytes);
    common::aift_ok(&["run", "s.toml", "--out", "c"], tmp.path());
    assert!(!tmp.path().join("c/run.mcap").exists());
}
