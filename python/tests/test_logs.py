"""Recorded logs: `run.mcap` read back by independent readers (PyPI's mcap-ros2-support decodes
the CDR from the schemas the file carries), every value equal to trajectory.csv."""

import json

import numpy as np
import pytest

import aift

from test_package import assert_same_bits, read_csv

mcap_ros2_reader = pytest.importorskip("mcap_ros2.reader")


def scenario_with_events(repo, tmp_path):
    """paper_encoder_freeze.toml, 10 s, every 3rd tick recorded, with an actuator fault and a
    payload (events of every class)."""
    text = (repo / "assets/scenarios/paper_encoder_freeze.toml").read_text()
    text = text.replace("../../urdf/", f"{repo / 'urdf'}/").replace("duration = 20.0", "duration = 10.0")
    text = "record_every = 3\n" + text
    text += """
[[actuator_faults]]
joint = 2
kind = "bias"
torque = 5.0
start = 9.0
end = 9.5

[[disturbances]]
kind = "payload"
link = "ee"
mass = 0.2
start = 8.5
"""
    path = tmp_path / "events.toml"
    path.write_text(text)
    return path


def read_mcap(path):
    topics = {}
    for m in mcap_ros2_reader.read_ros2_messages(str(path)):
        topics.setdefault(m.channel.topic, []).append((m.log_time_ns, m.schema.name, m.ros_msg))
    return topics


def test_run_mcap_equals_the_trajectory(tmp_path, cli, repo):
    scenario = scenario_with_events(repo, tmp_path)
    cli("run", scenario, "--method", "hybrid", "--mcap", "--out", tmp_path / "run")
    header, col = read_csv(tmp_path / "run" / "trajectory.csv")
    topics = read_mcap(tmp_path / "run" / "run.mcap")
    rows = len(col["t"])
    n = 2
    channels = ["enc1", "enc2", "tach1", "tach2", "cam_u", "cam_v"]
    for topic in ["/joint_states", "/true_joint_states", "/belief", "/command", "/target",
                  "/camera/point", "/precision", "/health", "/free_energy", "/detector"]:
        assert len(topics[topic]) == rows, topic
        times = np.array([t for t, _, _ in topics[topic]], dtype=np.float64) / 1e9
        assert np.all(np.abs(times - col["t"]) < 1e-9), topic
    assert {s for _, s, _ in topics["/joint_states"]} == {"sensor_msgs/msg/JointState"}

    def series(topic, field):
        return np.array([getattr(m, field) for _, _, m in topics[topic]], dtype=np.float64)

    for i in range(n):
        j = f"{i + 1}"
        assert_same_bits(series("/joint_states", "position")[:, i], col[f"y_enc{j}"], "readings enc")
        assert_same_bits(series("/joint_states", "velocity")[:, i], col[f"y_tach{j}"], "readings tach")
        assert_same_bits(series("/joint_states", "effort")[:, i], col[f"applied{j}"], "applied")
        assert_same_bits(series("/true_joint_states", "position")[:, i], col[f"q{j}"], "q")
        assert_same_bits(series("/true_joint_states", "velocity")[:, i], col[f"qd{j}"], "qd")
        assert_same_bits(series("/belief", "position")[:, i], col[f"mu{j}"], "mu")
        assert_same_bits(series("/belief", "velocity")[:, i], col[f"mu_p{j}"], "mu_p")
        assert_same_bits(series("/command", "effort")[:, i], col[f"u{j}"], "u")
        assert_same_bits(series("/target", "position")[:, i], col[f"target{j}"], "target")
    assert [m.name for _, _, m in topics["/joint_states"][:1]] == [["joint1", "joint2"]]
    points = [m.point for _, _, m in topics["/camera/point"]]
    assert_same_bits([p.x for p in points], col["y_cam_u"], "cam u")
    assert_same_bits([p.y for p in points], col["y_cam_v"], "cam v")
    for topic, prefix in [("/precision", "precision_"), ("/health", "health_")]:
        data = series(topic, "data")
        label = topics[topic][0][2].layout.dim[0].label
        assert label.split(",") == channels
        for k, c in enumerate(channels):
            assert_same_bits(data[:, k], col[prefix + c], topic + c)
    assert_same_bits(series("/free_energy", "data"), col["F"], "F")
    detector = series("/detector", "data")
    labels = topics["/detector"][0][2].layout.dim[0].label.split(",")
    for k, name in enumerate(labels):
        assert_same_bits(detector[:, k], col[name], name)
    assert {f"y_{c}" for c in channels} | {"F", "alarm", "isolated"} <= set(header)

    events = [(t, m.level, json.loads(m.msg)) for t, _, m in topics["/events"]]
    assert [(t, e["class"], e["event"]) for t, _, e in events] == [
        (8_000_000_000, "sensor", "start"),
        (8_500_000_000, "disturbance", "start"),
        (9_000_000_000, "actuator", "start"),
        (9_500_000_000, "actuator", "end"),
    ]
    assert events[0][2]["targets"] == ["enc1"] and events[0][1] == 30
    assert events[3][1] == 20


