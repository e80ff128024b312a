"""Stream estimation: the reduced-order steady-state Kalman filter over a recording.

Each recording is filtered at its full rate with the engine type's active design (V*, the
design model's sensors, health parameters and noise; docs/math.md sections 2-3):

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

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import delete, insert, select
from sqlalchemy.orm import Session

from app.errors import NotFound
from app.models import Engine, EstimatorDesign, StreamChunk, StreamRecording
from app.models.base import utcnow
from app.models.estimates import EstimateLayout
from app.models.stream_estimates import StreamEstimate, StreamFilterState
from app.services import common
from app.services.designs import service as designs
from app.services.streams import calibration, recordings, samples
from app.services.streams.estimator import (
    StreamEstimationError,
    StreamEstimator,
    estimator_for,
)
from app.services.streams.run import (
    Carry,
    filter_inputs,
    filter_piece,
    recording_start,
    window_means,
)
from app.services.trends import health as health_view
from estimation.stream_filter import noise_scale

WINDOW_S = 1.0  # stored window length (seconds of recording)
PIECE = 65_536  # samples filtered per pass (bounds memory; aligned on windows)

Progress = Callable[[float, str | None], None]


def _carry_of(state: Mapping[str, Any]) -> Carry:
    anchor = state.get("anchor")
    return Carry(np.asarray(state["x"], float), np.asarray(state["u_prev"], float),
                 None if anchor is None else np.array(anchor, float),  # null: NaN
                 int(state.get("switches", 0)), float(state.get("ti", 0.0)), state.get("plant"))


def _json_floats(values: np.ndarray) -> list[float | None]:
    """Floats as JSON takes them: a condition a recording does not carry (a single-point
    type's) is NaN, stored as null."""
    return [v if np.isfinite(v) else None for v in np.asarray(values, float).tolist()]


def _initial_x(session: Session, recording: StreamRecording, design_id: int, n: int,
               nx: int) -> list[float]:
    """x_hat before the first sample (``run.recording_start``): the tuners at the end of the
    engine's previous recording under the design, spool states at zero deviation."""
    previous = session.scalar(
        select(StreamFilterState)
        .where(StreamFilterState.engine_id == recording.engine_id,
               StreamFilterState.design_id == design_id,
               StreamFilterState.started_at < recording.started_at)
        .order_by(StreamFilterState.started_at.desc())
        .limit(1)
    )
    end = None if previous is None else previous.state.get("x_end")
    return recording_start(n, nx, 0, end).x.tolist()


def estimate_one(
    session: Session, data_dir: Path, recording: StreamRecording, design: EstimatorDesign,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Bring one recording's estimates under ``design`` up to its last received sample. A
    recording whose samples the retention removed keeps the estimates it has."""
    if recording.samples_removed_at is not None:
        return {"recording_id": recording.id, "samples": 0, "windows": 0,
                "message": "samples removed by the retention: estimates kept as they are"}
    est = estimator_for(session, design, recording.signals)
    state_row = session.scalar(
        select(StreamFilterState).where(StreamFilterState.recording_id == recording.id,
                                        StreamFilterState.design_id == design.id)
    )
    dt = float(recording.dt_s)
    W = max(1, round(WINDOW_S / dt))
    if state_row is not None and (state_row.layout != est.layout.to_dict()
                                  or not _same_noise(state_row, est, dt)):
        session.delete(state_row)  # another sensor set, or another filter: start over
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
                   "x_end": x0, "x_initial": x0, "noise_interval_s": est.noise_interval_s},
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
    table = samples.read_from(data_dir, recording, chunks, start)
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
        cond, dy, du = filter_inputs(est, part)
        S = part.num_rows
        capture = restart - 1 - (start + p0)
        rows, carry, got = filter_piece(est, dt, cond, dy, du, carry,
                                        capture if 0 <= capture < S else None)
        if got is not None:
            at_restart = got
        starts, counts, means = window_means(rows, W)
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
                     anchor=None if at_restart.anchor is None else _json_floats(at_restart.anchor),
                     switches=at_restart.switches, plant=at_restart.plant)
        if est.bias is not None:
            state["ti"] = at_restart.ti
        state_row.restart_sample = restart
    state["x_end"] = carry.x.tolist()
    state_row.state = state
    state_row.n_samples = N
    state_row.n_segments = carry.switches
    state_row.updated_at = utcnow()
    session.flush()
    return {"recording_id": recording.id, "samples": N - start, "windows": n_windows,
            "segments": carry.switches}


def _same_noise(state_row: StreamFilterState, est: StreamEstimator, dt: float) -> bool:
    """Whether the stored estimates were filtered with the sensor noise ``est`` takes at this
    interval (a design calibrated for streams since holds R at the calibration's interval,
    ``estimator.calibrated_interval``; a state from before says nothing: R per sample)."""
    stored = state_row.state.get("noise_interval_s")
    return noise_scale(dt, stored) == noise_scale(dt, est.noise_interval_s)


def estimate_held(
    session: Session, data_dir: Path, design: EstimatorDesign,
    progress: Progress | None = None,
) -> list[int]:
    """Estimate again, from their first sample, the design's recordings whose stored estimates
    were filtered with another sensor noise than the design's estimator now takes (after a
    stream calibration is stored: recordings at another rate than the calibration's), and the
    later recordings of their engines whose starting tuners changed; their ids."""
    rows = session.scalars(
        select(StreamFilterState).where(StreamFilterState.design_id == design.id)
        .order_by(StreamFilterState.engine_id, StreamFilterState.started_at)
    ).all()
    stale = []
    for row in rows:
        recording = session.get(StreamRecording, row.recording_id)
        if recording is None or recording.samples_removed_at is not None:
            continue  # samples removed by the retention: its estimates stay
        est = estimator_for(session, design, recording.signals)
        if not _same_noise(row, est, float(recording.dt_s)):
            stale.append(recording)
    done: list[int] = []
    for k, recording in enumerate(stale):
        if recording.id in done:
            continue  # estimated again as a later recording of its engine
        estimate_one(session, data_dir, recording, design)
        done += [recording.id, *_carry_forward(session, data_dir, recording, design)]
        if progress is not None:
            progress((k + 1) / len(stale), f"estimating again recording {recording.id} "
                     "with the calibrated filter")
    return done


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
        if other is None or other.samples_removed_at is not None:
            continue  # samples removed by the retention: its estimates stay
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
    # What the 1-sigma is (``calibrated``): calibrated, uncalibrated (the design has no stream
    # calibration) or sensors (the recording lacks a sensor the calibration had); the health
    # parameters and tuners the calibration finds unobservable (nulls).
    uncertainty: str = "uncalibrated"
    unobservable: tuple[str, ...] = ()
    tuners_unobservable: tuple[str, ...] = ()


def calibrated(
    session: Session, design_id: int, layout: EstimateLayout, values: np.ndarray
) -> tuple[np.ndarray, str, tuple[str, ...], tuple[str, ...]]:
    """Stored windows [n, width] with the design's stream calibration
    (``calibration.design_calibration``) applied as the engine trend applies the snapshot one
    (``trends.health.apply``: the calibrated level and tuners, their honest 1-sigma, the
    unobservable ones NaN): (values, what the sigma is, unobservable health parameters and
    tuners). Without a calibration, or for a recording lacking a sensor it was fitted with,
    the values as stored and the filter's own sigma."""
    calib = calibration.design_calibration(session, design_id)
    if calib is None:
        return values, "uncalibrated", (), ()
    if set(calib.source.get("sensors", ())) - set(layout.sensors):
        return values, "sensors", (), ()
    out, meta = health_view.apply(values, layout.slices(), tuple(layout.health), calib,
                                  "level", tuner_names=tuple(layout.tuners))
    return out, "calibrated", meta.unobservable, meta.tuners_unobservable


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
    values, band, unobservable, tuners_unobservable = calibrated(session, state.design_id,
                                                                 layout, values)
    window_s = state.window * float(recording.dt_s)
    if len(got) > max_points > 0:
        per = math.ceil(len(got) / max_points)
        starts = np.arange(0, len(got), per)
        weights = np.add.reduceat(n, starts)
        values = np.add.reduceat(values * n[:, None], starts, axis=0) / weights[:, None]
        t = t[starts]
        window_s *= per
    return StreamSeries(recording, state.design_id, layout, window_s, int(state.n_samples), t,
                        values, band, unobservable, tuners_unobservable)
