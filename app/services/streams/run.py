"""The stream filter over samples: deviations from the trim at each sample's condition, and
the filter scheduled piecewise over the envelope (a segment keeps its anchor's gain until the
condition leaves the ``TOLERANCE`` box); or, when the design chooses ``cgekf``, seed 001's
constant-gain EKF on the built-in nonlinear engine over the samples in engine units.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pyarrow as pa

from app.services.streams.estimator import TOLERANCE, StreamEstimator, _stored_affine
from app.signals import CONDITION_COLUMNS
from estimation.bias import filter_compensated
from estimation.cgekf import filter_one
from estimation.stream_filter import SegmentGain, filter_run


def _first_outside(cond: np.ndarray, start: int, anchor: np.ndarray) -> int:
    """First index >= start whose condition leaves the box around ``anchor`` (len if none)."""
    k, step, S = start, 256, cond.shape[0]
    while k < S:
        block = cond[k:k + step]
        out = np.any(np.abs(block - anchor) > TOLERANCE, axis=1)
        if out.any():
            return k + int(np.argmax(out))
        k += step
        step = min(step * 2, 1 << 16)
    return S


@dataclass
class Carry:
    """The filter state between samples: x_hat and du of the last sample, the anchor; for
    the constant-gain EKF, x is the a-priori [x (engine units); tuners] of the next sample
    and ``plant`` what the on-board engine model carries (``cgekf.filter_one``'s state; None
    before the first sample)."""

    x: np.ndarray
    u_prev: np.ndarray
    anchor: np.ndarray | None
    switches: int
    ti: float = 0.0  # low-passed transient index (docs/math.md section 7)
    plant: dict[str, Any] | None = None


def recording_start(n: int, nx: int, n_inputs: int,
                    previous_end: Sequence[float] | np.ndarray | None = None) -> Carry:
    """The filter state before a recording's first sample, as every recording of an engine
    starts: the tuners where the engine's previous recording under the design ended
    (``previous_end``, its x_hat after the last sample; None, or of another length: nominal),
    the engine states at zero deviation, no anchor."""
    x = np.zeros(n)
    if previous_end is not None and len(previous_end) == n:
        x[nx:] = np.asarray(previous_end, float)[nx:]
    return Carry(x, np.zeros(n_inputs), None, 0)


def filter_piece(
    est: StreamEstimator, dt: float, cond: np.ndarray, dy: np.ndarray, du: np.ndarray,
    carry: Carry, capture: int | None = None,
) -> tuple[np.ndarray, Carry, Carry | None]:
    """Filter S samples from ``carry``; returns per-sample rows [S, width] (q, q 1-sigma, h,
    h 1-sigma, z, z 1-sigma, innovations), the carry after the last sample, and the carry
    after sample ``capture`` (an index into this piece) when given."""
    if est.stream_filter == "cgekf":
        return _cgekf_piece(est, dt, cond, dy, du, carry, capture)
    S = cond.shape[0]
    layout = est.layout
    sl = layout.slices()
    rows = np.empty((S, layout.width))
    nx = est.nx
    anchor = carry.anchor
    switches = carry.switches
    x_prev, u_prev = carry.x, carry.u_prev
    ti_prev = carry.ti
    bias = est.bias
    scale = None if bias is None else est.state_scale(cond, bias.x_ref)
    captured: Carry | None = None
    i = 0
    while i < S:
        if anchor is None:
            anchor, switches = cond[i].copy(), switches + 1
        j = _first_outside(cond, i, anchor)
        if j == i:
            anchor, switches = cond[i].copy(), switches + 1
            continue
        g = est.gain(est.snapped(anchor), dt)
        ys, us = dy[i:j], du[i:j]
        if bias is not None and not np.isnan(ys).any():
            # seed 004 eq. 5-6; a segment with a missing sensor runs uncompensated
            ce = filter_compensated(
                g.A, g.B, g.C, g.D, {0: g.K, **g.region_gains}, ys[:, None, :],
                us[:, None, :], nx, dt, bias=bias, x0=x_prev, u_prev=u_prev,
                state_scale=None if scale is None else scale[i:j], ti0=ti_prev)
            x = ce.x_hat[:, 0, :]
            ti_prev = float(ce.ti[-1, 0])
        else:
            x = filter_run(g, ys, us, x_prev, u_prev)
        # Innovation dy - C x_pred - D du with x_pred = A x_hat[k-1] + B du[k-1].
        xp, up = np.empty_like(x), np.empty_like(us)
        xp[0], xp[1:], up[0], up[1:] = x_prev, x[:-1], u_prev, us[:-1]
        pred = xp @ g.A.T + up @ g.B.T
        q = x[:, nx:]
        rows[i:j, sl["q"]] = q
        rows[i:j, sl["h"]] = q @ est.Vp.T  # seed 002 eq. 11
        rows[i:j, sl["z"]] = x @ g.F.T + us @ g.G.T
        rows[i:j, sl["residual"]] = ys - pred @ g.C.T - us @ g.D.T
        m, p = q.shape[1], est.Vp.shape[0]
        rows[i:j, sl["q_sigma"]] = g.sigma[:m]
        rows[i:j, sl["h_sigma"]] = g.sigma[m:m + p]
        rows[i:j, sl["z_sigma"]] = g.sigma[m + p:]
        if capture is not None and i <= capture < j:
            captured = Carry(x[capture - i].copy(), us[capture - i].copy(), anchor.copy(),
                             switches, ti_prev)
        x_prev, u_prev = x[-1].copy(), us[-1].copy()
        i = j
    return rows, Carry(x_prev, u_prev, anchor, switches, ti_prev), captured


def window_means(rows: np.ndarray, W: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stored windows of ``filter_piece``'s rows [S, width]: each window's first sample
    [n], its samples [n] and the means of its rows [n, width] over W samples at a time, each
    over the finite values (a missing sensor has no residual there; NaN where none is)."""
    S = rows.shape[0]
    starts = np.arange(0, S, W)
    counts = np.diff(np.append(starts, S))
    finite = np.isfinite(rows)
    sums = np.add.reduceat(np.where(finite, rows, 0.0), starts, axis=0)
    seen = np.add.reduceat(finite.astype(np.int64), starts, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(seen > 0, sums / np.maximum(seen, 1), np.nan)
    return starts, counts, means


def learning_residuals(
    est: StreamEstimator, dt: float, cond: np.ndarray, dy: np.ndarray, du: np.ndarray,
    x_ref: np.ndarray, ti_tau_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Transient index [S] and innovations [S, ny] of a healthy recording with the tuners held
    at zero (seed 004's learning phase), scheduled like ``filter_piece``. Samples of a segment
    with a missing sensor are NaN."""
    S = cond.shape[0]
    nx = est.nx
    ti = np.full(S, np.nan)
    innov = np.full((S, dy.shape[1]), np.nan)
    scale = est.state_scale(cond, x_ref)
    x_prev = np.zeros(est.n)
    u_prev = du[0] if S else np.zeros(du.shape[1])
    ti_prev = 0.0
    i = 0
    while i < S:
        anchor = cond[i].copy()
        j = max(i + 1, _first_outside(cond, i, anchor))
        g: SegmentGain = est.gain(est.snapped(anchor), dt)
        K = g.K.copy()
        K[nx:] = 0.0  # tuners frozen at nominal health
        ys, us = dy[i:j], du[i:j]
        if not np.isnan(ys).any():
            ce = filter_compensated(g.A, g.B, g.C, g.D, {0: K}, ys[:, None, :], us[:, None, :],
                                    nx, dt, x0=x_prev, u_prev=u_prev,
                                    state_scale=None if scale is None else scale[i:j],
                                    ti_tau_s=ti_tau_s, ti0=ti_prev)
            ti[i:j], innov[i:j] = ce.ti[:, 0], ce.innovation[:, 0]
            x_prev, ti_prev = ce.x_hat[-1, 0].copy(), float(ce.ti[-1, 0])
        else:
            x_prev = filter_run(replace(g, K=K), ys, us, x_prev, u_prev)[-1]
        u_prev = us[-1]
        i = j
    return ti, innov


def deviations(
    est: StreamEstimator, table: pa.Table
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Conditions [S, 4], sensor and actuator deviations [S, ny], [S, nu] in percent of the
    trim at each sample's condition (actuators absent from the recording, or with no trim,
    stay at trim)."""
    S = table.num_rows

    def column(name: str) -> np.ndarray | None:
        if name not in table.column_names:
            return None
        return np.asarray(table[name].to_numpy(zero_copy_only=False), float)

    def sensor(name: str) -> np.ndarray:
        values = column(name)
        return np.full(S, np.nan) if values is None else values

    cond = np.column_stack([sensor(c) for c in CONDITION_COLUMNS])
    y_trim, u_trim = est.trims(cond)
    y = np.column_stack([sensor(n) for n in est.model.sensor_names])
    dy = 100.0 * (y - y_trim) / y_trim
    du = np.zeros((S, est.model.n_inputs))
    for k, name in enumerate(est.model.input_names):
        u = column(name)
        if u is None:
            continue
        trim = u_trim[:, k]
        ok = np.isfinite(trim) & (np.abs(trim) > 1e-9) & np.isfinite(u)
        du[ok, k] = 100.0 * (u[ok] - trim[ok]) / trim[ok]
    return cond, dy, du


def _column(table: pa.Table, name: str) -> np.ndarray:
    """A stored column as floats (NaN throughout when the recording lacks it)."""
    if name not in table.column_names:
        return np.full(table.num_rows, np.nan)
    return np.asarray(table[name].to_numpy(zero_copy_only=False), float)


def filter_inputs(
    est: StreamEstimator, table: pa.Table
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the design's stream filter takes: ``deviations`` for the scheduled linear filter;
    for the constant-gain EKF, conditions [S, 4] and the sensors and commands [S, ny], [S, 3]
    in the engine's units (a command the recording lacks is its trim at the condition)."""
    if est.stream_filter != "cgekf":
        return deviations(est, table)
    cond = np.column_stack([_column(table, c) for c in CONDITION_COLUMNS])
    _, u_trim = est.trims(cond)
    model = est.model

    def engine_units(stored: np.ndarray, names: list[str], units: list[str]) -> np.ndarray:
        ab = np.array([_stored_affine(n, u) for n, u in zip(names, units, strict=True)])
        return (stored - ab[:, 1]) / ab[:, 0]

    y = np.column_stack([_column(table, n) for n in model.sensor_names])
    y = engine_units(y, model.sensor_names, [s.unit for s in model.sensors])
    u = np.column_stack([_column(table, n) if n in table.column_names else u_trim[:, k]
                         for k, n in enumerate(model.input_names)])
    u = engine_units(u, model.input_names, [s.unit for s in model.inputs])
    return cond, y, u


def _cgekf_piece(
    est: StreamEstimator, dt: float, cond: np.ndarray, y: np.ndarray, u: np.ndarray,
    carry: Carry, capture: int | None,
) -> tuple[np.ndarray, Carry, Carry | None]:
    """``filter_piece`` with the constant-gain EKF (seed 001 eq. 4): the same row layout, the
    health V*^+ q (seed 002 eq. 11), aux in percent of the trim at each sample's condition,
    innovations in percent of the design point's trim corrected to the inlet."""
    design, sigma = est.cgekf(dt)
    S, nx = cond.shape[0], est.nx
    layout = est.layout
    sl = layout.slices()
    rows = np.empty((S, layout.width))
    env = cond[:, :3]  # alt ft, Mach, dTamb K
    assert est.schedule is not None  # a cgekf design is on the built-in engine
    trims = est.schedule.trims_at(cond[:, [0, 1, 3, 2]])
    z_trim = np.stack([trims[n] for n in design.aux], axis=1) if design.aux else \
        np.zeros((S, 0))
    cuts = [0, S] if capture is None else [0, capture + 1, S]
    x, plant = carry.x, carry.plant
    out, captured = carry, None
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        res, plant = filter_one(design, y[a:b], u[a:b], env[a:b], x[nx:], plant, x[:nx])
        q = res.d_hat[:, 0]
        rows[a:b, sl["q"]] = q
        rows[a:b, sl["h"]] = q @ est.Vp.T  # seed 002 eq. 11
        rows[a:b, sl["z"]] = 100.0 * (res.z_hat[:, 0] - z_trim[a:b]) / z_trim[a:b]
        rows[a:b, sl["residual"]] = res.residual[:, 0]
        x = np.concatenate([res.x_next[0], res.d_next[0]])
        out = Carry(x, np.zeros(u.shape[1]), None, 0, plant=plant)
        if capture is not None and b == capture + 1:
            captured = out
    m, p = est.vstar.shape[0], est.Vp.shape[0]
    rows[:, sl["q_sigma"]] = sigma[:m]
    rows[:, sl["h_sigma"]] = sigma[m:m + p]
    rows[:, sl["z_sigma"]] = sigma[m + p:]
    return rows, out, captured
