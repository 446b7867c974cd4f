"""aift from Python: fault-tolerant control of robot arms with active inference.

The library, not the CLI: scenarios, runs, tables, campaigns and a step API, computed by the same
Rust code as the ``aift`` command, so the numbers agree bit for bit.

    import aift
    sc = aift.Scenario.default().set("faults[0].start", 9.0)
    r = aift.run(sc, method="pl-always", seed=1)
    r.summary["mse_faulty"], r.trajectory["mu1"]

Errors arrive as :class:`BadInput` (the CLI's exit code 2) or :class:`InternalError` (exit 1),
with the CLI's message. Long calls release the GIL.
"""

from __future__ import annotations

import json
import os
from typing import Dict, Iterable, List, Optional, Sequence

import numpy as np

from . import _aift
from ._aift import AiftError, BadInput, InternalError, Scenario, __version__

__all__ = [
    "AiftError",
    "BadInput",
    "InternalError",
    "Scenario",
    "Sim",
    "Trajectory",
    "RunResult",
    "Rows",
    "run",
    "replay",
    "table",
    "campaign",
    "report",
    "merge",
    "check_urdf",
    "gen_arm",
    "init",
    "calibrate",
    "train_gp",
    "methods",
    "schema",
    "__version__",
]


def _path(p):
    return None if p is None else os.fspath(p)


class Trajectory:
    """A run's trajectory: one float64 numpy array per column (``t``, ``q1``, ``mu1``, ...,
    ``y_enc1``, ``precision_enc1``, ``F``, ...), as trajectory.csv has them."""

    def __init__(self, names: List[str], data: bytes):
        self.columns: List[str] = list(names)
        n = len(self.columns)
        values = np.frombuffer(data, dtype="<f8")
        rows = values.size // n if n else 0
        # A read-only view of the bytes the run filled (no copy).
        self._matrix = values.reshape(n, rows)
        self._index = {c: i for i, c in enumerate(self.columns)}

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self._matrix[self._index[name]]
        except KeyError:
            raise KeyError(f"no column {name!r} (columns: {', '.join(self.columns)})") from None

    def __contains__(self, name: str) -> bool:
        return name in self._index

    def __iter__(self):
        return iter(self.columns)

    def __len__(self) -> int:
        """Rows (recorded ticks)."""
        return self._matrix.shape[1]

    def keys(self):
        return list(self.columns)

    def as_dict(self) -> Dict[str, np.ndarray]:
        return {c: self[c] for c in self.columns}

    def to_numpy(self) -> np.ndarray:
        """Rows by columns, as the CSV file."""
        return self._matrix.T.copy()

    def to_pandas(self):
        """A pandas DataFrame (needs pandas)."""
        import pandas as pd

        return pd.DataFrame(self.as_dict(), columns=self.columns)

    def __repr__(self) -> str:
        return f"Trajectory({len(self)} rows x {len(self.columns)} columns)"


class RunResult:
    """What :func:`run` returns: ``summary`` (the dict summary.json holds), ``trajectory``
    (:class:`Trajectory`) and ``out`` (the run folder, when one was written)."""

    def __init__(self, summary: dict, trajectory: Trajectory, out: Optional[str]):
        self.summary = summary
        self.trajectory = trajectory
        self.out = out

    def __repr__(self) -> str:
        s = self.summary
        return f"RunResult(method={s['method']!r}, seed={s['seed']}, outcome={s['outcome']!r}, ticks={s['ticks']})"


class Rows:
    """A table's or campaign's JSON document (``doc``) with its rows as a list of dicts."""

    def __init__(self, doc: dict, key: str):
        self.doc = doc
        self.rows: List[dict] = list(doc.get(key, []))

    def __iter__(self):
        return iter(self.rows)

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, i):
        return self.rows[i]

    def to_pandas(self):
        import pandas as pd

        return pd.DataFrame(self.rows)

    def __repr__(self) -> str:
        return f"Rows({len(self.rows)} rows)"


def _scenario(scenario) -> Scenario:
    if scenario is None:
        return Scenario.default()
    if isinstance(scenario, Scenario):
        return scenario
    if isinstance(scenario, (str, os.PathLike)):
        return Scenario.load(os.fspath(scenario))
    raise TypeError(f"a Scenario, a path or None, not {type(scenario).__name__}")


