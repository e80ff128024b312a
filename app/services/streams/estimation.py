"""Stream estimation: the reduced-order steady-state Kalman filter over a recording.

Each recording is filtered at its full rate with the engine type's active design (V*, the
design model's sensors, health parameters and noise; MATH.md sections 2-3):

    x_hat[k] = A_xq x_hat[k-1] + B_xq du[k-1] + K (dy[k] - C_xq x_pred[k] - D du[k])

Scheduling over the envelope. Sensor and actuator deviations are percent of the trim at each
sample's own operating condition (interpolated from the built-in engine's schedule, corrected
parameters, as the snapshot pipeline does). The model matrices and the steady-state gain K
(DARE) are scheduled piecewise: a segment keeps the gain of its anchor condition until
altitude, Mach, power or dTamb leaves a box of ``TOLERANCE`` around the anchor; the next sample
becomes the new anchor. The gain is computed at the anchor rounded to a lattice of the same
step, so gains are cached and shared between recordings (the benchmark's climb to 35,000 ft,
cruise and descent takes 71, each a DARE of order nx + m). An imported single-point model has
one gain. A model linearised at another sample interval is resampled exactly (zero-order hold
of the same continuous system: A^(dt_recording / dt_model), see ``resample``).

Storage. The filter output is stored as one row per one-second window (means of q_hat, h_hat,
z_hat, their 1-sigma and the innovations), not per sample: a 20 Hz flight of two hours is
144,000 samples but 7,200 rows, which is what a trend plot can show, and each row stays one
packed blob. The full-rate state is kept at the last complete window boundary (where the next
chunk restarts, so a window split by a chunk boundary is recomputed whole from the same
state) and at the last sample (the end of the last chunk).

Continuation and re-runs. A recording's first sample starts from the tuners at the end of the
engine's previous recording (spool states start at zero deviation). Each run deletes the
recording's rows from the first affected window and inserts them again, so a re-run never
duplicates rows; because the arithmetic per sample does not depend on where runs start,
live chunks give the rows of the whole file. When an earlier recording arrives late, every
later recording whose starting tuners change is estimated again from its start.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from sqlalchemy import delete, insert, select
from sqlalchemy.orm import Session

from app.errors import NotFound
from app.models import Engine, EngineModel, EstimatorDesign, StreamChunk, StreamRecording
from app.models.base import utcnow
from app.models.estimates import EstimateLayout
from app.models.ingest import ACTUATORS, CONDITION_COLUMNS, SENSORS, SignalSpec
from app.models.stream_estimates import StreamEstimate, StreamFilterState
from app.services import common, units
from app.services.designs import service as designs
from app.services.snapshots import estimator
from app.services.streams import recordings
from estimation.engine.schedule import EngineSchedule
from estimation.kalman import filter_stream_states, steady_state_gain
from estimation.model import LinearModel
from estimation.reduced import reduced_model

WINDOW_S = 1.0  # stored window length (seconds of recording)
# Re-schedule box and gain lattice, in stored column order (alt ft, Mach, dTamb K, power %).
TOLERANCE = np.array([1000.0, 0.02, 2.0, 2.0])
PIECE = 65_536  # samples filtered per pass (bounds memory; aligned on windows)
# Noise when a design document does not carry it (per sample of the design model).
DEFAULT_Q_STD = 0.01
DEFAULT_QH_STD = 0.01

STORED: dict[str, SignalSpec] = {s.name: s for s in SENSORS + ACTUATORS}

Progress = Callable[[float, str | None], None]


class StreamEstimationError(RuntimeError):
    """A design or recording the stream filter cannot run."""


@dataclass(frozen=True)
class SegmentGain:
    """Reduced model and steady-state gain at one anchor condition and sample interval."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    F: np.ndarray
    G: np.ndarray
    K: np.ndarray
    sigma: np.ndarray  # [q | h | z] 1-sigma from the a-posteriori covariance


