"""Methods written in Python, scored by aift: the protocol's two kinds, determinism, the
precision-only kind against the built-in no-FT bit for bit, and the errors a user's method can
make (an exception, the wrong shape, NaN), each naming the tick."""

import importlib.util
import math
import pathlib

import numpy as np
import pytest

import aift

from test_package import assert_same_bits

REPO = pathlib.Path(__file__).resolve().parents[2]


def short(seconds=9.0):
    return aift.Scenario.default().set("duration", seconds)


def load_example():
    spec = importlib.util.spec_from_file_location("numpy_ekf", REPO / "python/examples/numpy_ekf.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class NominalPrecisions:
    """Precision-only kind: the nominal precisions every tick (the built-in no-FT's)."""
    name = "nominal"

    def reset(self, *, n_joints, channels, dt, nominal, seed):
        self.nominal = list(nominal)
        self.calls = 0

    def update(self, readings, residuals, mu, mu_p, dt):
        self.calls += 1
        return self.nominal


def test_a_precision_method_from_python_drives_the_uaic_as_no_ft_does():
    sc = short()
    mine = NominalPrecisions()
    a = aift.run(sc, mine, seed=3)
    b = aift.run(sc, "no-ft", seed=3)
    assert a.summary["method"] == "nominal"
    assert mine.calls == len(b.trajectory["t"])
    for col in ["mu1", "mu2", "mu_p1", "q1", "u2", "precision_enc1"]:
        assert_same_bits(a.trajectory[col], b.trajectory[col], col)


def test_an_estimator_from_python_is_scored_and_deterministic(tmp_path):
    example = load_example()
    sc = short(12.0)
    a = aift.run(sc, example.NumpyKalman, seed=2, out=tmp_path / "a")
    b = aift.run(sc, example.NumpyKalman(), seed=2)
    assert a.summary["method"] == "numpy-kf"
    assert (tmp_path / "a" / "summary.json").is_file()
    for col in ["mu1", "mu_p2", "health_enc1", "F"]:
        assert_same_bits(a.trajectory[col], b.trajectory[col], col)
    # Its belief follows the arm before the fault (8 s): within 2 mrad RMS.
    t = a.trajectory["t"]
    err = a.trajectory["mu1"][t < 8.0] - a.trajectory["q1"][t < 8.0]
    assert math.sqrt(np.mean(err**2)) < 2e-3
    # The frozen encoder is gated out (its reported precision 0: health 0) after the fault.
    assert a.summary["detected_at"] is not None and a.summary["detected_at"] >= 8.0
    assert a.summary["isolated_channel"] == "enc1"
    assert a.trajectory["health_enc1"][t >= 9.0].max() == 0.0


class Raises:
    def step(self, readings, applied, dt):
        self.ticks = getattr(self, "ticks", 0) + 1
        if self.ticks == 101:
            raise ZeroDivisionError("my bug")
        n = len(applied)
        return [0.0] * n, [0.0] * n, [1.0] * len(readings)


class WrongShape:
    def step(self, readings, applied, dt):
        return [0.0] * (len(applied) + 1), [0.0] * len(applied), [1.0] * len(readings)


class NotFinite:
    def step(self, readings, applied, dt):
        n = len(applied)
        return [0.0] * n, [0.0] * n, [float("nan")] * len(readings)


class NeitherKind:
    pass


def test_a_user_exception_is_raised_with_its_tick_and_nothing_is_written(tmp_path):
    with pytest.raises(ZeroDivisionError, match="my bug") as info:
        aift.run(short(), Raises, out=tmp_path / "out")
    notes = " ".join(getattr(info.value, "__notes__", []))
    assert "at tick 100" in notes, notes
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("method,field", [(WrongShape, "`mu` has 3 values; 2 expected"),
                                          (NotFinite, "`precisions`[0] is NaN")])
def test_bad_values_from_a_method_name_the_field_and_tick(method, field):
    with pytest.raises(aift.BadInput, match="at tick 0") as info:
        aift.run(short(), method)
    assert field in str(info.value)


def test_an_object_of_neither_kind_is_refused():
    with pytest.raises(aift.BadInput, match="neither step"):
        aift.run(short(), NeitherKind)


def test_a_table_takes_python_methods_beside_names():
    sc = short()
    rows = aift.table(sc, ["no-ft", NominalPrecisions, "oracle"], seeds=2)
    by = {r["method"]: r for r in rows.rows}
    assert set(by) == {"no-ft", "oracle", "nominal"}
    # The same parts as no-FT over the same seeds: the same numbers.
    for key in ["mse_faulty_mean", "mse_healthy_mean", "max_final_error_mean", "ratio_to_oracle"]:
        assert by["nominal"][key] == by["no-ft"][key], key
    # Twice: the same table.
    again = {r["method"]: r for r in aift.table(sc, [NominalPrecisions], seeds=2).rows}
    assert again["nominal"]["mse_faulty_mean"] == by["nominal"]["mse_faulty_mean"]


def test_a_table_needs_classes_and_raises_a_failing_run():
    with pytest.raises(aift.BadInput, match="must be a class"):
        aift.table(short(), [NominalPrecisions()], seeds=1)
    with pytest.raises(ZeroDivisionError) as info:
        aift.table(short(), [Raises], seeds=2)
    notes = " ".join(getattr(info.value, "__notes__", []))
    assert "seed" in notes and "at tick 100" in notes, notes


def test_the_step_api_takes_a_python_method():
    sc = short()
    mine, builtin = aift.Sim(sc, NominalPrecisions), aift.Sim(sc, "no-ft")
    assert mine.method == "nominal"
    (a, _), (b, _) = mine.reset(seed=4), builtin.reset(seed=4)
    for _ in range(300):
        (a, _), (b, _) = mine.step(), builtin.step()
    assert_same_bits(a["mu"], b["mu"], "mu")
    assert_same_bits(a["precision"], b["precision"], "precision")
    failing = aift.Sim(sc, Raises)
    failing.reset(seed=1)
    with pytest.raises(ZeroDivisionError) as info:
        for _ in range(200):
            failing.step()
    assert "at tick 100" in " ".join(getattr(info.value, "__notes__", []))
    failing.reset(seed=1)  # a new instance of the class: starts over