def run(scenario=None, method=None, seed: Optional[int] = None, *,
        out=None, force: bool = False, calib=None, trajectory: bool = True,
        mcap: bool = False) -> RunResult:
    """Runs one (method, seed) of a scenario (a :class:`Scenario`, a path, or None for the
    default). Nothing touches disk unless ``out`` names a run folder to write (the CLI's files,
    whole or not at all). Methods with a detector calibrate it as the CLI does (``calib``, the
    scenario's file, or healthy runs cached in ``$AIFT_CACHE_DIR`` / ``~/.cache/aift``).
    ``trajectory=False`` keeps nothing of the trajectory in memory (``.trajectory`` is None; with
    ``out`` the file has it): for runs longer than the in-memory bound of 2**27 values.
    ``method`` is a name, or a method written in Python (an object, or a class to instantiate,
    with ``step(readings, applied, dt) -> (mu, mu_p, precisions)`` or ``update(readings,
    residuals, mu, mu_p, dt) -> precisions``; docs/python.md, "Bring your own method").
    ``mcap=True`` (with ``out``) also writes ``run.mcap``, the run as ROS 2 messages (the CLI's
    ``--mcap``; docs/logs.md)."""
    if method is not None and not isinstance(method, str):
        # A method written in Python (a class is instantiated for the run): docs/python.md,
        # "Bring your own method".
        if isinstance(method, type):
            method = method()
        summary, names, data = _aift.run_method(_scenario(scenario), method, seed, _path(out),
                                                force, trajectory, mcap)
    else:
        summary, names, data = _aift.run(_scenario(scenario), method, seed, _path(out), force,
                                         _path(calib), trajectory, mcap)
    return RunResult(json.loads(summary), Trajectory(names, data) if trajectory else None, _path(out))


def replay(log, scenario=None, method: Optional[str] = None, *, out, seed: Optional[int] = None,
           force: bool = False, calib=None, topic: Optional[str] = None,
           camera_topic: Optional[str] = None) -> RunResult:
    """Runs a method over a recorded log (``aift replay``): a rosbag2 bag folder or ``.mcap``
    file with ``sensor_msgs/msg/JointState`` (effort = applied torque; ``topic`` or
    ``/joint_states``), or a ``.csv`` with columns ``t``, ``applied<i>``, ``y_<channel>`` (a run's
    trajectory.csv is one). The controller and plant are not in the loop. Writes the run folder
    ``out`` (trajectory.csv with the plant's columns NaN, summary.json with a ``replay`` section,
    plots, report.html); returns its summary (``.trajectory`` is None: read ``out``'s CSV).
    Bad logs raise :class:`BadInput` naming the file and the field (docs/logs.md)."""
    summary = _aift.replay(_path(log), _scenario(scenario), _path(out), method, seed, force,
                           _path(calib), topic, camera_topic)
    return RunResult(json.loads(summary), None, _path(out))


def _methods(methods):
    """A list of method names: a sequence, or one string of comma-separated names (as the
    CLI's ``--methods``; a bare string was read letter by letter)."""
    if methods is None:
        return None
    if isinstance(methods, str):
        return [m.strip() for m in methods.split(",")]
    return list(methods)


def _split_methods(methods):
    """(built-in names or None, Python methods) from a list that may hold both."""
    if methods is None:
        return None, []
    listed = [methods] if isinstance(methods, str) else list(methods)
    custom = [m for m in listed if not isinstance(m, str)]
    named = [m for m in listed if isinstance(m, str)]
    # Names only, or names beside Python methods; Python methods alone: no built-in one.
    return (_methods(",".join(named)) if named else ([] if not custom else None)), custom


def table(scenario=None, methods=None, seeds: int = 20, *,
          out=None, force: bool = False, calib=None) -> Rows:
    """Every method (or ``methods``) over ``seeds`` seeds from the scenario's: table.json's
    document and its rows (one per method). ``methods`` may hold methods written in Python
    beside the names, as classes (or functions returning a new method object): every run gets
    its own instance (docs/python.md, "Bring your own method")."""
    names, custom = _split_methods(methods)
    doc = _aift.run_table(_scenario(scenario), names, seeds,
                          _path(out), force, _path(calib), custom)
    return Rows(json.loads(doc), "rows")


def campaign(path=None, *, seeds: Optional[int] = None, methods=None,
             set: Iterable[str] = (), shard: Optional[str] = None, out=None, force: bool = False,
             fresh: bool = False) -> Rows:
    """Runs a campaign file (default: the bundled one): campaign.json's document, with its
    per-cell rows (``doc["cells"]``) as rows. ``methods`` may hold methods written in Python
    beside the names, as classes (one instance per run, as in ``table``): they run in every cell
    and reaching task after the built-in ones, under their names in every table, and
    ``aift compare``/``aift merge``/``aift report`` read them from the records. With ``out``,
    each finished job is journaled beside the folder: an interrupted call is resumed by calling
    again with the same arguments (``fresh=True`` starts from nothing)."""
    names, custom = _split_methods(methods)
    doc = json.loads(_aift.run_campaign(_path(path), seeds, names,
                                        list(set), shard, _path(out), force, fresh, custom))
    return Rows(doc, "cells")


def report(dir) -> str:
    """Writes report.html into a run, table or campaign folder (as ``aift report DIR``);
    returns its path."""
    _, path = _aift.report(os.fspath(dir))
    return path