def resample(model: LinearModel, dt: float) -> LinearModel:
    """The model at sample interval ``dt`` (zero-order hold on u and h).

    With A = exp(Ac dt0) and [B, L] = Ac^-1 (A - I) [Bc, Lc], the same continuous system at dt
    has A_r = A^r (r = dt / dt0, through the eigenvalues of A, real and positive for spool and
    metal-temperature modes) and [B_r, L_r] = (A - I)^-1 (A_r - I) [B, L] (functions of A
    commute), which keeps the steady-state gains C (I - A)^-1 L + M.
    """
    if math.isclose(dt, model.dt, rel_tol=1e-9):
        return model
    w, T = np.linalg.eig(model.A)
    on_negative_axis = (np.abs(np.imag(w)) <= 1e-12 * np.abs(w)) & (np.real(w) <= 0.0)
    if np.any(on_negative_axis):
        raise StreamEstimationError(
            f"the design model (dt {model.dt:g} s) cannot be resampled to {dt:g} s: "
            "its state matrix has eigenvalues on the negative real axis"
        )
    # Principal powers of conjugate pairs are conjugate: the product is real.
    Ar_c = np.linalg.solve(T.T, (T * w ** (dt / model.dt)).T).T  # T diag(w^r) T^-1
    Ar = np.real(Ar_c)
    eye = np.eye(model.n_states)
    BL = np.linalg.solve(model.A - eye, (Ar - eye) @ np.hstack([model.B, model.L]))
    nu = model.n_inputs
    return replace(model, A=Ar, B=BL[:, :nu], L=BL[:, nu:], dt=dt)


def _stored_affine(name: str, unit: str) -> tuple[float, float]:
    """(a, b): stored = a * model value + b (NaN when the signal is not stored or converts not)."""
    spec = STORED.get(name)
    if spec is None:
        return math.nan, math.nan
    if unit in (spec.unit, ""):
        return 1.0, 0.0
    try:
        return units.affine(spec.quantity, unit, spec.unit, reference=spec.percent_reference)
    except units.UnknownUnitError:
        return math.nan, math.nan


