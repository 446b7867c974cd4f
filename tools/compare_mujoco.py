#!/usr/bin/env python3
"""Side-by-side speed comparison of aift's closed loop against bare MuJoCo stepping.

One invocation loads the same URDF arm into MuJoCo and times, interleaved
(MuJoCo, aift, MuJoCo, aift, ...; the order alternates every repeat so machine load
affects both alike):

  * MuJoCo ``mj_step`` called N times from a Python loop (the reference figure);
  * MuJoCo ``mj_step(m, d, nstep=N)``: the same N steps looped in C;
  * ``mujoco.rollout`` (if available): N steps in C, states copied out every step;
  * ``aift bench SCENARIO --ticks N``: its ``physics_ticks_per_s`` (rapier stepping alone,
    N ticks) and ``closed_loop_ticks_per_s`` (one whole scenario run: physics, sensors, GP,
    u-AIC belief update, controller and precision learner every tick).

Every figure is repeated R times; the table shows the median and [min, max]. The MuJoCo runs
mirror aift's physics bench: start at the scenario's ``[initial] q`` (zeros if it cannot be
read) at rest and apply a constant generalized force of ``--torque`` (default 1.0, as aift's
bench does) to every joint through ``data.qfrc_applied``.

MuJoCo is set up as aift's arm: gravity (0, 0, -9.81), timestep = the scenario's dt (0.001),
contacts disabled (aift's arm is contact-free), joint limits kept (aift keeps them too),
integrator Euler unless ``--integrator`` says otherwise. The URDF gets a
``<mujoco><compiler discardvisual="true" fusestatic="false" inertiafromgeom="false" .../></mujoco>``
element so that fixed-joint links (the end effector) stay bodies and links without ``<inertial>``
stay massless (MuJoCo would give them their collision geometry's mass); the script checks that MuJoCo's joint damping
(``model.dof_damping``), friction loss and link masses match the URDF's.

``--check-dynamics`` additionally runs both simulators open loop for ``--check-duration``
seconds (default 2) from the same state at rest with zero torque (``aift simulate``) and prints
the difference of the final joint angles, velocities and end-effector position. The default
start is the scenario's first target (the hanging initial pose of the shipped scenarios is an
equilibrium, where nothing would move); ``--check-q0`` overrides it. A MuJoCo RK4 run at the
same dt is printed too, as a measure of the integrator error alone.

Usage (from anywhere; default paths are relative to the repository root, the parent of this
script's folder; relative paths given on the command line are taken relative to the current
directory, or to the repository root if they do not exist there)::

    tools/compare_mujoco.py                       # paper arm, 20000 steps, 5 repeats
    tools/compare_mujoco.py --check-dynamics
    tools/compare_mujoco.py --set plant.engine=articulated   # aift's own engine
    tools/compare_mujoco.py --urdf urdf/spatial_3dof.urdf \\
        --scenario assets/scenarios/spatial3_encoder_freeze.toml --repeats 3

Requires Python >= 3.8 (3.11+ reads the scenario with ``tomllib``), numpy and the ``mujoco``
package from PyPI (``python3 -m venv /tmp/mjvenv && /tmp/mjvenv/bin/pip install mujoco numpy``),
and a built aift binary (``--aift``, default target/release/aift; this script never builds it).

The line ``ratio_closed_loop_over_mujoco: X`` (aift closed-loop ticks/s over MuJoCo mj_step
Python-loop steps/s) is printed on its own for grepping, beside other ``name: value`` lines.
"""

import argparse
import csv
import gc
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

try:
    import numpy as np
except ImportError:  # pragma: no cover - message only
    sys.exit("compare_mujoco.py: numpy is missing; install it, e.g. "
             "`python3 -m venv /tmp/mjvenv && /tmp/mjvenv/bin/pip install mujoco numpy`")

try:
    import mujoco
except ImportError:  # pragma: no cover - message only
    sys.exit("compare_mujoco.py: the `mujoco` Python package is missing; install it from PyPI, e.g. "
             "`python3 -m venv /tmp/mjvenv && /tmp/mjvenv/bin/pip install mujoco numpy`, "
             "then run this script with /tmp/mjvenv/bin/python")

