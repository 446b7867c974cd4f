"""Careless and hostile use of the Python package (issue 30, class 10): a method list given as one
string, stepping past the end or before reset, gymnasium's large seeds, a Sim used from another
thread, Ctrl-C during a table or a calibration, and outputs that are FIFOs."""

import os
import threading

import numpy as np
import pytest

import aift


def test_methods_as_one_string_are_names_not_letters():
    sc = aift.Scenario.default(["duration=1.0", "plant.engine=\"articulated\""])
    rows = aift.table(sc, methods="no-ft", seeds=1)
    assert [r["method"] for r in rows.rows] == ["no-ft"]
    rows = aift.table(sc, methods="no-ft, oracle", seeds=1)
    assert [r["method"] for r in rows.rows] == ["no-ft", "oracle"]


def test_a_sim_refuses_to_step_past_its_end():
    sim = aift.Sim(aift.Scenario.default(["duration=0.2", "faults=[]"]), method="no-ft")
    with pytest.raises(aift.AiftError, match="reset"):
        sim.step()
    obs, info = sim.reset(seed=1)
    steps = 0
    while not info["done"]:
        obs, info = sim.step()
        steps += 1
    assert steps == sim.ticks - 1
    with pytest.raises(aift.AiftError, match="has ended"):
        sim.step()
    # reset() starts over.
    obs, info = sim.reset(seed=1)
    assert obs["tick"] == 0


def test_a_sim_works_from_another_thread():
    sc = aift.Scenario.default(["duration=0.2", "faults=[]"])
    sim = aift.Sim(sc, method="no-ft")
    seen = {}

    def work():
        try:
            obs, info = sim.reset(seed=3)
            while not info["done"]:
                obs, info = sim.step()
            seen["mu"] = list(obs["mu"])
        except Exception as e:  # a PanicException would not be caught here
            seen["error"] = e

    t = threading.Thread(target=work)
    t.start()
    t.join()
    assert "error" not in seen, seen.get("error")
    r = aift.run(sc, method="no-ft", seed=3)
    assert seen["mu"] == [r.trajectory["mu1"][-1], r.trajectory["mu2"][-1]]


def test_the_gym_env_needs_reset_and_takes_any_gymnasium_seed():
    gym = pytest.importorskip("gymnasium")
    from aift.gym import AiftEnv

    env = AiftEnv(aift.Scenario.default(["duration=0.2", "faults=[]"]), method="no-ft")
    zero = np.zeros(env.action_space.shape)
    with pytest.raises(gym.error.ResetNeeded):
        env.step(zero)
    env.reset(seed=2**70)
    env.reset(seed=2**64 + 5)
    a = env.sim.step()[0]["y"]
    env.reset(seed=5)
    b = env.sim.step()[0]["y"]
    assert np.array_equal(a, b, equal_nan=True)
    env.reset(seed=1)
    truncated = terminated = False
    while not (truncated or terminated):
        _, _, terminated, truncated, _ = env.step(zero)
    with pytest.raises(gym.error.ResetNeeded):
        env.step(zero)


def test_ctrl_c_stops_tables_campaigns_and_calibrations(tmp_path, tiny_campaign, interrupted):
    long = aift.Scenario.default(["duration=300.0", "plant.engine=\"articulated\"", "faults=[]"])
    aift.run(long.copy().set("duration", 0.1), method="no-ft")  # the GP trained
    interrupted(lambda: aift.table(long, methods=["no-ft", "oracle"], seeds=4, out=tmp_path / "t"))
    assert not (tmp_path / "t").exists()
    interrupted(lambda: aift.calibrate(long, tmp_path / "cal.json", runs=20))
    assert not (tmp_path / "cal.json").exists()
    campaign = tmp_path / "c.toml"
    campaign.write_text(tiny_campaign("interrupted", methods=("no-ft",))
                        .replace("seeds = 1", "seeds = 4").replace("duration = 9.0", "duration = 300.0"))
    interrupted(lambda: aift.campaign(campaign, out=tmp_path / "c"))
    assert not (tmp_path / "c").exists()
    # The campaign's journal stays for a later call to resume, holding no stopped run: only its
    # header (no job of 300 s finished).
    journal = tmp_path / ".c.aift-journal"
    assert len(journal.read_text().splitlines()) == 1
    # Runs go on normally afterwards.
    r = aift.run(long.copy().set("duration", 0.1), method="no-ft")
    assert r.summary["outcome"] == "completed"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".c.aift-journal", "c.toml"]


def test_outputs_that_are_fifos_are_refused_and_left_alone(tmp_path):
    fifo = tmp_path / "out.json"
    os.mkfifo(fifo)
    sc = aift.Scenario.default(["duration=1.0"])
    for call in (lambda: aift.calibrate(sc, fifo, runs=2), lambda: aift.train_gp(sc, fifo)):
        with pytest.raises(aift.BadInput, match="FIFO"):
            call()
        assert fifo.is_fifo()


def test_setting_a_scenario_that_another_thread_runs_is_an_error_not_a_panic():
    sc = aift.Scenario.default(["duration=30.0", "plant.engine=\"articulated\"", "faults=[]"])
    aift.run(sc.copy().set("duration", 0.1), method="no-ft")  # the GP trained
    started = threading.Event()
    done = {}

    def work():
        started.set()
        done["r"] = aift.run(sc, method="no-ft", trajectory=False)

    t = threading.Thread(target=work)
    t.start()
    started.wait()
    import time

    errors = []
    deadline = time.monotonic() + 5.0
    while t.is_alive() and time.monotonic() < deadline and not errors:
        try:
            sc.set("seed", 4)
        except aift.AiftError as e:
            errors.append(e)
        time.sleep(0.01)
    t.join()
    assert errors and "another thread" in str(errors[0])
    assert done["r"].summary["outcome"] == "completed"
