"""Steady windows: a synthetic flight (piecewise-linear condition, a first-order spool lag
after each throttle move, sensor noise) cut on the window grid: windows across a throttle
step, a take-off roll, a level-off or a settling spool are refused, the others get the phase
of their segment; a recording that starts in the air has no take-off; the grid does not
depend on where the samples are split; window means skip missing values. Without a condition,
a single-point type's own inputs and sensors decide: a moved input or a sensor drifting
beyond the dead band refuses its window, a missing value is not judged, and such windows have
no phase."""

from __future__ import annotations

import numpy as np
import pytest

from estimation.steady_windows import (
    SteadyCriteria,
    field_of,
    held_steady,
    steady_windows,
    unphased_windows,
    window_length,
    window_means,
)

DT = 0.05
# Breakpoints [s] and values: idle, throttle up, roll, initial climb, climb power, climb,
# level-off, cruise, descent at idle.
T = np.array([0, 60, 66, 100, 180, 190, 490, 520, 700, 800], float)
ALT = np.array([500, 500, 500, 500, 2500, 2500, 20000, 20000, 20000, 10000], float)
MACH = np.array([0, 0, 0, 0.25, 0.30, 0.30, 0.55, 0.78, 0.78, 0.6])
POWER = np.array([0, 0, 100, 100, 100, 92, 92, 80, 80, 30], float)


def _flight(seed: int = 0) -> tuple[np.ndarray, ...]:
    t = np.arange(0.0, T[-1], DT)
    alt, mach, power = (np.interp(t, T, v) for v in (ALT, MACH, POWER))
    # Spool speed: a first-order lag (5 s) behind the power setting, plus noise.
    speed = np.empty_like(t)
    speed[0] = 60.0 + 0.4 * power[0]
    for k in range(1, len(t)):
        speed[k] = speed[k - 1] + DT / 5.0 * (60.0 + 0.4 * power[k] - speed[k - 1])
    rng = np.random.default_rng(seed)
    spools = (speed * (1 + 1e-3 * rng.standard_normal(len(t))))[:, None]
    return t, alt, mach, power, spools


def test_windows_and_phases_of_a_flight() -> None:
    t, alt, mach, power, spools = _flight()
    windows = steady_windows(alt, mach, power, spools, DT, field_of(alt[0], mach[0]))
    W = window_length(DT, 30.0)
    assert W == 600
    phase_of = {w.index: w.phase for w in windows}
    for w in windows:
        assert (w.start, w.stop) == (w.index * W, (w.index + 1) * W)
    # 60-90 s: the throttle step and the roll; 90-120 s: the roll ends at 100 s.
    assert 2 not in phase_of and 3 not in phase_of
    # 120-180 s: the initial climb at take-off power, settled.
    assert phase_of[4] == phase_of[5] == "takeoff"
    # 180-210 s: back to climb power.
    assert 6 not in phase_of
    assert all(phase_of[k] == "climb" for k in range(8, 16))
    # 480-510 s and 510-540 s: the level-off and the power change.
    assert 16 not in phase_of and 17 not in phase_of
    assert all(phase_of[k] == "cruise" for k in range(18, 23))
    # The descent at idle is not summarised.
    assert all(k < 23 for k in phase_of)


def test_a_moving_spool_is_refused_by_its_transient_index() -> None:
    # Steady cruise condition; the spool speed drifts at 0.2 %/s in the first window (outside
    # seed 004's dead band of 0.1 %/s) and at 0.02 %/s in the second.
    n = 1200
    alt, mach, power = np.full(n, 30000.0), np.full(n, 0.8), np.full(n, 80.0)
    t = np.arange(n) * DT
    rate = np.where(t < 30.0, 2e-3, 2e-4)
    spools = (9000.0 * np.exp(np.cumsum(rate) * DT))[:, None]
    without = steady_windows(alt, mach, power, None, DT, None)
    with_ti = steady_windows(alt, mach, power, spools, DT, None)
    assert [w.index for w in without] == [0, 1]
    assert [w.index for w in with_ti] == [1]
    assert with_ti[0].phase == "cruise"


