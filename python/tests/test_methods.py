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


def tiny_campaign(tmp_path, seeds=2):
    path = tmp_path / "tiny.toml"
    path.write_text(f"""
name = "tiny"
seeds = {seeds}
methods = ["no-ft"]
channels = ["enc*"]
defaults = {{ duration = 10.0, plant = {{ engine = "articulated" }} }}

[[arms]]
name = "paper"
scenario = "{(REPO / 'assets/scenarios/paper_healthy.toml').as_posix()}"

[[kinds]]
kind = "freeze"
onsets = ["moving"]
""")
    return path


def results(doc, method):
    """Per cell label: the method's summary in that cell."""
    return {c["label"]: next(r for r in c["results"] if r["method"] == method) for c in doc["cells"]}


def test_a_campaign_takes_python_methods_beside_names(tmp_path):
    path = tiny_campaign(tmp_path)
    rows = aift.campaign(path, methods=["no-ft", NominalPrecisions], out=tmp_path / "out")
    assert rows.doc["methods"] == ["no-ft", "nominal"]
    mine, builtin = results(rows.doc, "nominal"), results(rows.doc, "no-ft")
    assert set(mine) == {"healthy", "enc1 freeze moving"}
    # The same parts as no-FT over the same seeds: the same numbers in every cell.
    for label in mine:
        for key in ["verdict", "mse_post_mean", "final_error_mean", "false_alarms_per_hour"]:
            assert mine[label][key] == builtin[label][key], (label, key)
    records = (tmp_path / "out" / "records.json").read_text()
    assert '"external_methods"' in records and '"nominal"' in records
    assert "nominal" in (tmp_path / "out" / "campaign.csv").read_text()
    # Alone, and again: the same numbers.
    again = results(aift.campaign(path, methods=[NominalPrecisions]).doc, "nominal")
    assert again == mine


def test_a_failing_method_in_a_campaign_names_its_cell_seed_and_tick(tmp_path):
    path = tiny_campaign(tmp_path, seeds=1)
    with pytest.raises(ZeroDivisionError, match="my bug") as info:
        aift.campaign(path, methods=[Raises], out=tmp_path / "out")
    notes = " ".join(getattr(info.value, "__notes__", []))
    assert "arm paper, cell" in notes and "seed 1" in notes and "at tick 100" in notes, notes
    assert not (tmp_path / "out").exists()
    # No run of the failed method is kept for a resume.
    journal = tmp_path / ".out.aift-journal"
    assert not journal.exists() or '"Raises"' not in journal.read_text()
    with pytest.raises(aift.BadInput, match="must be a class"):
        aift.campaign(path, methods=[NominalPrecisions()])
    with pytest.raises(aift.BadInput, match="taken"):
        aift.campaign(path, methods=[NominalPrecisions, NominalPrecisions])


def test_the_numpy_filter_agrees_with_the_built_in_one_on_a_small_campaign():
    """The example's stated tolerance (docs/python.md): verdicts agree in at least 80 % of the
    cells; in every fault cell both detect the fault on every seed and isolate it alike, with
    mean detection delays within 50 ms; neither alarms on a healthy cell."""
    example = load_example()
    rows = aift.campaign(example.SMALL_CAMPAIGN, methods=["ekf-gate", example.NumpyKalman])
    cells = example.verdicts(rows.doc, "ekf-gate", "numpy-kf")
    agree = sum(a["verdict"] == b["verdict"] for _, _, a, b in cells)
    assert agree >= 0.8 * len(cells), (agree, len(cells))
    for arm, label, a, b in cells:
        if label == "healthy":
            assert a["false_alarms_per_hour"] == 0 and b["false_alarms_per_hour"] == 0, arm
            continue
        assert a["missed_detections"] == b["missed_detections"] == 0, (arm, label)
        assert a["isolation_correct"] == b["isolation_correct"], (arm, label)
        assert abs(a["detection_delay_mean"] - b["detection_delay_mean"]) <= 0.05, (arm, label)