@dataclass(eq=False)
class StreamEstimator:
    """One design ready to filter streams: its model (sensors in use), V*, noise, schedule."""

    design_id: int
    model: LinearModel  # design model restricted to the sensors in use
    vstar: np.ndarray
    Vp: np.ndarray
    Q: np.ndarray
    Qh: np.ndarray
    schedule: EngineSchedule | None
    layout: EstimateLayout
    _gains: dict[tuple[Any, ...], SegmentGain] = field(default_factory=dict)

    @property
    def nx(self) -> int:
        return self.model.n_states

    @property
    def n(self) -> int:
        return self.model.n_states + int(self.vstar.shape[0])

    def snapped(self, anchor: np.ndarray) -> tuple[float, ...]:
        """The lattice point the gain of an anchor condition is computed at."""
        if self.schedule is None:
            return ()
        return tuple(float(v) for v in np.round(anchor / TOLERANCE) * TOLERANCE)

    def gain(self, key: tuple[float, ...], dt: float) -> SegmentGain:
        cached = self._gains.get((*key, dt))
        if cached is not None:
            return cached
        model = self.model
        if self.schedule is not None:
            alt, mach, dtamb, power = key
            at = self.schedule.model_at(alt, mach, power, dtamb)
            at = at.select_sensors(model.sensor_names).select_health(model.health_names)
            model = replace(at.select_aux(model.aux_names),
                            sensor_noise_std=model.sensor_noise_std)
        ratio = dt / model.dt
        model = resample(model, dt)
        # Random walks and process noise per sample scale with the sample interval.
        red = reduced_model(model, self.vstar, self.Q * ratio, self.Qh * ratio)
        ss = steady_state_gain(red.A, red.C, red.Q, model.R)
        P = ss.P_post
        Pq = P[self.nx:, self.nx:]
        sigma = np.sqrt(np.maximum(np.concatenate([
            np.diag(Pq), np.diag(self.Vp @ Pq @ self.Vp.T), np.diag(red.F @ P @ red.F.T)
        ]), 0.0))
        out = SegmentGain(red.A, red.B, red.C, red.D, red.F, red.G, ss.K, sigma)
        self._gains[(*key, dt)] = out
        return out

    def trims(self, cond: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sensor and actuator trims [S, ny], [S, nu] in stored units at conditions [S, 4]
        (stored column order alt, Mach, dTamb, power)."""
        model = self.model
        ys = [(s.name, s.unit) for s in model.sensors]
        us = [(s.name, s.unit) for s in model.inputs]
        if self.schedule is None:
            raw_y = np.array([model.trim.get(n, math.nan) for n, _ in ys])[None, :]
            raw_u = np.array([model.trim.get(n, math.nan) for n, _ in us])[None, :]
            raw_y = np.broadcast_to(raw_y, (cond.shape[0], len(ys)))
            raw_u = np.broadcast_to(raw_u, (cond.shape[0], len(us)))
            units_of = {n: u for n, u in ys + us}
        else:
            t = self.schedule.trims_at(cond[:, [0, 1, 3, 2]])
            raw_y = np.stack([t[n] for n, _ in ys], axis=1)
            raw_u = np.stack([t[n] for n, _ in us], axis=1) if us else np.zeros((len(cond), 0))
            tmpl = self.schedule.template
            units_of = {s.name: s.unit for s in (*tmpl.sensors, *tmpl.inputs)}
        ay = np.array([_stored_affine(n, units_of[n]) for n, _ in ys]).reshape(-1, 2)
        au = np.array([_stored_affine(n, units_of[n]) for n, _ in us]).reshape(-1, 2)
        return raw_y * ay[:, 0] + ay[:, 1], raw_u * au[:, 0] + au[:, 1]


_ESTIMATORS: dict[tuple[Any, ...], StreamEstimator] = {}


def _document_key(*documents: Any) -> str:
    text = json.dumps(documents, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def estimator_for(
    session: Session, design: EstimatorDesign, signals: Sequence[str]
) -> StreamEstimator:
    """The stream estimator of a stored design for a recording carrying ``signals``: the
    design's sensors that the recording has (at least one)."""
    if design.status != "ready" or design.result is None:
        raise StreamEstimationError(f"design {design.id} is not ready")
    row = session.get(EngineModel, design.engine_model_id)
    if row is None:
        raise StreamEstimationError(f"design {design.id}: its engine model is missing")
    result = design.result
    embedded = result.get("model")
    sched = estimator.builtin_schedule() if row.source == "builtin" else None
    key = (design.id, _document_key(result, None if isinstance(embedded, Mapping)
                                    else row.content), tuple(signals), id(sched))
    cached = _ESTIMATORS.get(key)
    if cached is not None:
        return cached
    model = LinearModel.from_dict(embedded if isinstance(embedded, Mapping) else row.content)
    sensors = result.get("sensors")
    if isinstance(sensors, list) and sensors and all(isinstance(s, str) for s in sensors):
        model = model.select_sensors(sensors)
    present = set(signals)
    used = [s for s in model.sensor_names if s in present]
    if not used:
        raise StreamEstimationError(
            f"the recording carries none of design {design.id}'s sensors {model.sensor_names}"
        )
    model = model.select_sensors(used)
    vstar_doc = estimator._find(result, "vstar")
    if vstar_doc is None:
        raise StreamEstimationError(f"design {design.id} has no V* (vstar)")
    vstar = np.asarray(vstar_doc, float)
    noise = result.get("noise") if isinstance(result.get("noise"), Mapping) else {}
    assert isinstance(noise, Mapping)
    nx, p = model.n_states, model.n_health
    Q = np.asarray(noise["Q"], float) if "Q" in noise else np.eye(nx) * DEFAULT_Q_STD**2
    Qh = np.asarray(noise["Qh"], float) if "Qh" in noise else np.eye(p) * DEFAULT_QH_STD**2
    Vp = np.linalg.solve(vstar @ vstar.T, vstar).T  # V*^+ (seed 002 eq. 5)
    m = vstar.shape[0]
    layout = EstimateLayout(
        tuners=tuple(f"q{i + 1}" for i in range(m)),
        health=tuple(model.health_names),
        aux=tuple(model.aux_names),
        sensors=tuple(model.sensor_names),
        faults=(),
        units={"tuners": ["%"] * m, "health": ["%"] * p, "aux": ["%"] * model.n_aux,
               "sensors": ["%"] * model.n_sensors, "faults": []},
    )
    est = StreamEstimator(design.id, model, vstar, Vp, Q, Qh, sched, layout)
    if len(_ESTIMATORS) > 32:
        _ESTIMATORS.clear()
    _ESTIMATORS[key] = est
    return est


# ---------------------------------------------------------------------------- filtering


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


def _filter_run(g: SegmentGain, ys: np.ndarray, us: np.ndarray, x_prev: np.ndarray,
                u_prev: np.ndarray) -> np.ndarray:
    """x_hat [L, n] over samples ys [L, ny], us [L, nu] with one gain. A sample missing a
    sensor (null) is not a measurement: x_hat is the prediction A x_hat + B du there."""
    missing = np.isnan(ys).any(axis=1)
    L = ys.shape[0]
    if not missing.any():
        return filter_stream_states(g.A, g.C, g.K, ys[:, None, :], u=us[:, None, :], B=g.B,
                                    D=g.D, x0=x_prev, u_prev=u_prev)[:, 0, :]
    x = np.empty((L, g.A.shape[0]))
    k = 0
    while k < L:
        if missing[k]:
            x[k] = g.A @ x_prev + g.B @ u_prev
            x_prev, u_prev, k = x[k], us[k], k + 1
            continue
        rest = missing[k:]
        e = k + int(np.argmax(rest)) if rest.any() else L
        x[k:e] = filter_stream_states(g.A, g.C, g.K, ys[k:e, None, :], u=us[k:e, None, :],
                                      B=g.B, D=g.D, x0=x_prev, u_prev=u_prev)[:, 0, :]
        x_prev, u_prev, k = x[e - 1], us[e - 1], e
    return x


@dataclass
class Carry:
    """The filter state between samples: x_hat and du of the last sample, the anchor."""

    x: np.ndarray
    u_prev: np.ndarray
    anchor: np.ndarray | None
    switches: int


def filter_piece(
    est: StreamEstimator, dt: float, cond: np.ndarray, dy: np.ndarray, du: np.ndarray,
    carry: Carry, capture: int | None = None,
) -> tuple[np.ndarray, Carry, Carry | None]:
    """Filter S samples from ``carry``; returns per-sample rows [S, width] (q, q 1-sigma, h,
    h 1-sigma, z, z 1-sigma, innovations), the carry after the last sample, and the carry
    after sample ``capture`` (an index into this piece) when given."""
    S = cond.shape[0]
    layout = est.layout
    sl = layout.slices()
    rows = np.empty((S, layout.width))
    nx = est.nx
    anchor = carry.anchor
    switches = carry.switches
    x_prev, u_prev = carry.x, carry.u_prev
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
        x = _filter_run(g, ys, us, x_prev, u_prev)
        # Innovation dy - C x_pred - D du with x_pred = A x_hat[k-1] + B du[k-1].
        xp = np.vstack([x_prev[None, :], x[:-1]])
        up = np.vstack([u_prev[None, :], us[:-1]])
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
                             switches)
        x_prev, u_prev = x[-1].copy(), us[-1].copy()
        i = j
    return rows, Carry(x_prev, u_prev, anchor, switches), captured


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