def test_mcap_from_python_and_its_errors(tmp_path, repo):
    scenario = scenario_with_events(repo, tmp_path)
    a = aift.run(str(scenario), "no-ft", out=tmp_path / "a", mcap=True, trajectory=False)
    assert (tmp_path / "a" / "run.mcap").is_file()
    b = aift.run(str(scenario), "no-ft", out=tmp_path / "b", mcap=True, trajectory=False)
    # Deterministic: the same scenario and seed give the same bytes.
    assert (tmp_path / "a" / "run.mcap").read_bytes() == (tmp_path / "b" / "run.mcap").read_bytes()
    assert a.summary["outcome"] == b.summary["outcome"]
    with pytest.raises(aift.BadInput, match="out="):
        aift.run(str(scenario), "no-ft", mcap=True)


def write_bag_with_rosbags(path, col, stamp0_ns):
    """A rosbag2 bag (MCAP storage) written by PyPI's rosbags from a run's trajectory columns:
    /joint_states (readings, effort = applied torque) and /camera/point, header stamps from
    `stamp0_ns` (as a real recording's epoch times)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    JointState = ts.types["sensor_msgs/msg/JointState"]
    PointStamped = ts.types["geometry_msgs/msg/PointStamped"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    Point = ts.types["geometry_msgs/msg/Point"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        joints = w.add_connection("/joint_states", JointState.__msgtype__, typestore=ts)
        camera = w.add_connection("/camera/point", PointStamped.__msgtype__, typestore=ts)
        for k, t in enumerate(col["t"]):
            ns = stamp0_ns + int(round(t * 1e9))
            header = Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="")
            js = JointState(
                header=header,
                name=["joint1", "joint2"],
                position=np.array([col["y_enc1"][k], col["y_enc2"][k]], dtype=np.float64),
                velocity=np.array([col["y_tach1"][k], col["y_tach2"][k]], dtype=np.float64),
                effort=np.array([col["applied1"][k], col["applied2"][k]], dtype=np.float64),
            )
            w.write(joints, ns, ts.serialize_cdr(js, JointState.__msgtype__))
            p = PointStamped(header=header, point=Point(x=col["y_cam_u"][k], y=col["y_cam_v"][k], z=0.0))
            w.write(camera, ns, ts.serialize_cdr(p, PointStamped.__msgtype__))


def test_replay_of_a_bag_written_by_rosbags(tmp_path, cli, repo):
    pytest.importorskip("rosbags")
    text = (repo / "assets/scenarios/paper_encoder_freeze.toml").read_text()
    text = text.replace("../../urdf/", f"{repo / 'urdf'}/").replace("duration = 20.0", "duration = 10.0")
    scenario = tmp_path / "s.toml"
    scenario.write_text(text)
    cli("run", scenario, "--method", "hybrid", "--out", tmp_path / "live")
    _, col = read_csv(tmp_path / "live" / "trajectory.csv")
    bag = tmp_path / "bag"
    write_bag_with_rosbags(bag, col, stamp0_ns=1_733_000_000_123_000_000)
    assert (bag / "metadata.yaml").is_file()
    p = cli("replay", bag, "--scenario", scenario, "--method", "hybrid", "--out", tmp_path / "replay", "--json")
    replayed = json.loads(p.stdout)
    live = json.loads((tmp_path / "live" / "summary.json").read_text())
    # Header stamps are used (every message has one), counted from the first.
    assert "header time" in replayed["replay"]["read"]
    assert replayed["replay"]["samples"] == 2 * len(col["t"])
    assert replayed["replay"]["empty_ticks"] == 0
    # The frozen encoder is detected and isolated as in the live run: the same channel, the
    # same time (the readings and torques are the same bits, so is everything computed).
    assert live["isolated_channel"] == replayed["isolated_channel"] == "enc1"
    assert live["detected_at"] == replayed["detected_at"]
    _, rcol = read_csv(tmp_path / "replay" / "trajectory.csv")
    for c in ["mu1", "mu2", "mu_p1", "mu_p2", "precision_enc1", "health_tach2", "health_cam_u"]:
        assert_same_bits(rcol[c], col[c], c)


def test_replay_from_python_and_bad_logs(tmp_path, repo):
    text = (repo / "assets/scenarios/paper_encoder_freeze.toml").read_text()
    text = text.replace("../../urdf/", f"{repo / 'urdf'}/").replace("duration = 20.0", "duration = 9.0")
    scenario = tmp_path / "s.toml"
    scenario.write_text(text)
    live = aift.run(str(scenario), "pl-always", out=tmp_path / "live", mcap=True)
    replayed = aift.replay(tmp_path / "live" / "run.mcap", str(scenario), "pl-always", out=tmp_path / "r")
    assert replayed.summary["replay"]["ticks"] == len(live.trajectory["t"])
    assert replayed.summary["detected_at"] == live.summary["detected_at"]
    bad = tmp_path / "bad.csv"
    bad.write_text("t,applied1,applied2,y_enc1\n0,0,0,0\n-1,0,0,0\n")
    with pytest.raises(aift.BadInput, match="bad.csv.*line 3, column t"):
        aift.replay(bad, str(scenario), out=tmp_path / "never")
    assert not (tmp_path / "never").exists()