try:
    from mujoco import rollout as mj_rollout
except ImportError:
    mj_rollout = None


# --------------------------------------------------------------------------------------------
# Paths and the scenario
# --------------------------------------------------------------------------------------------

def resolve(path):
    """A command-line path: as given if it exists (relative to the cwd), else under the repo."""
    p = Path(path).expanduser()
    if p.is_absolute() or p.exists():
        return p.resolve()
    return (REPO / p).resolve()


def read_scenario(path):
    """The few scenario values used here: dt, duration, robot.urdf, robot.ee_link,
    plant.rapier.solver_iterations, initial.q, targets[0].q. Missing values are None."""
    text = path.read_text()
    data = None
    try:
        import tomllib  # Python 3.11+
        data = tomllib.loads(text)
    except ImportError:
        try:
            import tomli as tomllib  # type: ignore
            data = tomllib.loads(text)
        except ImportError:
            data = None
    except Exception as exc:  # malformed TOML: report and fall back to the regex reader
        print(f"warning: {path}: TOML parse failed ({exc}); reading it approximately",
              file=sys.stderr)
    if data is not None:
        robot = data.get("robot", {})
        targets = data.get("targets", [])
        return {
            "dt": data.get("dt"),
            "duration": data.get("duration"),
            "urdf": robot.get("urdf"),
            "ee_link": robot.get("ee_link"),
            "solver_iterations": data.get("plant", {}).get("rapier", {}).get("solver_iterations"),
            "q0": data.get("initial", {}).get("q"),
            "target_q": targets[0].get("q") if targets else None,
        }
    # Approximate reader for Pythons without tomllib: sections and `key = value` lines.
    out = {k: None for k in ("dt", "duration", "urdf", "ee_link", "solver_iterations", "q0",
                             "target_q")}
    section = ""
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        m = re.match(r"^\[\[?\s*([\w.]+)\s*\]?\]$", line)
        if m:
            new = m.group(1)
            section = new if not (new == "targets" and section.startswith("targets")) \
                else "targets+"
            continue
        m = re.match(r"^(\w+)\s*=\s*(.+)$", line)
        if not m:
            continue
        key, val = m.group(1), m.group(2).strip()

        def num_list(v):
            return [float(x) for x in v.strip("[]").split(",") if x.strip()]
        try:
            if section == "" and key in ("dt", "duration"):
                out[key] = float(val)
            elif section == "robot" and key in ("urdf", "ee_link"):
                out[key] = val.strip("\"'")
            elif section == "plant.rapier" and key == "solver_iterations":
                out[key] = int(val)
            elif section == "initial" and key == "q":
                out["q0"] = num_list(val)
            elif section == "targets" and key == "q" and out["target_q"] is None:
                out["target_q"] = num_list(val)
        except ValueError:
            pass
    return out


# --------------------------------------------------------------------------------------------
# MuJoCo model
# --------------------------------------------------------------------------------------------

def urdf_joint_specs(urdf_text):
    """Movable joints of the URDF in file order: name -> (damping, friction)."""
    root = ET.fromstring(urdf_text)
    specs = {}
    for j in root.findall("joint"):
        if j.get("type") == "fixed":
            continue
        dyn = j.find("dynamics")
        damping = float(dyn.get("damping", 0.0)) if dyn is not None else 0.0
        friction = float(dyn.get("friction", 0.0)) if dyn is not None else 0.0
        specs[j.get("name")] = (damping, friction)
    masses = {}
    for link in root.findall("link"):
        inertial = link.find("inertial")
        mass = inertial.find("mass") if inertial is not None else None
        masses[link.get("name")] = float(mass.get("value")) if mass is not None else 0.0
    return specs, masses