def merge(shards: Sequence, out, *, force: bool = False) -> Rows:
    """Merges campaign shards (folders written with ``campaign(..., shard="K/N", out=...)``)
    into the campaign folder ``out``, as ``aift merge``: campaign.json's document and cells."""
    doc = _aift.merge([os.fspath(s) for s in shards], os.fspath(out), force)
    return Rows(json.loads(doc), "cells")


def check_urdf(path, ee: Optional[str] = None, *, balance_inertia: bool = False) -> dict:
    """The arm of a URDF file, as ``aift check-urdf --json`` prints it."""
    return json.loads(_aift.check_urdf(os.fspath(path), ee, balance_inertia))


def gen_arm(seed: int, *, joints=(2, 7), out=None) -> str:
    """A random serial arm drawn from ``seed`` (as ``aift gen-arm``): its URDF text, the same
    bytes for the same seed. ``joints`` is a count or (fewest, most), at most 12 (docs/arms.md,
    "Generated arms"). With ``out``, the text is also written to that file."""
    lo, hi = (joints, joints) if isinstance(joints, int) else tuple(joints)
    text = _aift.gen_arm(seed, lo, hi)
    if out is not None:
        with open(os.fspath(out), "w", encoding="utf-8") as f:
            f.write(text)
    return text


def init(urdf, *, name: str = "scenario", ee: Optional[str] = None, balance_inertia: bool = False) -> Scenario:
    """A scenario derived from any URDF, as ``aift init`` writes it (controller gains from the
    arm's inertia, targets inside its limits, a camera that sees it); the URDF is named by its
    absolute path, so ``to_toml()`` can be saved anywhere."""
    path = os.path.abspath(os.fspath(urdf))
    text = _aift.init_scenario(path, name, ee, balance_inertia, path)
    return Scenario.from_toml(text, base_dir=os.path.dirname(path))


def calibrate(scenario, out, *, runs: Optional[int] = None) -> dict:
    """Writes the detector calibration (``runs`` healthy runs) to the file ``out``, as
    ``aift calibrate``; pass it to ``run(..., calib=out)``. Returns its fingerprint, runs, ticks."""
    return json.loads(_aift.calibrate_to(_scenario(scenario), os.fspath(out), runs))


def train_gp(scenario, out, *, points: Optional[int] = None) -> dict:
    """Trains the camera GP and writes it to the file ``out``, as ``aift train-gp``; returns the
    hyperparameters (points, length_scales, signal_std, noise_std), the log marginal likelihood,
    evaluations and the held-out error (m: held_out_rms, held_out_max, held_out_points)."""
    return json.loads(_aift.train_gp_to(_scenario(scenario), os.fspath(out), points))


def methods() -> List[str]:
    """The method names."""
    return _aift.methods()


def schema() -> dict:
    """The scenario file's JSON Schema (as ``aift schema`` prints it)."""
    return json.loads(_aift.schema())


def _obs(raw: dict) -> dict:
    return {k: (np.asarray(v, dtype=np.float64) if isinstance(v, list) else v) for k, v in raw.items()}


class Sim:
    """The closed loop stepped from Python.

    ``obs, info = sim.reset(seed)`` senses, estimates and controls tick 0; ``obs, info =
    sim.step()`` applies the controller's torques (``obs["u"]``) or ``torques=``, steps the plant
    one tick and decides the next (sensor ``readings=`` may replace the sensors', NaN or None for
    missing). ``obs`` has ``t``, ``q``, ``qd`` (the plant), ``mu``, ``mu_p`` (the belief),
    ``target``, ``u``, ``y`` (readings, in ``sim.channels`` order) and ``precision``; ``info``
    has ``free_energy``, ``alarm``, ``isolated``, ``actuator_alarms`` (the method's own, None
    when it infers no actuator health), ``diverged`` and ``done`` (the scenario's last tick).
    With nothing supplied the ticks equal :func:`run`'s bit for bit. ``method`` may be a method
    written in Python (an object, reset on each ``reset``, or a class, instantiated on
    each ``reset``; docs/python.md, "Bring your own method").
    """

    def __init__(self, scenario=None, method=None, *, calib=None):
        self._sim = _aift.Sim(_scenario(scenario), method, _path(calib))

    def reset(self, seed: Optional[int] = None, readings=None):
        obs, info = self._sim.reset(seed, None if readings is None else [None if v is None else float(v) for v in readings])
        return _obs(obs), info

    def step(self, torques=None, readings=None):
        u = None if torques is None else [float(v) for v in np.asarray(torques, dtype=np.float64).ravel()]
        r = None if readings is None else [None if v is None else float(v) for v in readings]
        obs, info = self._sim.step(u, r)
        return _obs(obs), info

    @property
    def channels(self) -> List[str]:
        return self._sim.channels

    @property
    def n_joints(self) -> int:
        return self._sim.n_joints

    @property
    def ticks(self) -> int:
        return self._sim.ticks

    @property
    def dt(self) -> float:
        return self._sim.dt

    @property
    def method(self) -> str:
        return self._sim.method

    @property
    def effort_limits(self):
        return self._sim.effort_limits
