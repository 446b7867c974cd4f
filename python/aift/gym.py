"""A gymnasium environment around :class:`aift.Sim` (needs ``gymnasium``).

Observation: the readings (``sim.channels`` order, a missing reading as 0) followed by the
target joint angles. Action: joint torques (``action="torque"``, the controller ignored), or
torques added to the u-AIC's own (``action="residual"``, for residual learning on top of active
inference). Reward: minus the squared joint error to the target. ``terminated`` when the run
diverges, ``truncated`` on the scenario's last tick.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import gymnasium as gym
from gymnasium import spaces

from . import Sim, _scenario


class AiftEnv(gym.Env):
    metadata = {"render_modes": []}

    def __init__(self, scenario=None, method: Optional[str] = None, action: str = "residual",
                 max_torque: float = 50.0, calib=None):
        if action not in ("torque", "residual"):
            raise ValueError(f"action must be 'torque' or 'residual', not {action!r}")
        self._scenario = _scenario(scenario)
        self.sim = Sim(self._scenario, method, calib=calib)
        self.action_mode = action
        limits = np.array([max_torque if e is None else e for e in self.sim.effort_limits], dtype=np.float64)
        self.action_space = spaces.Box(-limits, limits, dtype=np.float64)
        n_obs = len(self.sim.channels) + self.sim.n_joints
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(n_obs,), dtype=np.float64)
        self._obs = None
        self._done = False

    def _observation(self, obs) -> np.ndarray:
        y = np.nan_to_num(obs["y"], nan=0.0, posinf=0.0, neginf=0.0)
        return np.concatenate([y, obs["target"]]).astype(np.float64)

    def reset(self, *, seed: Optional[int] = None, options=None):
        super().reset(seed=seed)
        # gymnasium takes any non-negative integer seed; aift's are 64-bit: larger ones are
        # reduced modulo 2**64.
        aift_seed = self._scenario.seed if seed is None else int(seed) % (1 << 64)
        obs, info = self.sim.reset(aift_seed)
        self._obs = obs
        self._done = False
        return self._observation(obs), dict(info)

    def step(self, action):
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        if self._done:
            raise gym.error.ResetNeeded("the episode has ended (terminated or truncated); call reset()")
        a = np.clip(np.asarray(action, dtype=np.float64), self.action_space.low, self.action_space.high)
        torques = a if self.action_mode == "torque" else self._obs["u"] + a
        obs, info = self.sim.step(torques=torques)
        self._obs = obs
        reward = -float(np.sum((obs["target"] - obs["q"]) ** 2))
        terminated = info["diverged"] is not None
        truncated = bool(info["done"]) and not terminated
        self._done = terminated or truncated
        return self._observation(obs), reward, terminated, truncated, dict(info)