def prepare_urdf(urdf_path):
    """The URDF text with a <mujoco><compiler .../></mujoco> element, and notes on what was done."""
    text = urdf_path.read_text()
    notes = []
    if re.search(r"<mujoco\b", text):
        notes.append("URDF already has a <mujoco> element; left as is (fusestatic may be on)")
        return text, notes
    # inertiafromgeom="false": a link without <inertial> is massless, as URDF says (MuJoCo would
    # otherwise give it the mass of its collision geometry).
    compiler = ('<mujoco><compiler discardvisual="true" fusestatic="false" '
                'inertiafromgeom="false" strippath="false" '
                f'meshdir="{urdf_path.parent}/"/></mujoco>')
    new, count = re.subn(r"(<robot\b[^>]*>)", lambda m: m.group(1) + compiler, text, count=1)
    if count != 1:
        sys.exit(f"{urdf_path}: no <robot> element found; not a URDF?")
    notes.append("inserted <mujoco><compiler discardvisual=\"true\" fusestatic=\"false\" "
                 "inertiafromgeom=\"false\"/></mujoco> (fixed-joint links such as the end "
                 "effector stay bodies; links without <inertial> stay massless)")
    return new, notes


def integrator_choices():
    return {name[len("mjINT_"):].lower(): val
            for name, val in mujoco.mjtIntegrator.__members__.items()}


def load_mujoco(urdf_path, dt, integrator):
    text, notes = prepare_urdf(urdf_path)
    model = mujoco.MjModel.from_xml_string(text)
    model.opt.timestep = dt
    model.opt.gravity[:] = (0.0, 0.0, -9.81)
    model.opt.integrator = integrator_choices()[integrator]
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)

    # Joint damping, friction and masses as the URDF says.
    specs, masses = urdf_joint_specs(urdf_path.read_text())
    names = [model.joint(i).name for i in range(model.njnt)]
    if model.nq != model.nv or model.nv != len(specs):
        sys.exit(f"MuJoCo built nq={model.nq}, nv={model.nv} from {len(specs)} movable URDF "
                 "joints; only serial arms of 1-dof joints are compared here")
    problems = []
    for i, name in enumerate(names):
        if name not in specs:
            problems.append(f"joint {name!r} is not a movable URDF joint")
            continue
        damping, friction = specs[name]
        dof = model.jnt_dofadr[i]
        if not np.isclose(model.dof_damping[dof], damping, rtol=1e-12, atol=0):
            problems.append(f"joint {name!r}: dof_damping {model.dof_damping[dof]} != URDF {damping}")
        if not np.isclose(model.dof_frictionloss[dof], friction, rtol=1e-12, atol=0):
            problems.append(f"joint {name!r}: dof_frictionloss {model.dof_frictionloss[dof]} "
                            f"!= URDF friction {friction}")
    if list(specs) != names:
        problems.append(f"joint order differs: URDF {list(specs)} vs MuJoCo {names}")
    body_names = [model.body(i).name for i in range(model.nbody)]
    for link, mass in masses.items():
        if link in body_names:
            got = model.body_mass[body_names.index(link)]
            if not np.isclose(got, mass, rtol=1e-12, atol=1e-12):
                problems.append(f"link {link!r}: MuJoCo mass {got} != URDF {mass}")
        elif mass > 0:
            notes.append(f"link {link!r} (mass {mass}) is not a MuJoCo body (merged)")
    if problems:
        sys.exit("MuJoCo's model disagrees with the URDF:\n  " + "\n  ".join(problems))
    if model.dof_armature.any():
        notes.append(f"note: dof_armature = {model.dof_armature.tolist()} (aift has none)")
    return model, notes


def describe_model(model):
    lines = []
    for i in range(model.njnt):
        j = model.joint(i)
        dof = model.jnt_dofadr[i]
        kind = {0: "free", 1: "ball", 2: "slide", 3: "hinge"}.get(int(model.jnt_type[i]), "?")
        lim = (f"range [{model.jnt_range[i][0]:g}, {model.jnt_range[i][1]:g}]"
               if model.jnt_limited[i] else "unlimited")
        lines.append(f"  {j.name:10s} {kind:6s} axis {np.array2string(model.jnt_axis[i], precision=3)}"
                     f"  damping {model.dof_damping[dof]:.10g}  frictionloss "
                     f"{model.dof_frictionloss[dof]:.10g}  armature {model.dof_armature[dof]:g}  {lim}")
    lines.append("  bodies: " + ", ".join(f"{model.body(i).name}({model.body_mass[i]:g} kg)"
                                          for i in range(model.nbody)))
    integ = [k for k, v in integrator_choices().items() if v == model.opt.integrator]
    lines.append(f"  timestep {model.opt.timestep:g}  gravity {model.opt.gravity.tolist()}  "
                 f"integrator {integ[0] if integ else model.opt.integrator}  contacts disabled: "
                 f"{bool(model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CONTACT))}")
    return lines


