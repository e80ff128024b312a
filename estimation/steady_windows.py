"""Steady windows of a stream recording: stable-frame extraction for the engine's trend.

A recording is cut into fixed windows of ``window_s`` seconds on a grid from its first sample
(window k holds samples ``k W .. (k + 1) W - 1``, W = round(window_s / dt)), so a window is the
same whatever chunks the samples arrived in. A window is *steady* when, over it,

- the power setting moves by at most ``power_tol_pct`` (max - min),
- the Mach number moves by at most ``mach_tol`` (a slow climb schedule passes, a take-off
  roll does not),
- the altitude rate is constant: the rates fitted over the window's two halves differ by at
  most ``rate_tol_fpm`` (a level-off or the start of a climb inside the window fails),
- the spools are settled: seed 004's transient index (``bias.transient_index``) of the
  measured spool speeds, their fitted slope over their mean, is inside its dead band
  ``bias.TI_STAR`` in magnitude (skipped when the recording carries no spool speed).

An engine type whose models are at one operating point (no schedule on the condition) may send
no condition at all; its windows are then found on its own signals (``held_steady``), the
model's inputs and sensors:

- each input is held: it moves by at most ``input_tol_pct`` percent of its mean over the
  window (max - min; an input whose mean is zero must not move at all), an input with a
  missing value in the window is not judged there;
- each sensor has settled: its own transient index, the fitted slope over the window divided
  by its mean (seed 004's eq. 8, ``bias.transient_index``, with that one signal), is inside
  the same dead band ``ti_max`` in magnitude; a sensor with a missing value in the window, or
  a mean of zero, is not judged there, and a window with no sensor judged is not steady.

Such a window has no phase (the type's models do not depend on it: ``unphased_windows``); when
the recording carries the condition as well, the condition's criteria and phase apply on top
(``steady_windows`` with ``held``).

A steady window is given the phase of its segment from its mean condition: below
``min_power_pct`` or descending faster than ``climb_rate_fpm`` it is not summarised (idle,
descent); within ``takeoff_height_ft`` of the departure field (the recording's first
altitude when it starts on the ground, below ``ground_mach``; a recording that starts in the
air has no take-off) it is take-off; climbing at ``climb_rate_fpm`` or more it is climb;
otherwise cruise.
``window_means`` then summarises each window into one record: the mean of every signal over
the window's finite values (NaN where a signal has none).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimation.bias import TI_STAR, transient_index


@dataclass(frozen=True)
class SteadyCriteria:
    """How long a window is and how steady it must be (see the module docstring)."""

    window_s: float = 30.0
    power_tol_pct: float = 1.0
    mach_tol: float = 0.04
    rate_tol_fpm: float = 300.0
    ti_max: float = TI_STAR
    climb_rate_fpm: float = 300.0
    takeoff_height_ft: float = 3000.0
    min_power_pct: float = 50.0
    ground_mach: float = 0.1
    input_tol_pct: float = 1.0


@dataclass(frozen=True)
class SteadyWindow:
    """Window ``index`` of the grid (samples ``start`` .. ``stop`` - 1) and its phase (None:
    found on a single-point type's own signals, no condition to tell it)."""

    index: int
    start: int
    stop: int
    phase: str | None


def window_length(dt_s: float, window_s: float) -> int:
    """Samples per window (at least two, so that a rate can be fitted)."""
    return max(2, int(round(window_s / dt_s)))


def _slopes(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares slope of each row of y [n, W] over times t [W] (NaN-free rows)."""
    tc = t - t.mean()
    return (y - y.mean(axis=1, keepdims=True)) @ tc / float(tc @ tc)


def _blocks(values: np.ndarray | None, n: int, W: int) -> np.ndarray:
    """Columns of values [S, k] (or None: no column) cut into windows: [n, k, W]."""
    if values is None:
        return np.empty((n, 0, W))
    v = np.asarray(values, float)
    v = v.reshape(v.shape[0], -1)[: n * W]
    return v.reshape(n, W, v.shape[1]).transpose(0, 2, 1)


def held_steady(
    inputs: np.ndarray | None,
    sensors: np.ndarray | None,
    dt_s: float,
    criteria: SteadyCriteria | None = None,
) -> np.ndarray:
    """Whether each complete window of the samples given has its inputs held and its sensors
    settled (see the module docstring): [n] booleans.

    inputs [S, ni], sensors [S, ns] in any units (NaN: missing), or None: none of them.
    """
    c = criteria or SteadyCriteria()
    W = window_length(dt_s, c.window_s)
    lengths = [np.asarray(v).shape[0] for v in (inputs, sensors) if v is not None]
    n = (lengths[0] if lengths else 0) // W
    u, y = _blocks(inputs, n, W), _blocks(sensors, n, W)
    with np.errstate(invalid="ignore"):
        u_mean = u.mean(axis=2)
        moved = np.ptp(u, axis=2) > c.input_tol_pct / 100.0 * np.abs(u_mean)
        held = ~np.any(np.isfinite(u_mean) & moved, axis=1)
        y_mean = y.mean(axis=2)
        judged = np.isfinite(y_mean) & (np.abs(y_mean) > 0)
        t = np.arange(W) * dt_s
        tc = t - t.mean()
        slope = (y - y_mean[..., None]) @ tc / float(tc @ tc)
        # seed 004 eq. 8 with one signal: its slope over its mean
        ti = np.abs(slope / np.where(judged, y_mean, 1.0))
        unsettled = judged & ~(ti <= c.ti_max)
    return held & judged.any(axis=1) & ~unsettled.any(axis=1)


def unphased_windows(
    held: np.ndarray, dt_s: float, first_window: int = 0, criteria: SteadyCriteria | None = None
) -> list[SteadyWindow]:
    """The windows ``held_steady`` found, counted from window ``first_window`` of the grid,
    without a phase."""
    W = window_length(dt_s, (criteria or SteadyCriteria()).window_s)
    return [SteadyWindow(i, i * W, (i + 1) * W, None)
            for i in (first_window + np.flatnonzero(held)).tolist()]


def steady_windows(
    alt_ft: np.ndarray,
    mach: np.ndarray,
    power_pct: np.ndarray,
    spools: np.ndarray | None,
    dt_s: float,
    field_alt_ft: float | None,
    first_window: int = 0,
    criteria: SteadyCriteria | None = None,
    held: np.ndarray | None = None,
) -> list[SteadyWindow]:
    """The steady windows among the complete windows of samples that start at window
    ``first_window`` of the grid; ``start``/``stop`` count from the recording's first sample.

    alt_ft, mach, power_pct [S]; spools [S, k] measured spool speeds (NaN: missing) or None;
    field_alt_ft: the departure field's altitude (``field_of``), None: no take-off here;
    held: ``held_steady`` of the same samples, required as well when given.
    """
    c = criteria or SteadyCriteria()
    W = window_length(dt_s, c.window_s)
    n = int(np.asarray(alt_ft).shape[0]) // W
    if n == 0:
        return []
    alt = np.asarray(alt_ft, float)[: n * W].reshape(n, W)
    m = np.asarray(mach, float)[: n * W].reshape(n, W)
    p = np.asarray(power_pct, float)[: n * W].reshape(n, W)
    t = np.arange(W) * dt_s
    h = W // 2
    rate = _slopes(t, alt) * 60.0  # ft/min
    rate_a = _slopes(t[:h], alt[:, :h]) * 60.0
    rate_b = _slopes(t[h:], alt[:, h:]) * 60.0
    steady = (
        (np.ptp(p, axis=1) <= c.power_tol_pct)
        & (np.ptp(m, axis=1) <= c.mach_tol)
        & (np.abs(rate_b - rate_a) <= c.rate_tol_fpm)
    )
    if spools is not None:
        s = np.asarray(spools, float)
        s = s.reshape(s.shape[0], -1)[: n * W]
        ti = np.zeros(n)
        for k in range(n):
            block = s[k * W:(k + 1) * W]
            cols = np.all(np.isfinite(block), axis=0) & (np.abs(np.nanmean(block, axis=0)) > 0)
            if not cols.any():
                continue
            xdot = _slopes(t, block[:, cols].T)
            ti[k] = abs(float(transient_index(xdot[None, :], block[:, cols].mean(axis=0))[0]))
        steady &= ti <= c.ti_max
    if held is not None:
        steady &= np.asarray(held, bool)[:n]
    mean_p = p.mean(axis=1)
    height = (np.full(n, np.inf) if field_alt_ft is None
              else alt.mean(axis=1) - float(field_alt_ft))
    out = []
    for j in np.flatnonzero(steady).tolist():
        if mean_p[j] < c.min_power_pct or rate[j] <= -c.climb_rate_fpm:
            continue
        if height[j] < c.takeoff_height_ft:
            phase = "takeoff"
        elif rate[j] >= c.climb_rate_fpm:
            phase = "climb"
        else:
            phase = "cruise"
        i = first_window + j
        out.append(SteadyWindow(i, i * W, (i + 1) * W, phase))
    return out


def field_of(first_alt_ft: float, first_mach: float,
             criteria: SteadyCriteria | None = None) -> float | None:
    """The departure field's altitude: the first sample's when the recording starts on the
    ground (Mach below ``ground_mach``), else None (no take-off in the recording)."""
    c = criteria or SteadyCriteria()
    if not (np.isfinite(first_alt_ft) and np.isfinite(first_mach)):
        return None
    return float(first_alt_ft) if first_mach < c.ground_mach else None


def window_means(values: np.ndarray, starts: np.ndarray, length: int) -> np.ndarray:
    """Mean of each column of values [S, n] over the finite samples of each window
    ``starts[j] .. starts[j] + length - 1`` (indices into values): [len(starts), n], NaN where
    a column has no finite value in a window."""
    v = np.asarray(values, float)
    v = v.reshape(v.shape[0], -1)
    idx = np.asarray(starts, int)[:, None] + np.arange(length)[None, :]
    block = v[idx]  # [J, W, n]
    finite = np.isfinite(block)
    seen = finite.sum(axis=1)
    total = np.where(finite, block, 0.0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(seen > 0, total / np.maximum(seen, 1), np.nan)
