"""The nominal engine's dense trim table against the exact steady-state solve."""

import numpy as np
import pytest

from estimation.engine.fleet import engine_noise_std
from estimation.engine.sensors import SENSOR_NAMES
from estimation.engine.steady import ENVELOPE, steady_state
from estimation.engine.trim_table import (
    DEFAULT_TRIM_AXES,
    TRIM_AXIS_NAMES,
    TRIM_NAMES,
    build_trim_table,
    trim_axes,
)

# A take-off corner of the envelope at the default grid's spacing (fast to solve).
SMALL = {"alt": (0.0, 5000.0), "mach": tuple(np.linspace(0.0, 0.25, 21)),
         "dtamb": (-20.0, 0.0, 20.0), "power": (90.0, 92.5, 95.0, 97.5, 100.0)}


def exact(conditions):
    ss = steady_state(conditions[:, :3], power=conditions[:, 3])
    return np.concatenate([ss.sensors, ss.u[:, 1:]], axis=1)


def within_target(approx, truth):
    """Per sensor: max error below 0.05 % of trim or below 0.1 sigma of its noise."""
    sigma = engine_noise_std()
    bad = []
    for j, name in enumerate(SENSOR_NAMES):
        err = np.abs(approx[:, j] - truth[:, j])
        pct = 100 * err / np.abs(truth[:, j])
        if not (pct.max() < 0.05 or (err / sigma[j]).max() < 0.1):
            bad.append((name, float(pct.max()), float((err / sigma[j]).max())))
    return bad


@pytest.fixture(scope="module")
def small_table():
    return build_trim_table(SMALL)


def test_nodes_are_the_exact_trims(small_table):
    nodes = np.array([[5000.0, 0.25, 20.0, 97.5], [0.0, 0.0, -20.0, 90.0]])
    assert np.allclose(small_table.trims_at(nodes), exact(nodes), rtol=1e-12, atol=1e-9)


def test_between_nodes_within_a_tenth_of_the_noise(small_table):
    rng = np.random.default_rng(3)
    c = np.column_stack([rng.uniform(small_table.axes[k][0], small_table.axes[k][-1], 400)
                         for k in range(4)])
    approx, truth = small_table.trims_at(c), exact(c)
    assert within_target(approx, truth) == []
    # Without the density the error is of a fault's size: the test can tell.
    coarse = build_trim_table({**SMALL, "mach": (0.0, 0.25), "power": (90.0, 100.0)})
    assert within_target(coarse.trims_at(c), truth) != []


def test_a_records_trims_do_not_depend_on_its_batch(small_table):
    rng = np.random.default_rng(4)
    c = np.column_stack([rng.uniform(small_table.axes[k][0], small_table.axes[k][-1], 300)
                         for k in range(4)])
    whole = small_table.trims_at(c)
    assert np.array_equal(whole[100:137], small_table.trims_at(c[100:137]))


def test_inside_is_the_span(small_table):
    c = np.array([[0.0, 0.1, 0.0, 95.0], [6000.0, 0.1, 0.0, 95.0], [np.nan, 0.1, 0.0, 95.0]])
    assert small_table.inside(c).tolist() == [True, False, False]


def test_default_grid_spans_the_envelope():
    axes = trim_axes()
    for name, a in zip(TRIM_AXIS_NAMES, axes, strict=True):
        assert (a[0], a[-1]) == ENVELOPE[name]
        assert len(a) == len(DEFAULT_TRIM_AXES[name])
    assert TRIM_NAMES[:len(SENSOR_NAMES)] == SENSOR_NAMES


def test_axes_outside_the_envelope_are_refused():
    with pytest.raises(ValueError, match="mach"):
        trim_axes({"mach": (0.0, 0.9)})
    with pytest.raises(ValueError, match="power"):
        trim_axes({"power": (50.0,)})
