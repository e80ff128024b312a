"""Schedule of linear models: exact at nodes, close between, round-trips."""

import json

import numpy as np
import pytest

from estimation.engine.linearize import linearize
from estimation.engine.schedule import EngineSchedule, build_schedule
from estimation.model import MATRIX_NAMES

AXES = {"alt": (0.0, 20000.0), "mach": (0.0, 0.5), "power": (60.0, 100.0)}


@pytest.fixture(scope="module")
def sched():
    return build_schedule(AXES)


def test_nodes_reproduce_direct_linearisation(sched):
    m = sched.model_at(20000.0, 0.0, 100.0)
    ref = linearize(20000.0, 0.0, 100.0)
    for name in MATRIX_NAMES:
        assert np.allclose(getattr(m, name), getattr(ref, name), rtol=1e-9, atol=1e-12), name
    for k, v in ref.trim.items():
        assert np.isclose(m.trim[k], v, rtol=1e-12)


def test_between_nodes_close_to_direct_linearisation(sched):
    m = sched.model_at(10000.0, 0.25, 80.0)
    ref = linearize(10000.0, 0.25, 80.0)
    gy, _ = m.steady_state_gains()
    gy_ref, _ = ref.steady_state_gains()
    assert np.max(np.abs(gy - gy_ref)) < 0.1 * np.max(np.abs(gy_ref))
    # Trims interpolate as corrected parameters, so pressures follow the atmosphere.
    # (A coarse test grid: a 40 % power and 0.5 Mach cell.)
    for k in ("T24", "T30", "T50", "Nc", "P15", "P50"):
        assert abs(m.trim[k] / ref.trim[k] - 1.0) < 0.01, k
    for k in ("P30", "Ps30", "P24"):
        assert abs(m.trim[k] / ref.trim[k] - 1.0) < 0.03, k
    # Interpolated gains stored in the schedule equal the gains of the interpolated
    # node models only at nodes; between, they are interpolated directly.
    g = sched.interpolate("Gy", np.array([[20000.0, 0.5, 60.0, 0.0]]))[0]
    g_node, _ = sched.model_at(20000.0, 0.5, 60.0).steady_state_gains()
    assert np.allclose(g, g_node, rtol=1e-8, atol=1e-10)


def test_multilinear_interpolation_is_linear_along_an_axis(sched):
    c = np.array([[5000.0, 0.5, 100.0, 0.0], [0.0, 0.5, 100.0, 0.0], [20000.0, 0.5, 100.0, 0.0]])
    t = sched.interpolate("trim_corrected", c)
    assert np.allclose(t[0], 0.75 * t[1] + 0.25 * t[2])


def test_queries_outside_the_grid_clip_to_the_edge(sched):
    a = sched.interpolate("A", np.array([[30000.0, 0.7, 110.0, 0.0]]))
    b = sched.interpolate("A", np.array([[20000.0, 0.5, 100.0, 0.0]]))
    assert np.array_equal(a, b)


def test_dict_round_trip(sched):
    back = EngineSchedule.from_dict(json.loads(json.dumps(sched.to_dict())))
    for k, v in sched.values.items():
        assert np.array_equal(back.values[k], v), k
    assert back.fingerprint == sched.fingerprint and back.trim_names == sched.trim_names