# ---------------------------------------------------------------------------- service


def _carry_of(state: Mapping[str, Any]) -> Carry:
    anchor = state.get("anchor")
    return Carry(np.asarray(state["x"], float), np.asarray(state["u_prev"], float),
                 None if anchor is None else np.asarray(anchor, float),
                 int(state.get("switches", 0)))


def _read_from(data_dir: Path, recording: StreamRecording, chunks: Sequence[StreamChunk],
               start: int) -> pa.Table:
    """Samples ``start`` .. end of the recording."""
    tables, first = [], None
    for chunk in chunks:
        if chunk.first_sample + chunk.n_samples <= start:
            continue
        if first is None:
            first = chunk.first_sample
        tables.append(pq.read_table(recordings.chunk_path(data_dir, recording, chunk.chunk_index)))
    if not tables:
        return pa.table({"time_s": pa.array([], pa.float64())})
    table = pa.concat_tables(tables, promote_options="default")
    assert first is not None
    return table.slice(start - first)


def _initial_x(session: Session, recording: StreamRecording, design_id: int, n: int,
               nx: int) -> list[float]:
    """x_hat before the first sample: the tuners at the end of the engine's previous
    recording under the design, spool states at zero deviation."""
    previous = session.scalar(
        select(StreamFilterState)
        .where(StreamFilterState.engine_id == recording.engine_id,
               StreamFilterState.design_id == design_id,
               StreamFilterState.started_at < recording.started_at)
        .order_by(StreamFilterState.started_at.desc())
        .limit(1)
    )
    x = [0.0] * n
    if previous is not None:
        end = previous.state.get("x_end", [])
        if len(end) == n:
            x[nx:] = [float(v) for v in end[nx:]]
    return x


