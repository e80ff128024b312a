"""A stored design ready to filter streams (``StreamEstimator``): the design model restricted to
the sensors a recording carries, V*, noise, the engine schedule and the gains per anchor
condition (cached; the numerics are ``estimation.stream_filter``).

Trims come as the snapshot pipeline takes them (``snapshots.estimator``): from the built-in
engine's schedule for a model linearised from it; from an imported model schedule
(``fleethealth.model-schedule/1``) at each sample's condition, with its models interpolated
at each segment's anchor; from the model's own trims for an imported model at one operating
point (one gain). They are in the unit the samples are stored in (``stored_affine``): the
catalogue's for a catalogue signal, the model file's for an engine type's own signal.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from app.models import EngineModel, EstimatorDesign
from app.models.estimates import EstimateLayout
from app.services import units
from app.services.snapshots import estimator
from app.signals import ACTUATORS, SENSORS, SignalSpec
from estimation.bias import BiasModel
from estimation.cgekf import CgekfDesign, cgekf_design
from estimation.design import STREAM_FILTERS
from estimation.engine.health import HEALTH_NAMES
from estimation.engine.schedule import EngineSchedule
from estimation.engine.sensors import AUX_NAMES, SENSOR_NAMES
from estimation.model import LinearModel
from estimation.schedule import SCHEDULE_FORMAT, ModelSchedule
from estimation.snapshot_design import DesignResult
from estimation.stream_filter import ResampleError, SegmentGain, segment_gain

# Re-schedule box and gain lattice, in stored column order (alt ft, Mach, dTamb K, power %).
TOLERANCE = np.array([1000.0, 0.02, 2.0, 2.0])
# Noise when a design document does not carry it (per sample of the design model).
DEFAULT_Q_STD = 0.01
DEFAULT_QH_STD = 0.01

BIAS_KEY = "transient_bias"  # the design result's key of its bias model (docs/math.md section 7)
CALIBRATION_KEY = "stream_uncertainty"  # the design result's key of its stream calibration

STORED: dict[str, SignalSpec] = {s.name: s for s in SENSORS + ACTUATORS}


class StreamEstimationError(RuntimeError):
    """A design or recording the stream filter cannot run."""


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
    bias: BiasModel | None = None  # transient bias compensation, for the sensors in use
    stream_filter: str = STREAM_FILTERS[0]
    model_schedule: ModelSchedule | None = None  # an imported model schedule (not built-in)
    # The sample interval R holds at (``calibrated_interval``; None: R per sample at any rate).
    noise_interval_s: float | None = None
    _gains: dict[tuple[Any, ...], SegmentGain] = field(default_factory=dict)
    _cgekf: dict[float, tuple[CgekfDesign, np.ndarray]] = field(default_factory=dict)

    @property
    def nx(self) -> int:
        return self.model.n_states

    @property
    def n(self) -> int:
        return self.model.n_states + int(self.vstar.shape[0])

    def snapped(self, anchor: np.ndarray) -> tuple[float, ...]:
        """The lattice point the gain of an anchor condition is computed at."""
        if self.schedule is None and self.model_schedule is None:
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
        elif self.model_schedule is not None:
            # (alt, Mach, dTamb, power): the stored column order is the schedule's; the sensor
            # noise interpolated there too, as the snapshot pipeline takes it
            at = self.model_schedule.model_at(key)
            at = at.select_sensors(model.sensor_names).select_health(model.health_names)
            model = at.select_aux(model.aux_names)
        R_regions = None if self.bias is None else {
            r: self.bias.covariance(r, model.R) for r in self.bias.regions()}
        try:
            out = segment_gain(model, self.vstar, self.Vp, self.Q, self.Qh, dt, R_regions,
                               self.noise_interval_s)
        except ResampleError as e:
            raise StreamEstimationError(str(e)) from e
        self._gains[(*key, dt)] = out
        return out

    def x_ref(self) -> np.ndarray:
        """Reference values of the design model's states for the transient index: their trims
        in the model (corrected, at the model's condition when there is a schedule)."""
        model = self.model
        if self.schedule is None:
            return np.array([model.trim.get(n, math.nan) for n in model.state_names])
        # sea-level static take-off, corrected (seed 004: reference state values)
        return self._corrected_states(np.array([[0.0, 0.0, 100.0, 0.0]]))[0]

    def _corrected_states(self, cond_sched: np.ndarray) -> np.ndarray:
        """Corrected state trims [S, nx] at conditions (alt, Mach, power, dTamb); NaN for a
        state the schedule does not trim."""
        assert self.schedule is not None
        names = self.schedule.trim_names
        t = self.schedule.interpolate("trim_corrected", cond_sched)
        cols = [t[:, names.index(n)] if n in names else np.full(len(t), math.nan)
                for n in self.model.state_names]
        return np.column_stack(cols)

    def state_scale(self, cond: np.ndarray, x_ref: Sequence[float] | np.ndarray
                    ) -> np.ndarray | None:
        """s [S, nx] of ``estimation.bias.filter_compensated``: corrected state trims at the
        samples' conditions [S, 4] over ``x_ref`` (None: fixed trims, s = 1)."""
        if self.schedule is None or not len(x_ref):
            return None
        s = self._corrected_states(cond[:, [0, 1, 3, 2]]) / np.asarray(x_ref)
        return np.where(np.isfinite(s), s, 1.0)
    def cgekf(self, dt: float) -> tuple[CgekfDesign, np.ndarray]:
        """The constant-gain EKF of this design at sample interval ``dt`` (seed 001: one gain
        at ground maximum power, the design's V*, Q and Qh, per sample scaled with dt) and
        the 1-sigma [q | h | z] of its a-posteriori covariance."""
        # A whole-flight upload's interval comes from its time stamps (0.05 s to a few parts in
        # 1e15), a live recording's is declared: the same filter for both (the Euler step and
        # the gain take dt as it is, where the linear filter's resampling treats it as equal).
        dt = float(f"{dt:.12g}")
        cached = self._cgekf.get(dt)
        if cached is not None:
            return cached
        model = self.model
        turbo = list(HEALTH_NAMES[:10])
        cols = [turbo.index(h) for h in model.health_names]
        m = self.vstar.shape[0]
        vstar = np.zeros((m, len(turbo)))
        vstar[:, cols] = self.vstar
        ratio = dt / model.dt
        Qh = np.zeros((len(turbo), len(turbo)))
        Qh[np.ix_(cols, cols)] = self.Qh * ratio
        design = cgekf_design(model.sensor_names, self.layout.tuners, model.aux_names, dt=dt,
                              vstar=vstar, Q=self.Q * ratio, Qh=Qh,
                              noise_interval_s=self.noise_interval_s)
        P = design.gain.P_post
        nx = self.nx
        Pq = P[nx:, nx:]
        F = design.reduced.F
        sigma = np.sqrt(np.maximum(np.concatenate([
            np.diag(Pq), np.diag(self.Vp @ Pq @ self.Vp.T), np.diag(F @ P @ F.T)
        ]), 0.0))
        self._cgekf[dt] = (design, sigma)
        return design, sigma

    def trims(self, cond: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sensor and actuator trims [S, ny], [S, nu] in stored units at conditions [S, 4]
        (stored column order alt, Mach, dTamb, power)."""
        model = self.model
        if self.schedule is None:
            return self._own_trims(cond)
        ys = [(s.name, s.unit) for s in model.sensors]
        us = [(s.name, s.unit) for s in model.inputs]
        t = self.schedule.trims_at(cond[:, [0, 1, 3, 2]])
        raw_y = np.stack([t[n] for n, _ in ys], axis=1)
        raw_u = np.stack([t[n] for n, _ in us], axis=1) if us else np.zeros((len(cond), 0))
        tmpl = self.schedule.template
        units_of = {s.name: s.unit for s in (*tmpl.sensors, *tmpl.inputs)}
        ay = np.array([_stored_affine(n, units_of[n]) for n, _ in ys]).reshape(-1, 2)
        au = np.array([_stored_affine(n, units_of[n]) for n, _ in us]).reshape(-1, 2)
        return raw_y * ay[:, 0] + ay[:, 1], raw_u * au[:, 0] + au[:, 1]

    def _own_trims(self, cond: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``trims`` of an imported model: the model schedule's at each condition, else the
        model's own (one operating point), into the stored units as snapshots take them."""
        model, S = self.model, cond.shape[0]
        if self.model_schedule is not None:
            t = self.model_schedule.trims_at(cond)
            raw_y = np.stack([t[n] for n in model.sensor_names], axis=1)
            raw_u = (np.stack([t[n] for n in model.input_names], axis=1) if model.inputs
                     else np.zeros((S, 0)))
        else:
            raw_y = np.broadcast_to(
                np.array([model.trim.get(n, math.nan) for n in model.sensor_names]),
                (S, model.n_sensors))
            raw_u = np.broadcast_to(
                np.array([model.trim.get(n, math.nan) for n in model.input_names]),
                (S, model.n_inputs))
        ya, yb = estimator.stored_affine(model.sensors)
        ua, ub = estimator.stored_affine(model.inputs)
        return raw_y * ya + yb, raw_u * ua + ub


_ESTIMATORS: dict[tuple[Any, ...], StreamEstimator] = {}


def _document_key(*documents: Any) -> str:
    text = json.dumps(documents, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def estimator_for(
    session: Session, design: EstimatorDesign, signals: Sequence[str]
) -> StreamEstimator:
    """The stream estimator of a stored design for a recording carrying ``signals``: the
    design's sensors that the recording has (at least one)."""
    row = session.get(EngineModel, design.engine_model_id)
    if row is None:
        raise StreamEstimationError(f"design {design.id}: its engine model is missing")
    return stream_estimator(design, row, signals)


def stream_estimator(
    design: EstimatorDesign, row: EngineModel, signals: Sequence[str]
) -> StreamEstimator:
    """``estimator_for`` of a design and its engine model (stored or not)."""
    if design.status != "ready" or design.result is None:
        raise StreamEstimationError(f"design {design.id} is not ready")
    result = design.result
    embedded = result.get("model")
    stream_filter = result.get("stream_filter") or (design.spec or {}).get(
        "stream_filter", STREAM_FILTERS[0])
    if stream_filter not in STREAM_FILTERS:
        raise StreamEstimationError(
            f"design {design.id}: stream_filter must be one of {list(STREAM_FILTERS)}, "
            f"found {stream_filter!r}")
    sched = estimator.builtin_schedule() if row.source == "builtin" else None
    scheduled = row.source != "builtin" and row.format == SCHEDULE_FORMAT
    key = (design.id, _document_key(result, row.content if scheduled or not isinstance(
        embedded, Mapping) else None), tuple(signals), id(sched), stream_filter)
    cached = _ESTIMATORS.get(key)
    if cached is not None:
        return cached
    model = LinearModel.from_dict(embedded if isinstance(embedded, Mapping) else row.content)
    doc = DesignResult.from_document(result)
    if doc.sensors is not None:
        model = model.select_sensors(list(doc.sensors))
    present = set(signals)
    used = [s for s in model.sensor_names if s in present]
    if not used:
        raise StreamEstimationError(
            f"the recording carries none of design {design.id}'s sensors {model.sensor_names}"
        )
    model = model.select_sensors(used)
    if doc.vstar is None:
        raise StreamEstimationError(f"design {design.id} has no V* (vstar)")
    vstar = doc.vstar
    nx, p = model.n_states, model.n_health
    Q = doc.Q if doc.Q is not None else np.eye(nx) * DEFAULT_Q_STD**2
    Qh = doc.Qh if doc.Qh is not None else np.eye(p) * DEFAULT_QH_STD**2
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
    bias = None
    stored_bias = result.get(BIAS_KEY)
    if isinstance(stored_bias, Mapping):
        try:
            bias = BiasModel.from_dict(stored_bias).for_sensors(model.sensor_names)
        except ValueError as e:
            raise StreamEstimationError(f"design {design.id}: its transient bias model: {e}") from e
    if stream_filter == "cgekf":
        _check_cgekf(design.id, row.source, model)
    model_schedule = ModelSchedule.from_dict(row.content) if scheduled else None
    if model_schedule is not None:
        missing = [n for n in (*model.sensor_names, *model.input_names)
                   if n not in model_schedule.trim_names]
        if missing:
            raise StreamEstimationError(
                f"design {design.id}: the model schedule trims none of the signals {missing}")
    est = StreamEstimator(design.id, model, vstar, Vp, Q, Qh, sched, layout, bias=bias,
                          stream_filter=stream_filter, model_schedule=model_schedule,
                          noise_interval_s=calibrated_interval(result.get(CALIBRATION_KEY)))
    if len(_ESTIMATORS) > 32:
        _ESTIMATORS.clear()
    _ESTIMATORS[key] = est
    return est


def calibrated_interval(stored: Any) -> float | None:
    """The sample interval a design's sensor noise R holds at on streams: that of its stored
    stream calibration (``streams.calibration``), whose bands hold for the filter's gain per
    second at the rate it was fitted at; None (R per sample at every rate) uncalibrated.

    A stream estimate errs by the model's own error far more than by the sensor noise, and that
    error persists over seconds. With R per sample, a 10 Hz recording's gain took five times
    the 2 Hz calibration's information per second, chased that error and left its bands
    (bench_stream_uncertainty --score-rate-hz 10)."""
    source = stored.get("source") if isinstance(stored, Mapping) else None
    rate = source.get("rate_hz") if isinstance(source, Mapping) else None
    if not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0:
        return None
    return 1.0 / float(rate)


def _check_cgekf(design_id: int, source: str, model: LinearModel) -> None:
    """The constant-gain EKF runs the built-in nonlinear engine: a design of another engine
    model, or with signals that engine does not have, cannot choose it."""
    why = None
    if source != "builtin":
        why = "its engine model is not the built-in engine"
    elif model.n_states != 4:
        why = f"its model has {model.n_states} states, the built-in engine 4"
    else:
        odd = ([h for h in model.health_names if h not in HEALTH_NAMES[:10]]
               + [s for s in model.sensor_names if s not in SENSOR_NAMES]
               + [a for a in model.aux_names if a not in AUX_NAMES])
        if odd:
            why = f"the built-in engine's filter has no {odd} (component health only)"
    if why is not None:
        raise StreamEstimationError(f"design {design_id} chooses the cgekf stream filter but {why}")