def reset(model, data, q0, tau):
    mujoco.mj_resetData(model, data)
    data.qpos[:] = q0
    data.qvel[:] = 0.0
    data.qfrc_applied[:] = tau
    mujoco.mj_forward(model, data)


# --------------------------------------------------------------------------------------------
# Timed runs
# --------------------------------------------------------------------------------------------

def time_python_loop(model, data, q0, tau, n):
    reset(model, data, q0, tau)
    step = mujoco.mj_step
    gc_was = gc.isenabled()
    gc.disable()
    try:
        t = time.perf_counter()
        for _ in range(n):
            step(model, data)
        elapsed = time.perf_counter() - t
    finally:
        if gc_was:
            gc.enable()
    return n / elapsed, data.qpos.copy()


def time_nstep(model, data, q0, tau, n):
    reset(model, data, q0, tau)
    t = time.perf_counter()
    mujoco.mj_step(model, data, nstep=n)
    elapsed = time.perf_counter() - t
    return n / elapsed, data.qpos.copy()


class RolloutRunner:
    """mujoco.rollout from the same state under a constant qfrc_applied (single thread)."""

    def __init__(self, model, q0, tau, n):
        self.model, self.n = model, n
        self.data = mujoco.MjData(model)
        reset(model, self.data, q0, 0.0)
        self.spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        nstate = mujoco.mj_stateSize(model, self.spec)
        self.state0 = np.empty(nstate)
        mujoco.mj_getState(model, self.data, self.state0, self.spec)
        self.control = np.full((1, 1, model.nv), float(tau))  # tiled over all steps
        self.out = np.empty((1, n, nstate))
        self.qpos_slice = slice(1, 1 + model.nq)  # FULLPHYSICS = time, qpos, qvel, ...

    def __call__(self):
        t = time.perf_counter()
        mj_rollout.rollout(self.model, self.data, self.state0, self.control,
                           control_spec=int(mujoco.mjtState.mjSTATE_QFRC_APPLIED),
                           nstep=self.n, state=self.out)
        elapsed = time.perf_counter() - t
        return self.n / elapsed, self.out[0, -1, self.qpos_slice].copy()


def run_aift_bench(aift, scenario, n, sets=()):
    cmd = [str(aift), "bench", str(scenario), "--ticks", str(n)]
    for kv in sets:
        cmd += ["--set", kv]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"`{' '.join(cmd)}` failed ({proc.returncode}):\n{proc.stderr.strip()}")
    figures = {}
    for line in proc.stdout.splitlines():
        m = re.match(r"^\s*([A-Za-z_]\w*)\s*:\s*(\S+)", line)
        if m:
            try:
                figures[m.group(1)] = float(m.group(2))
            except ValueError:
                figures[m.group(1)] = m.group(2)
    for key in ("physics_ticks_per_s", "closed_loop_ticks_per_s"):
        if not isinstance(figures.get(key), float):
            sys.exit(f"`{' '.join(cmd)}` printed no {key}:\n{proc.stdout}")
    return figures


# --------------------------------------------------------------------------------------------
# Dynamics check
# --------------------------------------------------------------------------------------------

def mujoco_open_loop(model, q0, duration, integrator, ee_link):
    saved = model.opt.integrator
    model.opt.integrator = integrator_choices()[integrator]
    try:
        data = mujoco.MjData(model)
        reset(model, data, q0, 0.0)
        nsteps = int(round(duration / model.opt.timestep))
        mujoco.mj_step(model, data, nstep=nsteps)
        mujoco.mj_forward(model, data)  # mj_step leaves xpos at the pre-step positions
        ee = None
        try:
            ee = data.body(ee_link).xpos.copy()
        except KeyError:
            pass
        return data.qpos.copy(), data.qvel.copy(), ee, data.time
    finally:
        model.opt.integrator = saved


