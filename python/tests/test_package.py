"""The Python package against the CLI: same numbers bit for bit, same errors, the step API."""

import csv
import json
import math
import threading

import numpy as np
import pytest

import aift


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    cols = list(zip(*body))
    return header, {h: np.array([float(v) for v in c], dtype=np.float64) for h, c in zip(header, cols)}


def assert_same_bits(a, b, name):
    """Equal bit for bit; NaN (missing readings, undefined F) must sit in the same places."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    assert a.shape == b.shape, f"{name}: {a.shape} vs {b.shape}"
    nan_a, nan_b = np.isnan(a), np.isnan(b)
    assert np.array_equal(nan_a, nan_b), f"{name}: NaN in different places"
    ok = a[~nan_a].view(np.uint64) == b[~nan_b].view(np.uint64)
    assert ok.all(), f"{name}: first difference at row {np.argmin(ok)}: {a[~nan_a][~ok][0]!r} vs {b[~nan_b][~ok][0]!r}"


def without_timing(summary):
    return {k: v for k, v in summary.items() if k != "ticks_per_second"}


@pytest.mark.parametrize("method", ["pl-always", "pl-detect"])
def test_default_scenario_matches_aift_run_bit_for_bit(tmp_path, cli, method):
    # The whole default scenario for the paper's method; a detector method on a shorter run
    # (its calibration, computed once, is shared through the cache).
    overrides = [] if method == "pl-always" else ["duration=10.0"]
    sets = [a for o in overrides for a in ("--set", o)]
    out = tmp_path / "cli"
    cli("run", "--method", method, "--seed", "3", *sets, "--out", out)
    sc = aift.Scenario.default(overrides)
    r = aift.run(sc, method=method, seed=3)
    header, expected = read_csv(out / "trajectory.csv")
    assert r.trajectory.columns == header
    assert len(r.trajectory) == len(expected["t"])
    for name in header:
        assert_same_bits(r.trajectory[name], expected[name], name)
    with open(out / "summary.json") as f:
        assert without_timing(r.summary) == without_timing(json.load(f))
    assert r.out is None


def test_out_writes_the_cli_run_folder(tmp_path, cli):
    sc = aift.Scenario.default(["duration=3.0"])
    cli("run", "--set", "duration=3.0", "--out", tmp_path / "cli")
    r = aift.run(sc, out=tmp_path / "py")
    names = sorted(p.name for p in (tmp_path / "cli").iterdir())
    assert sorted(p.name for p in (tmp_path / "py").iterdir()) == names
    assert (tmp_path / "py" / "trajectory.csv").read_bytes() == (tmp_path / "cli" / "trajectory.csv").read_bytes()
    header, expected = read_csv(tmp_path / "py" / "trajectory.csv")
    assert_same_bits(r.trajectory["mu1"], expected["mu1"], "mu1")
    # A second write needs force, as in the CLI.
    with pytest.raises(aift.BadInput, match="exists"):
        aift.run(sc, out=tmp_path / "py")
    aift.run(sc, out=tmp_path / "py", force=True)


def test_to_pandas_and_numpy():
    pd = pytest.importorskip("pandas")
    r = aift.run(aift.Scenario.default(["duration=1.0"]), method="no-ft")
    df = r.trajectory.to_pandas()
    assert isinstance(df, pd.DataFrame)
    assert list(df.columns) == r.trajectory.columns
    assert df.shape == (1000, len(r.trajectory.columns))
    assert r.trajectory.to_numpy().shape == df.shape
    assert (df["t"].to_numpy() == r.trajectory["t"]).all()


def test_scenario_set_to_toml_round_trip(repo):
    sc = aift.Scenario.load(repo / "assets/scenarios/paper_healthy.toml")
    sc.set("duration", 2.5).set("belief.prior_position_precision", 1e9).set("precision.method", "bayes")
    assert sc.duration == 2.5 and sc.method == "bayes"
    assert sc.overrides == ["duration=2.5", "belief.prior_position_precision=1000000000.0", 'precision.method="bayes"']
    # A Python str stays text even when it reads as a number; numpy integers are integers.
    assert 'name = "2024"' in sc.copy().set("name", "2024").to_toml()
    assert "record_every = 3" in sc.copy().set("record_every", np.int64(3)).to_toml()
    back = aift.Scenario.from_toml(sc.to_toml(), base_dir=repo / "assets/scenarios")
    assert back.to_toml() == sc.to_toml()
    # Lists, booleans and indices reach the same keys as --set.
    sc2 = aift.Scenario.default().set("faults[0].start", 9).set("initial.q", [0.1, -0.2])
    assert "start = 9" in sc2.to_toml()
    r1 = aift.run(sc2.copy().set("duration", 1.0), method="no-ft")
    assert r1.trajectory["q1"][0] == 0.1 and r1.trajectory["q2"][0] == -0.2


def test_errors_carry_the_cli_messages(cli, repo):
    # An unknown key from an override.
    p = cli("run", "--set", "controller.bogus=1", check=False)
    assert p.returncode == 2
    with pytest.raises(aift.BadInput) as e:
        aift.Scenario.default().set("controller.bogus", 1)
    assert p.stderr.strip() == f"error: {e.value}"
    # An invalid value caught by validation (an arm-independent key).
    p = cli("run", "--set", "dt=-1.0", check=False)
    assert p.returncode == 2
    with pytest.raises(aift.BadInput) as e:
        aift.run(aift.Scenario.default(["dt=-1.0"]))
    assert p.stderr.strip().endswith(str(e.value)), (p.stderr, str(e.value))
    # A missing file.
    p = cli("run", repo / "nope.toml", check=False)
    assert p.returncode == 2
    with pytest.raises(aift.BadInput) as e:
        aift.Scenario.load(repo / "nope.toml")
    assert p.stderr.strip() == f"error: {e.value}"
    # An unknown method.
    with pytest.raises(aift.BadInput, match="unknown method"):
        aift.run(aift.Scenario.default(["duration=0.1"]), method="kalman")
    assert issubclass(aift.BadInput, aift.AiftError) and issubclass(aift.InternalError, aift.AiftError)
    # The scenario is unchanged by a refused set.
    sc = aift.Scenario.default()
    with pytest.raises(aift.BadInput):
        sc.set("duration", "long")
    assert sc.overrides == []


def test_step_api_equals_run_and_reaches_the_target():
    sc = aift.Scenario.default(["duration=6.0", "faults=[]"])
    r = aift.run(sc, method="pl-always", seed=5)
    sim = aift.Sim(sc, method="pl-always")
    obs, info = sim.reset(seed=5)
    mu1 = [obs["mu"][0]]
    q = [obs["q"].copy()]
    while not info["done"]:
        obs, info = sim.step()
        mu1.append(obs["mu"][0])
        q.append(obs["q"].copy())
    assert len(mu1) == sim.ticks == len(r.trajectory)
    assert_same_bits(mu1, r.trajectory["mu1"], "mu1")
    assert_same_bits([x[1] for x in q], r.trajectory["q2"], "q2")
    error = np.abs(obs["q"] - obs["target"]).max()
    assert error < 0.01, f"final joint error {error} rad"
    assert info["diverged"] is None and not info["alarm"]


def test_actuator_faults_reach_runs_and_the_step_api():
    # A dead motor on joint 2 from 1 s: the trajectory's applied torque is the commanded one
    # before, 0 after; the step API shows the same in obs["applied"].
    sc = aift.Scenario.default(
        ["duration=2.0", "faults=[]", 'actuator_faults=[{joint=2, kind="dead", start=1.0}]']
    )
    r = aift.run(sc, method="no-ft", seed=3)
    fault = r.summary["actuator_faults"][0]
    assert (fault["kind"], fault["joint"], fault["start"]) == ("dead", "motor2", 1.0)
    t = r.trajectory
    before = t["t"] < 1.0 - 1e-9
    assert_same_bits(t["applied2"][before], t["u2"][before], "applied2 before the fault")
    assert (t["applied2"][~before] == 0.0).all()
    assert (t["u2"][~before] != 0.0).any()
    sim = aift.Sim(sc, method="no-ft")
    obs, info = sim.reset(seed=3)
    while obs["t"] < 1.5:
        obs, info = sim.step()
    assert obs["applied"][1] == 0.0 and obs["u"][1] != 0.0
    assert obs["applied"][0] == obs["u"][0]


def test_step_api_takes_torques_and_readings():
    sc = aift.Scenario.default(["duration=3.0", "faults=[]"])
    sim = aift.Sim(sc, method="pl-always")
    assert sim.channels[:2] == ["enc1", "enc2"]
    obs, _ = sim.reset(seed=1)
    # The caller freezes encoder 1 at its first reading, as a fault would.
    frozen = obs["y"][0]
    for _ in range(100):
        obs, info = sim.step(readings=[frozen] + [None] * (len(sim.channels) - 1))
        assert obs["y"][0] == frozen and np.isnan(obs["y"][1:]).all()
    # The caller's torques replace the controller's: a constant push on joint 1 of the arm
    # hanging at rest turns joint 1 positively, and not as the controller would.
    obs, _ = sim.reset(seed=1)
    start = obs["q"].copy()
    for _ in range(500):
        held, _ = sim.step()
    obs, _ = sim.reset(seed=1)
    for _ in range(500):
        obs, info = sim.step(torques=[2.0, 0.0])
    assert obs["q"][0] - start[0] > 5e-3
    assert np.abs(obs["q"] - held["q"]).max() > 0.1
    with pytest.raises(aift.BadInput, match="torques"):
        sim.step(torques=[0.0])
    with pytest.raises(aift.BadInput, match="not finite"):
        sim.step(torques=[math.nan, 0.0])
    with pytest.raises(aift.BadInput, match="readings"):
        sim.step(readings=[0.0])


def test_long_calls_release_the_gil():
    sc = aift.Scenario.default(["duration=4.0"])
    aift.run(sc, method="no-ft")  # the GP and everything else warmed up
    inside = threading.Event()
    finished = threading.Event()

    def work():
        inside.set()
        aift.run(sc, method="no-ft")
        finished.set()

    t = threading.Thread(target=work)
    t.start()
    inside.wait()
    spins = 0
    while not finished.is_set():
        spins += 1
    t.join()
    # Had the run held the GIL, this thread could not have run while it went.
    assert spins > 1000, spins


def test_table_equals_the_cli(tmp_path, cli):
    sc = aift.Scenario.default(["duration=9.0"])
    rows = aift.table(sc, methods=["no-ft", "oracle"], seeds=2)
    cli("table", "--set", "duration=9.0", "--methods", "no-ft,oracle", "--seeds", "2", "--out", tmp_path / "t")
    with open(tmp_path / "t" / "table.json") as f:
        doc = json.load(f)
    assert rows.doc == doc
    assert [r["method"] for r in rows] == ["no-ft", "oracle"]
    assert rows.to_pandas().shape[0] == 2


def test_campaign_equals_the_cli(tmp_path, cli, tiny_campaign):
    text = tiny_campaign("py_tiny")
    path = tmp_path / "tiny.toml"
    path.write_text(text)
    rows = aift.campaign(path, out=tmp_path / "py")
    cli("campaign", path, "--out", tmp_path / "cli")
    with open(tmp_path / "cli" / "campaign.json") as f:
        assert rows.doc == json.load(f)
    assert len(rows) == len(rows.doc["cells"]) > 0
    for name in ["campaign.csv", "campaign.md", "campaign.json"]:
        assert (tmp_path / "py" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name
    with pytest.raises(aift.BadInput, match="shard"):
        aift.campaign(path, shard="1/2")


def test_schema_and_methods():
    s = aift.schema()
    assert "properties" in s and "faults" in s["properties"]
    assert "hybrid" in aift.methods() and "oracle" in aift.methods()


def test_shards_merge_to_the_whole_campaign_and_report(tmp_path, tiny_campaign):
    text = tiny_campaign("py_shards")
    path = tmp_path / "c.toml"
    path.write_text(text)
    whole = aift.campaign(path, out=tmp_path / "whole")
    for k in (1, 2):
        aift.campaign(path, shard=f"{k}/2", out=tmp_path / f"s{k}")
    merged = aift.merge([tmp_path / "s1", tmp_path / "s2"], tmp_path / "merged")
    assert merged.doc == whole.doc
    for name in ["campaign.csv", "campaign.json", "report.html"]:
        assert (tmp_path / "merged" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes(), name
    with pytest.raises(aift.BadInput, match="shard"):
        aift.merge([tmp_path / "s1"], tmp_path / "half")
    # report() rewrites a folder's page; a folder that is not aift's is refused.
    (tmp_path / "whole" / "report.html").unlink()
    assert aift.report(tmp_path / "whole").endswith("report.html")
    assert (tmp_path / "whole" / "report.html").read_bytes() == (tmp_path / "merged" / "report.html").read_bytes()
    with pytest.raises(aift.BadInput, match="not a run, table or campaign folder"):
        aift.report(tmp_path)


def test_an_interrupted_run_leaves_no_folder(tmp_path, interrupted):
    sc = aift.Scenario.default(["duration=300.0", "plant.engine=\"articulated\""])
    aift.run(sc.copy().set("duration", 0.1), method="no-ft")  # the GP trained, the cache warm
    interrupted(lambda: aift.run(sc, method="no-ft", out=tmp_path / "run", trajectory=False))
    assert not (tmp_path / "run").exists()
    assert [p.name for p in tmp_path.iterdir()] == []


def test_check_urdf_init_calibrate_train_gp_as_the_cli(tmp_path, cli, repo):
    urdf = repo / "urdf" / "planar_2dof.urdf"
    doc = aift.check_urdf(urdf)
    assert doc == json.loads(cli("check-urdf", urdf, "--json").stdout)
    with pytest.raises(aift.BadInput, match="nosuchlink"):
        aift.check_urdf(urdf, ee="nosuchlink")
    # init: the same scenario as `aift init`, but for the URDF's path.
    sc = aift.init(urdf, name="mine")
    cli("init", "--urdf", urdf, "--out", tmp_path / "mine.toml")
    cli_sc = aift.Scenario.load(tmp_path / "mine.toml")
    strip = lambda t: "\n".join(l for l in t.splitlines() if not l.startswith("urdf ="))
    assert strip(sc.to_toml()) == strip(cli_sc.to_toml())
    r = aift.run(sc.copy().set("duration", 1.0), method="no-ft")
    assert r.summary["outcome"] == "completed"
    # calibrate and train_gp write the files the CLI writes, bit for bit.
    short = aift.Scenario.default(["duration=2.0"])
    info = aift.calibrate(short, tmp_path / "cal.json", runs=3)
    cli("calibrate", "--set", "duration=2.0", "--runs", "3", "--out", tmp_path / "cal_cli.json")
    assert (tmp_path / "cal.json").read_bytes() == (tmp_path / "cal_cli.json").read_bytes()
    assert info["runs"] == 3 and info["ticks"] == 2000
    r1 = aift.run(short, method="pl-detect", calib=tmp_path / "cal.json")
    assert r1.summary["outcome"] == "completed"
    gp = aift.train_gp(short, tmp_path / "gp.json", points=60)
    cli("train-gp", "--set", "duration=2.0", "--points", "60", "--out", tmp_path / "gp_cli.json")
    assert (tmp_path / "gp.json").read_bytes() == (tmp_path / "gp_cli.json").read_bytes()
    assert gp["points"] == 60 and gp["held_out_rms"] > 0


def test_gen_arm_writes_the_bytes_the_cli_writes(tmp_path, cli):
    text = aift.gen_arm(4242, joints=(3, 5), out=tmp_path / "arm.urdf")
    cli("gen-arm", "--seed", "4242", "--joints", "3..5", "--out", tmp_path / "arm_cli.urdf")
    assert (tmp_path / "arm.urdf").read_bytes() == (tmp_path / "arm_cli.urdf").read_bytes()
    assert text == (tmp_path / "arm.urdf").read_text()
    assert aift.gen_arm(4242, joints=(3, 5)) == text
    assert 3 <= len(aift.check_urdf(tmp_path / "arm.urdf")["joints"]) <= 5
    with pytest.raises(aift.BadInput):
        aift.gen_arm(1, joints=13)


def test_type_stub_names_what_the_native_module_has():
    import ast
    import pathlib
    from aift import _aift

    stub = pathlib.Path(aift.__file__).with_name("_aift.pyi")
    tree = ast.parse(stub.read_text())
    stubbed = {n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    stubbed |= {t.id for n in tree.body if isinstance(n, ast.AnnAssign) for t in [n.target]}
    native = {n for n in dir(_aift) if not n.startswith("_") or n == "__version__"}
    assert stubbed == native, (stubbed ^ native)
    for cls in ["Scenario", "Sim"]:
        node = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == cls)
        names = {n.name for n in node.body if isinstance(n, ast.FunctionDef)} - {"__init__"}
        have = {n for n in dir(getattr(_aift, cls)) if not n.startswith("_")}
        assert names == have, (cls, names ^ have)


def test_runs_of_one_scenario_agree_and_a_change_is_seen():
    # The Scenario reuses its prepared arm and GP between runs; runs are deterministic, so this
    # checks that the reuse changes no number and that set() drops it, not that it happens.
    sc = aift.Scenario.default(["duration=2.0"])
    a = aift.run(sc, method="pl-always", seed=2)
    b = aift.run(sc, method="pl-always", seed=2)  # the arm and GP prepared once, reused
    for name in a.trajectory.columns:
        assert_same_bits(a.trajectory[name], b.trajectory[name], name)
    fresh = aift.run(aift.Scenario.default(["duration=2.0"]), method="pl-always", seed=2)
    assert_same_bits(a.trajectory["mu1"], fresh.trajectory["mu1"], "mu1")
    # A change (fewer GP points) is seen by the next run, not hidden by the reuse.
    sc.set("gp.points", 50)
    c = aift.run(sc, method="pl-always", seed=2)
    assert not np.array_equal(a.trajectory["mu1"], c.trajectory["mu1"])


def test_step_api_reports_the_methods_actuator_alarms_as_the_summary_does():
    # A locked joint 2 from 1 s on the paper arm, the hybrid with actuator hypotheses: the step
    # API's info["actuator_alarms"] at the last tick equals the run's summary.json alarms; a
    # method without actuator hypotheses reports None.
    sc = aift.Scenario.default(
        [
            "duration=3.0",
            "faults=[]",
            'actuator_faults=[{joint=2, kind="locked", start=1.0}]',
            "hybrid.actuators=true",
            "hybrid.model_error_state=false",
            'model.inertial_budget="shared-cosine"',
        ]
    )
    r = aift.run(sc, method="hybrid", seed=4)
    expected = r.summary["actuator_alarms"]["alarms"]
    assert expected, "the locked joint raised no alarm"
    sim = aift.Sim(sc, method="hybrid")
    obs, info = sim.reset(seed=4)
    while not info["done"]:
        obs, info = sim.step()
    assert info["actuator_alarms"] == expected
    _, info = aift.Sim(sc, method="pl-always").reset(seed=4)
    assert info["actuator_alarms"] is None
