"""Ticks per second of the closed loop from Python, side by side in one call: `aift.run` (the
whole run in Rust, GIL released) against a Python loop of `Sim.step()` (one call per tick).

    python tools/python_speed.py [--duration 20]

Needs the package installed (`pip install ./python`)."""

import argparse
import time

import aift

p = argparse.ArgumentParser()
p.add_argument("--duration", type=float, default=20.0)
p.add_argument("--method", default="pl-always")
a = p.parse_args()
sc = aift.Scenario.default([f"duration={a.duration}"])
aift.run(sc, method=a.method)  # GP trained and caches warm
t = time.perf_counter()
r = aift.run(sc, method=a.method)
run_s = time.perf_counter() - t
sim = aift.Sim(sc, method=a.method)
t = time.perf_counter()
obs, info = sim.reset()
while not info["done"]:
    obs, info = sim.step()
step_s = time.perf_counter() - t
ticks = len(r.trajectory)
print(f"aift.run (in memory):  {ticks / run_s:10,.0f} ticks/s")
print(f"Sim.step() loop:       {ticks / step_s:10,.0f} ticks/s  ({run_s / step_s:.2f} of aift.run)")