def check_dynamics(args, model, urdf, q0, ee_link):
    n = model.nq
    fmt = lambda v: "[" + ", ".join(f"{x: .9f}" for x in v) + "]"
    with tempfile.TemporaryDirectory(prefix="compare_mujoco_") as tmp:
        out = Path(tmp) / "aift_simulate.csv"
        cmd = [str(args.aift), "simulate", "--urdf", str(urdf), "--ee", ee_link,
               "--q0=" + ",".join(repr(float(x)) for x in q0),
               "--duration", repr(args.check_duration), "--dt", repr(model.opt.timestep),
               "--out", str(out)]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(f"`{' '.join(cmd)}` failed ({proc.returncode}):\n{proc.stderr.strip()}")
        with out.open(newline="") as f:
            rows = list(csv.DictReader(f))
    last = rows[-1]
    a_t = float(last["t"])
    a_q = np.array([float(last[f"q{i + 1}"]) for i in range(n)])
    a_qd = np.array([float(last[f"qd{i + 1}"]) for i in range(n)])
    a_ee = (np.array([float(last[k]) for k in ("ee_x", "ee_y", "ee_z")])
            if all(k in last for k in ("ee_x", "ee_y", "ee_z")) else None)

    integ = args.integrator
    m_q, m_qd, m_ee, m_t = mujoco_open_loop(model, q0, args.check_duration, integ, ee_link)
    r_q, r_qd, r_ee, _ = mujoco_open_loop(model, q0, args.check_duration, "rk4", ee_link)

    print()
    print(f"== dynamics check: open loop, zero torque, from q0 = {fmt(q0)} at rest, "
          f"{args.check_duration:g} s at dt {model.opt.timestep:g} ==")
    print(f"  aift t = {a_t:g} s ({len(rows)} rows), MuJoCo t = {m_t:g} s")
    lab = lambda s: f"{s:<20s}"
    print(f"  q  {lab('aift')}{fmt(a_q)}")
    print(f"  q  {lab('MuJoCo ' + integ)}{fmt(m_q)}")
    print(f"  q  {lab('MuJoCo rk4')}{fmt(r_q)}")
    print(f"  qd {lab('aift')}{fmt(a_qd)}")
    print(f"  qd {lab('MuJoCo ' + integ)}{fmt(m_qd)}")
    dq = a_q - m_q
    print(f"  q  aift - MuJoCo {integ}: {fmt(dq)}  max |.| = {np.abs(dq).max():.3e} rad")
    if integ != "rk4":
        print(f"  q  aift - MuJoCo rk4: {fmt(a_q - r_q)}  max |.| = {np.abs(a_q - r_q).max():.3e} rad")
        print(f"  q  MuJoCo {integ} - MuJoCo rk4 (integrator error alone): "
              f"max |.| = {np.abs(m_q - r_q).max():.3e} rad")
    print(f"  qd aift - MuJoCo {integ}: max |.| = {np.abs(a_qd - m_qd).max():.3e} rad/s")
    print(f"  q travelled (|q_end - q0|, MuJoCo rk4): max = {np.abs(r_q - np.asarray(q0)).max():.3e} rad")
    if a_ee is not None and m_ee is not None:
        print(f"  ee aift {fmt(a_ee)}  MuJoCo {fmt(m_ee)}  |diff| = "
              f"{np.linalg.norm(a_ee - m_ee):.3e} m")
    print(f"dynamics_max_abs_dq_rad: {np.abs(dq).max():.6e}")


# --------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------

