"""A method written in Python and scored by aift: a Kalman filter in numpy.

A constant-velocity Kalman filter per joint on its encoder and tachometer (the camera is left
out: its model, the GP, lives in aift), with a chi-square gate per reading: a reading whose
normalised innovation squared exceeds `gate` is not used that tick, and its precision is
reported as 0 (so aift counts the channel as excluded: health 0). The protocol (docs/python.md,
"Bring your own method"): `reset(...)` once, then `step(readings, applied, dt)` every tick,
returning (mu, mu_p, precisions).

    python python/examples/numpy_ekf.py [SCENARIO]

runs it beside the built-in `ekf-gate` on the scenario (default: the embedded one, an encoder
freezing at 8 s) for three seeds and prints both methods' numbers;

    python python/examples/numpy_ekf.py --campaign [CAMPAIGN] [--out DIR]

runs both on a campaign (default: small_campaign.toml beside this file: two arms, encoder and
tachometer faults, a healthy cell, three seeds) and prints where their verdicts differ.

Its acceleration noise defaults to aift's `belief.acceleration_bound` (200 rad/s^2), the
acceleration the built-in filters' constant-velocity model treats as one standard deviation.

The precisions it returns are its verdict on each channel: the nominal precision for a reading it
used, 0 for one its gate left out this tick; the camera, which it does not model, keeps its
nominal precision (no verdict is not a failure).
"""

import sys
from pathlib import Path

import numpy as np

import aift


class NumpyKalman:
    name = "numpy-kf"

    def __init__(self, accel_sigma=200.0, gate=25.0):
        self.accel_sigma = accel_sigma
        self.gate = gate

    def reset(self, *, n_joints, channels, dt, nominal, seed):
        self.n = n_joints
        self.nominal = np.asarray(nominal, dtype=float)
        self.enc = [channels.index(f"enc{i + 1}") for i in range(n_joints)]
        self.tach = [channels.index(f"tach{i + 1}") for i in range(n_joints)]
        self.x = None
        self.P = np.tile(np.eye(2) * 1e-2, (n_joints, 1, 1))
        a = self.accel_sigma * dt
        self.Q = np.array([[0.25 * a * a * dt * dt, 0.5 * a * a * dt], [0.5 * a * a * dt, a * a]])
        self.F = np.array([[1.0, dt], [0.0, 1.0]])

    def step(self, readings, applied, dt):
        y = np.asarray(readings, dtype=float)
        used = self.nominal.copy()
        if self.x is None:
            self.x = np.stack([np.nan_to_num(y[self.enc]), np.nan_to_num(y[self.tach])], axis=1)
        for j in range(self.n):
            x = self.F @ self.x[j]
            P = self.F @ self.P[j] @ self.F.T + self.Q
            for row, c in ((0, self.enc[j]), (1, self.tach[j])):
                if np.isnan(y[c]):
                    continue
                s = P[row, row] + 1.0 / self.nominal[c]
                nu = y[c] - x[row]
                if nu * nu / s > self.gate:
                    used[c] = 0.0  # gated: left out this tick
                    continue
                k = P[:, row] / s
                x = x + k * nu
                P = P - np.outer(k, P[row, :])
            self.x[j], self.P[j] = x, P
        return self.x[:, 0], self.x[:, 1], used


SMALL_CAMPAIGN = Path(__file__).resolve().parent / "small_campaign.toml"


def verdicts(campaign_doc, a, b):
    """Per cell: (arm, label, a's cell summary, b's)."""
    out = []
    for cell in campaign_doc["cells"]:
        by = {r["method"]: r for r in cell["results"]}
        out.append((cell["arm"], cell["label"], by[a], by[b]))
    return out


def campaign(path, out):
    rows = aift.campaign(path, methods=["ekf-gate", NumpyKalman], out=out, force=out is not None)
    cells = verdicts(rows.doc, "ekf-gate", NumpyKalman.name)
    same = sum(a["verdict"] == b["verdict"] for _, _, a, b in cells)
    print(f"verdicts agree in {same} of {len(cells)} cells")
    for arm, label, a, b in cells:
        if a["verdict"] != b["verdict"]:
            print(f"  {arm} {label}: ekf-gate {a['verdict']}, {NumpyKalman.name} {b['verdict']}")


def main():
    args = sys.argv[1:]
    if args[:1] == ["--campaign"]:
        rest = args[1:]
        out = None
        if "--out" in rest:
            i = rest.index("--out")
            out, rest = rest[i + 1], rest[:i] + rest[i + 2:]
        return campaign(rest[0] if rest else SMALL_CAMPAIGN, out)
    scenario = args[0] if args else None
    for seed in (1, 2, 3):
        for method in (NumpyKalman, "ekf-gate"):
            r = aift.run(scenario, method, seed, trajectory=False)
            s = r.summary
            print(f"seed {seed} {s['method']:>9}: {s['outcome']}, final error {s['max_final_error']:.4f} rad, "
                  f"faulty-joint MSE {s['mse_faulty']:.2e}, detected at {s['detected_at']}, "
                  f"isolated {s['isolated_channel']}")


if __name__ == "__main__":
    main()
