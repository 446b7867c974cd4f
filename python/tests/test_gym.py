"""The gymnasium wrapper passes gymnasium's own environment checker."""

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

import aift
from aift.gym import AiftEnv


def test_env_checker_passes():
    from gymnasium.utils.env_checker import check_env

    env = AiftEnv(aift.Scenario.default(["duration=0.5"]), method="pl-always")
    check_env(env, skip_render_check=True)


def test_residual_zero_action_is_the_controller():
    sc = aift.Scenario.default(["duration=0.3", "faults=[]"])
    env = AiftEnv(sc, method="no-ft", action="residual")
    obs, _ = env.reset(seed=2)
    steps = 0
    truncated = terminated = False
    while not (truncated or terminated):
        obs, reward, terminated, truncated, info = env.step(np.zeros(env.action_space.shape))
        steps += 1
    r = aift.run(sc, method="no-ft", seed=2)
    assert steps == len(r.trajectory) - 1
    assert env.sim.ticks == len(r.trajectory)
    assert not terminated