def stats(values):
    return statistics.median(values), min(values), max(values)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--urdf", default=None,
                    help="URDF of the arm (default urdf/planar_2dof.urdf under the repo root)")
    ap.add_argument("--scenario", default=None,
                    help="aift scenario using that URDF "
                         "(default assets/scenarios/paper_encoder_freeze.toml)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="passed to `aift bench --set` (repeatable), e.g. plant.engine=articulated")
    ap.add_argument("--steps", type=int, default=20000, help="steps/ticks per timed run (20000)")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs of each figure (5)")
    ap.add_argument("--aift", default=None, help="aift binary (default target/release/aift)")
    ap.add_argument("--integrator", default="euler", choices=sorted(integrator_choices()),
                    help="MuJoCo integrator (default euler, MuJoCo's default)")
    ap.add_argument("--torque", type=float, default=1.0,
                    help="constant generalized force on every joint while timing (1.0, as aift bench)")
    ap.add_argument("--check-dynamics", action="store_true",
                    help="also compare a zero-torque open-loop run of both simulators")
    ap.add_argument("--check-q0", default=None,
                    help="start of the dynamics check, comma-separated "
                         "(default the scenario's first target q)")
    ap.add_argument("--check-duration", type=float, default=2.0, help="seconds (2)")
    ap.add_argument("--ee", default=None, help="end-effector link (default the scenario's, else ee)")
    args = ap.parse_args()

    urdf = resolve(args.urdf) if args.urdf else REPO / "urdf/planar_2dof.urdf"
    scenario = (resolve(args.scenario) if args.scenario
                else REPO / "assets/scenarios/paper_encoder_freeze.toml")
    args.aift = resolve(args.aift) if args.aift else REPO / "target/release/aift"
    for what, p in (("URDF", urdf), ("scenario", scenario)):
        if not p.is_file():
            sys.exit(f"{what} not found: {p}")
    if not (args.aift.is_file() and os.access(args.aift, os.X_OK)):
        sys.exit(f"aift binary not found or not executable: {args.aift} "
                 "(build it with `cargo build --release`, or pass --aift)")
    if args.steps < 1 or args.repeats < 1:
        sys.exit("--steps and --repeats must be >= 1")

    sc = read_scenario(scenario)
    if sc["urdf"]:
        sc_urdf = (scenario.parent / sc["urdf"]).resolve()
        if sc_urdf != urdf.resolve():
            sys.exit(f"the scenario's robot.urdf is {sc_urdf}, not {urdf}: aift and MuJoCo "
                     "would simulate different arms; pass the matching --urdf/--scenario pair")
    dt = float(sc["dt"]) if sc["dt"] else 0.001
    ee_link = args.ee or sc["ee_link"] or "ee"

    model, notes = load_mujoco(urdf, dt, args.integrator)
    n = model.nq
    q0 = sc["q0"]
    if q0 is None or len(q0) != n:
        print(f"note: scenario [initial] q unreadable or of the wrong length ({q0}); using zeros")
        q0 = [0.0] * n
    q0 = np.array(q0, dtype=float)

    aift_version = subprocess.run([str(args.aift), "--version"], capture_output=True,
                                  text=True).stdout.strip()
    print("== compare_mujoco ==")
    print(f"mujoco_version: {mujoco.__version__} (library {mujoco.mj_versionString()})")
    print(f"aift_version: {aift_version}")
    print(f"python: {platform.python_version()}  numpy: {np.__version__}  machine: "
          f"{platform.machine()} {platform.processor() or ''} cores: {os.cpu_count()}")
    print(f"urdf: {urdf}")
    print(f"scenario: {scenario}")
    print(f"steps: {args.steps}  repeats: {args.repeats}  dt: {dt:g}  torque: {args.torque:g}  "
          f"q0: {q0.tolist()}")
    print("MuJoCo model:")
    for line in describe_model(model):
        print(line)
    for note in notes:
        print(f"  {note}")

    if args.check_dynamics:
        cq0 = ([float(x) for x in args.check_q0.split(",")] if args.check_q0
               else (sc["target_q"] if sc["target_q"] and len(sc["target_q"]) == n else None))
        if cq0 is None:
            cq0 = (q0 + 0.3).tolist()
        if len(cq0) != n:
            sys.exit(f"--check-q0 needs {n} values")
        check_dynamics(args, model, urdf, cq0, ee_link)

    # Warm-up (imports, caches, page faults), not timed.
    data = mujoco.MjData(model)
    time_python_loop(model, data, q0, args.torque, min(args.steps, 2000))
    rollout = RolloutRunner(model, q0, args.torque, args.steps) if mj_rollout else None
    if rollout:
        rollout()

    res = {"loop": [], "nstep": [], "rollout": [], "aift_phys": [], "aift_closed": []}
    finals = {}
    print()
    print("timing (interleaved):", flush=True)
    for r in range(args.repeats):
        def mujoco_runs():
            v, finals["loop"] = time_python_loop(model, data, q0, args.torque, args.steps)
            res["loop"].append(v)
            v, finals["nstep"] = time_nstep(model, data, q0, args.torque, args.steps)
            res["nstep"].append(v)
            if rollout:
                v, finals["rollout"] = rollout()
                res["rollout"].append(v)

        def aift_run():
            fig = run_aift_bench(args.aift, scenario, args.steps, args.set)
            res["aift_phys"].append(fig["physics_ticks_per_s"])
            res["aift_closed"].append(fig["closed_loop_ticks_per_s"])

        order = (mujoco_runs, aift_run) if r % 2 == 0 else (aift_run, mujoco_runs)
        for f in order:
            f()
        print(f"  repeat {r + 1}/{args.repeats}: mj_step loop {res['loop'][-1]:,.0f}/s, "
              f"aift physics {res['aift_phys'][-1]:,.0f}/s, "
              f"aift closed loop {res['aift_closed'][-1]:,.0f}/s", flush=True)

    # The three MuJoCo ways of stepping must agree on the state they reach.
    if rollout and not np.allclose(finals["loop"], finals["rollout"], atol=1e-9):
        print(f"WARNING: rollout ended at {finals['rollout']} but the loop at {finals['loop']}")
    if not np.allclose(finals["loop"], finals["nstep"], atol=1e-9):
        print(f"WARNING: nstep ended at {finals['nstep']} but the loop at {finals['loop']}")

    loop_med = stats(res["loop"])[0]
    closed_note = ""
    if sc["duration"] and dt:
        closed_note = f" (one {sc['duration']:g} s scenario run = {round(sc['duration'] / dt)} ticks)"
    rows = [
        ("MuJoCo mj_step, Python loop (steps/s)", res["loop"]),
        ("MuJoCo mj_step(nstep=N), C loop (steps/s)", res["nstep"]),
        ("MuJoCo rollout, C loop + state copy (steps/s)", res["rollout"]),
        ("aift physics only (ticks/s)", res["aift_phys"]),
        ("aift closed loop (ticks/s)" + ("*" if closed_note else ""), res["aift_closed"]),
    ]
    print()
    print(f"== results: median [min, max] of {args.repeats} runs, {args.steps} steps each, "
          f"MuJoCo integrator {args.integrator} ==")
    w = max(len(r[0]) for r in rows)
    print(f"{'figure':{w}s}  {'median':>12s}  {'min':>12s}  {'max':>12s}  {'/ mj_step loop':>14s}")
    for name, vals in rows:
        if not vals:
            print(f"{name:{w}s}  {'n/a (mujoco.rollout not available)':>12s}")
            continue
        med, lo, hi = stats(vals)
        print(f"{name:{w}s}  {med:12,.0f}  {lo:12,.0f}  {hi:12,.0f}  {med / loop_med:14.3f}")
    if closed_note:
        print(f"* aift closed loop{closed_note}: physics, sensors, GP, u-AIC, controller and "
              "precision learner each tick")
    print()
    phys_med = stats(res["aift_phys"])[0]
    closed_med = stats(res["aift_closed"])[0]
    print(f"mujoco_step_loop_steps_per_s: {loop_med:.1f}")
    print(f"mujoco_step_nstep_steps_per_s: {stats(res['nstep'])[0]:.1f}")
    if res["rollout"]:
        print(f"mujoco_rollout_steps_per_s: {stats(res['rollout'])[0]:.1f}")
    print(f"aift_physics_ticks_per_s: {phys_med:.1f}")
    print(f"aift_closed_loop_ticks_per_s: {closed_med:.1f}")
    print(f"ratio_physics_over_mujoco: {phys_med / loop_med:.4f}")
    if res["rollout"]:
        print(f"ratio_closed_loop_over_mujoco_rollout: {closed_med / stats(res['rollout'])[0]:.4f}")
    print(f"ratio_closed_loop_over_mujoco: {closed_med / loop_med:.4f}")


if __name__ == "__main__":
    main()