def estimate_one(
    session: Session, data_dir: Path, recording: StreamRecording, design: EstimatorDesign,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Bring one recording's estimates under ``design`` up to its last received sample."""
    est = estimator_for(session, design, recording.signals)
    state_row = session.scalar(
        select(StreamFilterState).where(StreamFilterState.recording_id == recording.id,
                                        StreamFilterState.design_id == design.id)
    )
    dt = float(recording.dt_s)
    W = max(1, round(WINDOW_S / dt))
    if state_row is not None and state_row.layout != est.layout.to_dict():
        session.delete(state_row)  # another sensor set: start over
        session.flush()
        state_row = None
    if state_row is None:
        x0 = _initial_x(session, recording, design.id, est.n, est.nx)
        nu = est.model.n_inputs
        state_row = StreamFilterState(
            operator_id=recording.operator_id, engine_id=recording.engine_id,
            design_id=design.id, recording_id=recording.id, started_at=recording.started_at,
            window=W, n_samples=0, restart_sample=0, n_segments=0, layout=est.layout.to_dict(),
            state={"x": x0, "u_prev": [0.0] * nu, "anchor": None, "switches": 0,
                   "x_end": x0, "x_initial": x0},
        )
        session.add(state_row)
        session.flush()
    N = int(recording.n_samples)
    if state_row.n_samples >= N:
        return {"recording_id": recording.id, "samples": 0, "windows": 0}
    start = int(state_row.restart_sample)
    chunks = session.scalars(
        select(StreamChunk).where(StreamChunk.recording_id == recording.id)
        .order_by(StreamChunk.chunk_index)
    ).all()
    table = _read_from(data_dir, recording, chunks, start)
    if table.num_rows != N - start:
        raise StreamEstimationError(
            f"recording {recording.id}: {table.num_rows} samples on disk after sample {start}, "
            f"expected {N - start}"
        )
    session.execute(
        delete(StreamEstimate).where(StreamEstimate.recording_id == recording.id,
                                     StreamEstimate.design_id == design.id,
                                     StreamEstimate.window >= start // W)
    )
    restart = (N // W) * W  # the next run starts at the last complete window boundary
    carry = _carry_of(state_row.state)
    at_restart: Carry | None = None
    time_s = np.asarray(table["time_s"].to_numpy(zero_copy_only=False), float)
    piece = max(W, (PIECE // W) * W)
    n_windows = 0
    for p0 in range(0, N - start, piece):
        part = table.slice(p0, piece)
        cond, dy, du = deviations(est, part)
        S = part.num_rows
        capture = restart - 1 - (start + p0)
        rows, carry, got = filter_piece(est, dt, cond, dy, du, carry,
                                        capture if 0 <= capture < S else None)
        if got is not None:
            at_restart = got
        starts = np.arange(0, S, W)
        counts = np.diff(np.append(starts, S))
        # Window means over the finite values (a missing sensor has no residual there).
        finite = np.isfinite(rows)
        sums = np.add.reduceat(np.where(finite, rows, 0.0), starts, axis=0)
        seen = np.add.reduceat(finite.astype(np.int64), starts, axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            means = np.where(seen > 0, sums / np.maximum(seen, 1), np.nan)
        blobs = est.layout.pack(means)
        w0 = (start + p0) // W
        session.execute(insert(StreamEstimate), [
            {"operator_id": recording.operator_id, "engine_id": recording.engine_id,
             "design_id": design.id, "recording_id": recording.id, "window": w0 + k,
             "t_s": float(time_s[p0 + s]), "n": int(c), "packed": blob}
            for k, (s, c, blob) in enumerate(zip(starts, counts, blobs, strict=True))
        ])
        n_windows += len(blobs)
        if progress is not None:
            progress(min(1.0, (p0 + S) / (N - start)), f"recording {recording.id}: "
                     f"{start + p0 + S} of {N} samples")
    state = dict(state_row.state)
    if at_restart is not None:
        state.update(x=at_restart.x.tolist(), u_prev=at_restart.u_prev.tolist(),
                     anchor=None if at_restart.anchor is None else at_restart.anchor.tolist(),
                     switches=at_restart.switches)
        state_row.restart_sample = restart
    state["x_end"] = carry.x.tolist()
    state_row.state = state
    state_row.n_samples = N
    state_row.n_segments = carry.switches
    state_row.updated_at = utcnow()
    session.flush()
    return {"recording_id": recording.id, "samples": N - start, "windows": n_windows,
            "segments": carry.switches}


def _carry_forward(
    session: Session, data_dir: Path, recording: StreamRecording, design: EstimatorDesign,
) -> list[int]:
    """Re-estimate the engine's later recordings whose starting tuners changed."""
    later = session.scalars(
        select(StreamFilterState)
        .where(StreamFilterState.engine_id == recording.engine_id,
               StreamFilterState.design_id == design.id,
               StreamFilterState.started_at > recording.started_at)
        .order_by(StreamFilterState.started_at)
    ).all()
    rerun: list[int] = []
    for row in later:
        other = session.get(StreamRecording, row.recording_id)
        if other is None:
            continue
        n = len(row.state["x_initial"])
        if _initial_x(session, other, design.id, n, n - len(row.layout["tuners"])) == \
                row.state["x_initial"]:
            continue
        session.execute(delete(StreamEstimate).where(
            StreamEstimate.recording_id == other.id, StreamEstimate.design_id == design.id))
        session.delete(row)
        session.flush()
        estimate_one(session, data_dir, other, design)
        rerun.append(other.id)
    return rerun


def estimate_recording(
    session: Session, *, operator_id: int, recording_id: int, data_dir: Path,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Estimate a recording's new samples under its engine type's active design, then the
    engine's later recordings if their starting tuners changed. Idempotent."""
    recording = session.scalar(
        select(StreamRecording).where(StreamRecording.id == recording_id,
                                      StreamRecording.operator_id == operator_id)
        .with_for_update()
    )
    if recording is None:
        raise NotFound(f"recording {recording_id} not found")
    engine = session.get(Engine, recording.engine_id)
    assert engine is not None
    design = designs.active_design(
        session, operator_id=operator_id, engine_type_id=engine.engine_type_id
    )
    if design is None or design.status != "ready":
        return {"recording_id": recording.id, "samples": 0, "windows": 0,
                "message": "no active design for the engine type"}
    summary = estimate_one(session, data_dir, recording, design, progress)
    summary["design_id"] = design.id
    summary["rerun_recordings"] = _carry_forward(session, data_dir, recording, design)
    return summary


# ---------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class StreamSeries:
    """Decimated estimates of one recording: times [T] and values [T, width] by layout."""

    recording: StreamRecording
    design_id: int | None
    layout: EstimateLayout | None
    window_s: float
    n_estimated: int
    t_s: np.ndarray
    values: np.ndarray


def read_estimates(
    session: Session, *, operator_id: int, recording_id: int, design_id: int | None = None,
    max_points: int = 2000,
) -> StreamSeries:
    """The recording's stored windows (the latest design's unless ``design_id``), averaged
    into at most ``max_points`` equal buckets of windows."""
    recording = recordings.get_recording(
        session, operator_id=operator_id, recording_id=recording_id
    )
    stmt = select(StreamFilterState).where(StreamFilterState.recording_id == recording.id)
    if design_id is not None:
        common.owned(session, EstimatorDesign, operator_id, design_id, "design")
        stmt = stmt.where(StreamFilterState.design_id == design_id)
    state = session.scalars(stmt.order_by(StreamFilterState.updated_at.desc(),
                                          StreamFilterState.id.desc()).limit(1)).first()
    if state is None:  # not estimated (yet, or under that design)
        return StreamSeries(recording, design_id, None, WINDOW_S, 0, np.zeros(0),
                            np.zeros((0, 0)))
    layout = EstimateLayout.from_dict(state.layout)
    got = session.execute(
        select(StreamEstimate.t_s, StreamEstimate.n, StreamEstimate.packed)
        .where(StreamEstimate.recording_id == recording.id,
               StreamEstimate.design_id == state.design_id)
        .order_by(StreamEstimate.window)
    ).all()
    t = np.array([r[0] for r in got], float)
    n = np.array([r[1] for r in got], float)
    values = layout.unpack([r[2] for r in got]) if got else np.zeros((0, layout.width))
    window_s = state.window * float(recording.dt_s)
    if len(got) > max_points > 0:
        per = math.ceil(len(got) / max_points)
        starts = np.arange(0, len(got), per)
        weights = np.add.reduceat(n, starts)
        values = np.add.reduceat(values * n[:, None], starts, axis=0) / weights[:, None]
        t = t[starts]
        window_s *= per
    return StreamSeries(recording, state.design_id, layout, window_s, int(state.n_samples), t,
                        values)
