"""Model schedules of an engine type (fleethealth.model-schedule/1): every node reproduced
exactly, values between nodes within their corners, trims interpolated as corrected
parameters, and files that do not make a schedule refused naming what is wrong."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from estimation.errors import DimensionError, ModelFormatError
from estimation.model import MATRIX_NAMES
from estimation.schedule import CONDITIONS, SCHEDULE_FORMAT, ModelSchedule
from tests.estimation.models import scheduled_models

ALTS = (0.0, 20000.0, 35000.0)
POWERS = (60.0, 85.0, 100.0)
POINTS = [{"alt_ft": a, "mach": 0.5 * a / 35000.0 + 0.2, "power_pct": p}
          for a, p in itertools.product(ALTS, POWERS)]


def document(points: list[dict[str, float]] = POINTS, **extra: object) -> dict[str, object]:
    models = scheduled_models(points)
    return {"format": SCHEDULE_FORMAT, "variables": ["alt_ft", "power_pct"],
            "models": [m.to_dict() for m in models[::-1]], **extra}  # any order


def condition(point: dict[str, float]) -> list[float]:
    return [point.get(c, 0.0) for c in CONDITIONS]


@pytest.fixture(scope="module")
def sched() -> ModelSchedule:
    return ModelSchedule.from_dict(document())


def test_every_node_is_reproduced_exactly(sched: ModelSchedule) -> None:
    assert sched.grid.shape == (3, 3) and sched.variables == ("alt_ft", "power_pct")
    for point, truth in zip(POINTS, scheduled_models(POINTS), strict=True):
        m = sched.model_at(condition(point))
        for name in MATRIX_NAMES:
            assert np.allclose(getattr(m, name), getattr(truth, name), rtol=1e-12, atol=1e-14)
        assert np.allclose(m.sensor_noise_std, truth.sensor_noise_std, rtol=1e-12)
        for k, v in truth.trim.items():
            assert m.trim[k] == pytest.approx(v, rel=1e-12), k
        gy, _ = m.steady_state_gains()
        g = sched.interpolate("Gy", np.array([condition(point)]))[0]
        assert np.allclose(g, truth.steady_state_gains()[0], rtol=1e-10, atol=1e-12)
        assert np.allclose(gy, g, rtol=1e-9, atol=1e-12)


def test_between_nodes_every_value_lies_within_its_cells_corners(sched: ModelSchedule) -> None:
    rng = np.random.default_rng(4)
    q = np.column_stack([rng.uniform(0, 35000, 50), rng.uniform(0.2, 0.7, 50),
                         np.zeros(50), rng.uniform(60, 100, 50)])
    for name in ("Gy", "Gz", "Guy", "M", "L", "noise", "trim_corrected"):
        got = sched.interpolate(name, q)
        for k in range(len(q)):
            i = min(np.searchsorted(ALTS, q[k, 0], side="right") - 1, len(ALTS) - 2)
            j = min(np.searchsorted(POWERS, q[k, 3], side="right") - 1, len(POWERS) - 2)
            corners = sched.values[name][i: i + 2, j: j + 2].reshape(4, *got.shape[1:])
            assert np.all(got[k] >= corners.min(axis=0) - 1e-12), name
            assert np.all(got[k] <= corners.max(axis=0) + 1e-12), name
    # Half-way between two power nodes at one altitude, a gain is the mean of the two.
    mid = sched.interpolate("Gy", np.array([[20000.0, 0.5, 0.0, 92.5]]))[0]
    ends = sched.interpolate("Gy", np.array([[20000.0, 0.5, 0.0, 85.0],
                                             [20000.0, 0.5, 0.0, 100.0]]))
    assert np.allclose(mid, ends.mean(axis=0), rtol=1e-12)
    # Outside the grid: clipped to its edge.
    edge = sched.interpolate("Gy", np.array([[50000.0, 0.5, 0.0, 100.0]]))
    assert np.allclose(edge, sched.interpolate("Gy", np.array([[35000.0, 0.5, 0.0, 100.0]])))


def test_trims_are_interpolated_as_corrected_parameters(sched: ModelSchedule) -> None:
    # The test models' trims are a corrected value times theta2^a delta2^b: at any altitude
    # between the nodes (at a node's power) the interpolated trim is that product at the
    # query's own inlet conditions, where a straight line between the nodes is off.
    alt, mach, power = 10000.0, 0.2 + 0.5 * 10000.0 / 35000.0, 85.0
    truth = scheduled_models([{"alt_ft": alt, "mach": mach, "power_pct": power}])[0]
    got = sched.trims_at(np.array([[alt, mach, 0.0, power]]))
    assert sched.corrections["Ps30"] == "pressure" and sched.corrections["Nf"] == "speed"
    for name in ("Ps30", "T48", "Nf", "Wf"):
        assert got[name][0] == pytest.approx(truth.trim[name], rel=1e-9), name
    lo, hi = (sched.models[i].trim["Ps30"] for i in (1, 4))  # alt 0 and 20000 at 85 %
    assert abs((lo + hi) / 2 - truth.trim["Ps30"]) > 0.02 * truth.trim["Ps30"]
    # "none" interpolates a trim as it is: a straight line between the nodes.
    plain = ModelSchedule.from_dict(document(corrections={"Ps30": "none"}))
    assert plain.trims_at(np.array([[alt, mach, 0.0, power]]))["Ps30"][0] == pytest.approx(
        lo + (hi - lo) * alt / 20000.0, rel=1e-12)


def test_a_celsius_temperature_is_corrected_as_an_absolute_one() -> None:
    doc = document()
    for m in doc["models"]:  # type: ignore[union-attr]
        m["signals"]["sensors"][5]["unit"] = "degC"
        m["trim"]["T48"] = m["trim"]["T48"] / 1.8 - 273.15
    sched = ModelSchedule.from_dict(doc)
    alt, mach = 10000.0, 0.2 + 0.5 * 10000.0 / 35000.0
    truth = scheduled_models([{"alt_ft": alt, "mach": mach, "power_pct": 85.0}])[0]
    got = sched.trims_at(np.array([[alt, mach, 0.0, 85.0]]))["T48"][0]
    assert got == pytest.approx(truth.trim["T48"] / 1.8 - 273.15, rel=1e-9)


def test_the_file_round_trips_and_names_its_design_point(sched: ModelSchedule) -> None:
    back = ModelSchedule.from_dict(json.loads(json.dumps(sched.to_dict())))
    assert back.variables == sched.variables and back.corrections == sched.corrections
    for name in ("Gy", "trim_corrected", "noise"):
        assert np.array_equal(back.values[name], sched.values[name])
    # design_point indexes the file's models: the last in the file is the first point.
    chosen = ModelSchedule.from_dict(document(design_point=8))
    assert chosen.template.operating_condition["alt_ft"] == 0.0
    assert chosen.template.operating_condition["power_pct"] == 60.0


@pytest.mark.parametrize(("change", "message"), [
    (lambda d: d["models"].pop(3), "do not fill the grid 3 x 3 over ['alt_ft', 'power_pct']"),
    (lambda d: d["models"].append(d["models"][0]), "models[0] and models[9] are both at"),
    (lambda d: d.update(variables=["alt_ft", "thrust"]), "variables must be"),
    (lambda d: d.update(variables=[]), "variables must be"),
    (lambda d: d.update(models=[]), "models must be a non-empty list"),
    (lambda d: d.update(corrections={"Ps30": "cubic"}), "corrections.Ps30 must be one of"),
    (lambda d: d.update(corrections={"EGT": "temperature"}), "corrections names 'EGT'"),
    (lambda d: d.update(design_point=9), "design_point must be the index of a model (0..8)"),
    (lambda d: d["models"][2]["operating_condition"].pop("power_pct"),
     "models[2]: operating_condition gives no ['power_pct']"),
    (lambda d: d["models"][4]["signals"]["sensors"][0].update(unit="%"),
     "models[4] does not have the signals"),
    (lambda d: d.update(format="fleethealth.linear-model/1"), "format must be"),
])
def test_a_file_that_makes_no_schedule_is_refused_naming_why(change, message) -> None:
    doc = json.loads(json.dumps(document()))
    change(doc)
    with pytest.raises(ModelFormatError) as err:
        ModelSchedule.from_dict(doc)
    assert message in str(err.value)


def test_a_bad_model_inside_is_named_by_its_index() -> None:
    doc = json.loads(json.dumps(document()))
    doc["models"][5]["matrices"]["L"] = [[0.0]]
    with pytest.raises(DimensionError, match=r"^models\[5\]: Incompatible dimensions of L"):
        ModelSchedule.from_dict(doc)