def test_a_recording_that_starts_in_the_air_has_no_take_off() -> None:
    t, alt, mach, power, spools = _flight()
    start = int(200.0 / DT)
    windows = steady_windows(alt[start:], mach[start:], power[start:], spools[start:], DT,
                             field_of(alt[start], mach[start]))
    assert field_of(alt[start], mach[start]) is None
    assert windows and {w.phase for w in windows} <= {"climb", "cruise"}


@pytest.mark.parametrize("split", [1, 599, 600, 7777])
def test_the_grid_does_not_depend_on_where_samples_are_split(split: int) -> None:
    t, alt, mach, power, spools = _flight(seed=3)
    whole = steady_windows(alt, mach, power, spools, DT, alt[0])
    W = window_length(DT, 30.0)
    first = split // W
    part = steady_windows(alt[first * W:], mach[first * W:], power[first * W:],
                          spools[first * W:], DT, alt[0], first_window=first)
    assert part == [w for w in whole if w.index >= first]


def test_window_means_skip_missing_values() -> None:
    v = np.arange(12.0).reshape(6, 2)
    v[1, 0] = np.nan
    v[3:, 1] = np.nan
    got = window_means(v, np.array([0, 3]), 3)
    np.testing.assert_allclose(got[0], [(0 + 4) / 2, (1 + 3 + 5) / 3])
    assert got[1, 0] == pytest.approx((6 + 8 + 10) / 3) and np.isnan(got[1, 1])


def test_criteria_are_what_they_say() -> None:
    t, alt, mach, power, spools = _flight()
    loose = SteadyCriteria(window_s=10.0)
    windows = steady_windows(alt, mach, power, spools, DT, alt[0], criteria=loose)
    assert window_length(DT, 10.0) == 200
    assert all(w.stop - w.start == 200 for w in windows)


def test_own_signals_decide_without_a_condition() -> None:
    """Six 30 s windows at 50 Hz of two inputs (fuel flow, a vane at zero) and two sensors."""
    dt, W = 0.02, 1500
    n = 6 * W
    rng = np.random.default_rng(3)
    u = np.column_stack([np.full(n, 3600.0), np.zeros(n)])
    y = np.column_stack([780.0 + rng.normal(0, 2.0, n), 92.0 + rng.normal(0, 0.15, n)])
    u[W:2 * W, 0] *= np.linspace(1.0, 1.02, W)  # window 1: fuel flow moved by 2 %
    # window 2: a sensor drifting by 4 % over 30 s (transient index 1.3e-3 /s > 1e-3)
    y[2 * W:3 * W, 1] *= np.linspace(1.0, 1.04, W)
    y[3 * W:4 * W, 1] *= np.linspace(1.0, 1.02, W)  # window 3: 2 % (6.7e-4 /s): settled
    u[4 * W + 7, 0] = np.nan  # window 4: a missing input value is not judged there
    u[5 * W + 9, 1] = 0.5  # window 5: the vane, centred on zero, moved
    held = held_steady(u, y, dt)
    assert held.tolist() == [True, False, False, True, True, False]
    # Nothing to judge: no sensor, or every sensor missing in the window.
    assert not held_steady(u, None, dt).any()
    assert held_steady(None, y, dt)[[0, 1]].all()
    gone = y.copy()
    gone[10, :] = np.nan
    assert held_steady(u, gone, dt).tolist()[0] is False
    # Counted on the grid from the first window given, without a phase.
    windows = unphased_windows(held, dt, first_window=4)
    assert [(w.index, w.start, w.stop, w.phase) for w in windows] == [
        (4, 4 * W, 5 * W, None), (7, 7 * W, 8 * W, None), (8, 8 * W, 9 * W, None)]
