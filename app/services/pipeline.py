"""The estimation pipeline: snapshots -> tuner filter -> estimates, shift detection, isolation.

After an upload commits, each affected engine's snapshot filter (``estimation.snapshot``,
MATH.md section 8) continues from its stored state under the engine type's active design. A
record older than the last processed one re-runs the engine from the newest checkpoint before
it: estimates and checkpoints from there on are deleted and recomputed, so a re-run writes the
same rows as an uninterrupted run (the arithmetic per record does not depend on how records are
grouped into runs, and a state restored from JSON is bit-exact). Events detected again are
updated in place (an acknowledgement and comments survive); events not detected again go.
Checkpoints every ``CHECKPOINT_EVERY`` records bound a re-run: on the demo fleet (1460 records
an engine) a late record near the end re-ran 180 records in 0.27 s against 3 s from the start.

Between a reset and an alarm the detector's baselines, level statistics and WSSR are computed
for a run of records at once (``estimation.shift_scan``, the same sums as one record alone),
and only the CUSUM and its running mean go record by record (``_wssr_filled``; byte for byte
``detect_step`` record by record, tests/app/test_detection_replay.py).

Engines go in batches of up to ``BATCH`` (``estimate_engines``): a batch's records are read at
once (from memory when the upload that stored them committed in this process, else one query;
``estimate_rows``), filtered and derived for all engines per chunk of records, and their
estimate rows streamed into one binary COPY while the filter computes. On 100,000 records of
100 engines this job takes about 2 s (bench/bench_ingest.py; it took 11.5 s before these
changes, mostly per-engine queries and per-row writes).

Per record the pipeline stores q_hat, h_hat = V*^+ q_hat and z_hat = G_z V*^+ q_hat with their
1-sigma (from the filter covariance P), the innovation per sensor, and the WSSR of every
library fault (seed 002 eq. 21-23) for the tuner change against the baseline.

Detection (MATH.md section 4, last paragraph): a chi-squared CUSUM (``estimation.detection``
design) runs on the tuner estimate against its baseline, s = (q_hat - q_0)^T P^-1 (q_hat - q_0)
with the filter covariance P; q_0 is the mean of ``N_BASE`` tuner estimates ending ``GAP``
records before the current one. The estimates are correlated from record to record, so the
run-length theory only orders the settings; the statistic is rescaled by its running
in-control mean (model error raises it above m) and the false-alarm rate is measured on
simulated fleets (bench/bench_detection.py, tests/app/test_detection_replay.py). After an
alarm the ``N_CONFIRM`` records that follow are fitted in sensor space: each record against
the baseline tuners, r_j = dy_j - G_y,j V*^+ q_0, and each library fault's signature at the
record's own condition (health columns through G_y, actuator biases through G_u, so a fuel-flow
or variable-geometry bias is a fault like any other) give f_i and WSSR_i of seed 002 eq. 21-23
over all those records (``accumulate_sensor_fit``: four sums a fault). The event is an
``isolated_fault`` when the smallest WSSR is below the chi-squared quantile (times
``SENSOR_WSSR_MARGIN`` for the linearisation error) and the fitted magnitude is plausible, a
``shift`` when the change is still improbable under no change, else dropped. Then the
baseline restarts. A maintenance action restarts the baseline too and widens the filter
covariance (the health may jump at a shop visit or wash); an alarm pending then is isolated on
the records there are, with the covariance from before the action.

On the built-in engine the trims are solved per record by the steady-state solver (the
interpolated ones are off by up to ~0.5 % of a pressure, as much as a fault's signature) and
the sensor noise is constant in sensor units (so in percent of trim it grows with altitude).
On the demo fleet this finds 5 of its 6 detectable faults and names each correctly, with no
stored false alarm (bench/bench_detection.py).
"""

from __future__ import annotations

import functools
import gc
import logging
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from scipy import stats
from sqlalchemy import and_, delete, func, insert, or_, select
from sqlalchemy.orm import Session

from app.models import Engine, EngineModel, EstimatorDesign, MaintenanceAction, Snapshot
from app.models.base import utcnow
from app.models.estimates import (
    VALUE_DTYPE,
    Estimate,
    EstimateLayout,
    Event,
    FilterCheckpoint,
    FilterState,
)
from app.models.ingest import ACTUATORS, OPERATING_CONDITION, SENSORS, SignalSpec
from app.services import estimate_rows, fresh_records, units
from estimation import isolation
from estimation.detection import CusumDesign, design_cusum
from estimation.engine.schedule import EngineSchedule
from estimation.model import LinearModel
from estimation.shift_scan import level_scan, sliding_baselines
from estimation.snapshot import SnapshotState, snapshot_deviation, snapshot_filter

log = logging.getLogger("fleethealth.pipeline")

# Detector settings (records are snapshots; a flight gives one to three).
N_BASE = 30  # records averaged into the baseline
GAP = 15  # the baseline ends this many records before the alarm (the fault's onset)
N_CONFIRM = 20  # records between an alarm and its isolation (fitted in sensor space)
N_AVG = 10  # records averaged for the tuner change shown with an event
WARMUP = 60  # records after a start, maintenance or event before the detector arms
S_MEAN_RATE = 1.0 / 200.0  # memory of the in-control mean of the detector statistic
S_MEAN_CAP = 30.0  # samples above this many times m count as this much
DETECTOR_INPUT = "level"  # "level": q_hat against the baseline; "update": q_hat[k] - q_hat[k-1]
CUSUM_REFERENCE = 1.5  # CUSUM allowance per sample, in units of m (robust to model error)
ARL0 = 20_000.0  # mean records between false alarms of the CUSUM (theory, independent samples)
ISOLATION_LEVEL = 0.999  # WSSR quantile below which the best fault explains the change
MAGNITUDE_RANGE = (0.5, 3.0)  # fitted fault magnitudes that count as that fault (x nominal)
SHIFT_LEVEL = 1e-6  # an unexplained change must be this improbable under no change
ISOLATE_IN = "sensors"  # "sensors": records after the alarm fitted in sensor space; "tuners"
SENSOR_ISOLATION_LEVEL = 0.999  # WSSR quantile (sensor space) below which a fault explains it
# Linearisation error (health several percent from the trim) leaves a WSSR per sensor value
# above 1 even for the right fault: the quantile is scaled by this much.
SENSOR_WSSR_MARGIN = 1.5
# Filter settings: tuner random walk per flight (percent), fleet spread at start (percent).
WALK_STD = 0.05
FLEET_STD = 1.5
START_STD = 5.0
NEW_FLIGHT_S = 3600.0  # records further apart than this are different flights
# Sensor model error (percent of trim) added in quadrature to the sensor noise: gains
# interpolated between schedule nodes, and the linearisation of an engine several percent from
# its trim, are off by about this much.
MODEL_ERROR = 0.2
CHECKPOINT_EVERY = 256
# Records of all engines per filter call (bounds the scheduled-gain arrays, ~120 MB for the
# built-in engine): a call takes max(64, RECORD_SLOTS // engines) records of each engine.
RECORD_SLOTS = 32_768

SNAPSHOT_SIGNALS: dict[str, SignalSpec] = {s.name: s for s in SENSORS + ACTUATORS}
CONDITION_COLUMNS = tuple(s.column for s in OPERATING_CONDITION)


class PipelineError(RuntimeError):
    """A design or engine model the pipeline cannot run."""


class ScheduledGains(NamedTuple):
    """Linear model quantities at each record's operating condition (S records).

    y_trim [S, ny], u_trim [S, nu] in stored units; G_y [S, ny, p], G_u [S, ny, nu],
    G_z [S, nz, p] in percent of trim per percent.
    """

    y_trim: np.ndarray
    u_trim: np.ndarray
    G_y: np.ndarray
    G_u: np.ndarray
    G_z: np.ndarray
    noise_std: np.ndarray | None = None  # [S, ny] sensor noise, percent of y_trim (None: the
    # design model's)


Schedule = Callable[[np.ndarray], ScheduledGains]  # conditions [S, 4] -> gains


def _stored_unit(name: str, unit: str, value: float) -> float:
    """A trim value from the model's unit into the unit snapshots are stored in (NaN when the
    signal is not stored or its unit does not convert)."""
    spec = SNAPSHOT_SIGNALS.get(name)
    if spec is None:
        return math.nan
    if unit == spec.unit or not unit:
        return value
    try:
        a, b = units.affine(spec.quantity, unit, spec.unit, reference=spec.percent_reference)
    except units.UnknownUnitError:
        return math.nan
    return a * value + b


def single_point_schedule(model: LinearModel) -> Schedule:
    """An imported model at one operating point: the same gains and trims for every record."""
    G_y, G_z = model.steady_state_gains()
    G_u, _ = model.steady_state_input_gains()
    y_trim = np.array(
        [_stored_unit(s.name, s.unit, model.trim.get(s.name, math.nan)) for s in model.sensors]
    )
    u_trim = np.array(
        [_stored_unit(s.name, s.unit, model.trim.get(s.name, math.nan)) for s in model.inputs]
    )
    if not np.all(np.isfinite(y_trim)):
        missing = [s.name for s, v in zip(model.sensors, y_trim, strict=True) if not np.isfinite(v)]
        raise PipelineError(f"no trim in a stored unit for the engine model's sensors {missing}")

    def schedule(conditions: np.ndarray) -> ScheduledGains:
        S = conditions.shape[0]
        return ScheduledGains(
            np.broadcast_to(y_trim, (S, len(y_trim))),
            np.broadcast_to(u_trim, (S, len(u_trim))),
            np.broadcast_to(G_y, (S, *G_y.shape)),
            np.broadcast_to(G_u, (S, *G_u.shape)),
            np.broadcast_to(G_z, (S, *G_z.shape)),
        )

    return schedule


def _find(document: Any, key: str, depth: int = 3) -> Any:
    """``document[key]``, looked up breadth-first in nested dicts (design documents nest)."""
    if not isinstance(document, Mapping):
        return None
    if key in document:
        return document[key]
    if depth == 0:
        return None
    for value in document.values():
        found = _find(value, key, depth - 1)
        if found is not None:
            return found
    return None


def _covariance(value: Any, n: int, default_std: float) -> np.ndarray:
    if value is None:
        return np.eye(n) * default_std**2
    arr = np.asarray(value, float)
    return np.diag(arr) if arr.ndim == 1 else arr


@dataclass(frozen=True, eq=False)
class SnapshotEstimator:
    """Everything the pipeline needs of one design, ready to run."""

    design_id: int
    layout: EstimateLayout
    sensor_columns: tuple[str, ...]  # snapshot column per design sensor ("" = not stored)
    input_columns: tuple[str, ...]
    vstar: np.ndarray  # [m, p]
    Vp: np.ndarray  # V*^+ [p, m]
    Qq: np.ndarray  # [m, m] tuner random walk per flight
    P0: np.ndarray  # [m, m] start covariance
    noise_std: np.ndarray  # [ny] percent
    H: np.ndarray  # [m, n_faults] tuner change per library fault (nominal magnitude)
    S_full: np.ndarray  # [p + len(bias_inputs), n_faults] library shifts in health space and
    # in the biases of the inputs ``bias_inputs`` (those whose bias is not a health parameter)
    fault_shifts: tuple[dict[str, float], ...]
    bias_inputs: tuple[int, ...]
    schedule: Schedule
    cusum: CusumDesign
    wssr_threshold: float
    shift_threshold: float

    @property
    def m(self) -> int:
        return int(self.vstar.shape[0])

    def fault_signatures(self, G_y: np.ndarray, G_u: np.ndarray) -> np.ndarray:
        """Each library fault's sensor change (nominal magnitude) at the conditions of these
        gains: health columns through G_y [..., ny, p], actuator-bias columns through G_u
        [..., ny, nu] (MATH.md section 4, in sensor space) -> [..., ny, n_faults]."""
        p = G_y.shape[-1]
        return G_y @ self.S_full[:p] + G_u[..., list(self.bias_inputs)] @ self.S_full[p:]


@functools.lru_cache(maxsize=32)
def cusum_for(m: int) -> CusumDesign:
    """The CUSUM for m tuners at the pipeline's false-alarm rate (its design takes seconds)."""
    return design_cusum(m, arl0=ARL0, reference=CUSUM_REFERENCE * m)


def build_estimator(
    design_id: int, model: LinearModel, result: Mapping[str, Any],
    schedule: Schedule | None = None,
) -> SnapshotEstimator:
    """A runnable estimator from a design document and its engine model.

    The document gives V* (``vstar``), optionally the sensor suite (``sensors``), the fleet
    health covariance ``Ph`` and the fault library (``faults``); defaults fill the rest.
    """
    vstar_doc = _find(result, "vstar")
    if vstar_doc is None:
        raise PipelineError(f"design {design_id} has no V* (vstar)")
    sensors = _find(result, "sensors")
    if isinstance(sensors, list) and sensors and all(isinstance(s, str) for s in sensors):
        model = model.select_sensors(sensors)
    vstar = np.asarray(vstar_doc, float)
    m, p = vstar.shape
    if p != model.n_health:
        raise PipelineError(f"design {design_id}: V* has {p} columns, the model {model.n_health}")
    Vp = np.linalg.solve(vstar @ vstar.T, vstar).T  # V*^+ (seed 002 eq. 5)
    walk = np.eye(p) * WALK_STD**2
    # Engines join the service deteriorated: start from at least START_STD per parameter.
    Ph = _covariance(_find(result, "Ph"), p, FLEET_STD)
    Ph = Ph + np.diag(np.maximum(START_STD**2 - np.diag(Ph), 0.0))
    Qq = vstar @ walk @ vstar.T
    P0 = vstar @ Ph @ vstar.T

    # Fault influence in tuner space at the design point: the snapshot filter settles on the
    # R^-1-weighted least-squares tuner fit of a constant health shift (MATH.md section 4 with
    # the filter's steady state replaced by that fit; equal to V* S when m = p).
    G_y, _G_z = model.steady_state_gains()
    G_u, _ = model.steady_state_input_gains()
    # An actuator bias is a fault through its input column, unless the design's health
    # vector already carries it (then its health column is the one, counted once).
    health_lower = {n.lower() for n in model.health_names}
    bias_inputs = tuple(
        j for j, s in enumerate(model.inputs) if f"{s.name.lower()}_bias" not in health_lower
    )
    names = list(model.health_names) + [
        f"{model.inputs[j].name.lower()}_bias" for j in bias_inputs
    ]
    G_full = np.concatenate([G_y, G_u[:, list(bias_inputs)]], axis=1)
    faults_doc = result.get("faults")
    if isinstance(faults_doc, Mapping):
        faults_doc = faults_doc.get("library")
    library = isolation.faults_from_list(faults_doc if isinstance(faults_doc, list) else None)
    known = {n.lower() for n in names}
    library = tuple(f for f in library if all(k.lower() in known for k in f.shifts))
    S = isolation.signature_matrix(library, names)
    Hd = G_y @ Vp
    Rinv = 1.0 / (model.sensor_noise_std**2 + MODEL_ERROR**2)
    normal = Hd.T @ (Rinv[:, None] * Hd)
    H = np.linalg.solve(normal, Hd.T @ (Rinv[:, None] * (G_full @ S)))
    usable = np.sum(H**2, axis=0) > 1e-12
    library = tuple(f for f, ok in zip(library, usable, strict=True) if ok)
    H = H[:, usable]
    S = S[:, usable]

    layout = EstimateLayout(
        tuners=tuple(f"q{i + 1}" for i in range(m)),
        health=tuple(model.health_names),
        aux=tuple(model.aux_names),
        sensors=tuple(model.sensor_names),
        faults=tuple(f.name for f in library),
        units={
            "tuners": ["%"] * m,
            "health": ["%"] * p,
            "aux": ["%"] * model.n_aux,
            "sensors": ["%"] * model.n_sensors,
            "faults": ["1"] * len(library),
        },
    )
    sensor_columns = tuple(
        SNAPSHOT_SIGNALS[s.name].column if s.name in SNAPSHOT_SIGNALS else ""
        for s in model.sensors
    )
    # An actuator is used only where its trim converts to the stored unit.
    input_columns = tuple(
        SNAPSHOT_SIGNALS[s.name].column
        if s.name in SNAPSHOT_SIGNALS
        and np.isfinite(_stored_unit(s.name, s.unit, model.trim.get(s.name, math.nan)))
        else ""
        for s in model.inputs
    )
    return SnapshotEstimator(
        design_id=design_id,
        layout=layout,
        sensor_columns=sensor_columns,
        input_columns=input_columns,
        vstar=vstar,
        Vp=Vp,
        Qq=0.5 * (Qq + Qq.T),
        P0=0.5 * (P0 + P0.T),
        noise_std=np.sqrt(np.asarray(model.sensor_noise_std, float) ** 2 + MODEL_ERROR**2),
        H=H,
        S_full=S,
        fault_shifts=tuple(dict(f.shifts) for f in library),
        bias_inputs=bias_inputs,
        schedule=schedule or single_point_schedule(model),
        cusum=cusum_for(m),
        wssr_threshold=float(stats.chi2.ppf(ISOLATION_LEVEL, max(m - 1, 1))),
        shift_threshold=float(stats.chi2.isf(SHIFT_LEVEL, m)),
    )


def estimator_for_design(session: Session, design: EstimatorDesign) -> SnapshotEstimator:
    """The estimator of a stored design: the design's model (sensors and health selected) and,
    for the built-in engine, its operating-condition schedule."""
    if design.status != "ready" or design.result is None:
        raise PipelineError(f"design {design.id} is not ready")
    row = session.get(EngineModel, design.engine_model_id)
    if row is None:
        raise PipelineError(f"design {design.id}: engine model {design.engine_model_id} missing")
    embedded = design.result.get("model")
    model = LinearModel.from_dict(embedded if isinstance(embedded, Mapping) else row.content)
    schedule = None
    if row.source == "builtin":
        schedule = engine_schedule_for(model, builtin_schedule())
    return build_estimator(design.id, model, design.result, schedule)


def builtin_schedule() -> EngineSchedule:
    """The built-in engine's schedule from the data directory's cache (built on first use)."""
    from app.config import get_settings

    return _cached_schedule(str(get_settings().data_dir.resolve() / "cache"))


@functools.lru_cache(maxsize=2)
def _cached_schedule(cache_dir: str) -> EngineSchedule:
    from app.engine_cache import engine_schedule

    return engine_schedule(Path(cache_dir))


def exact_nominal_trims(
    conditions: np.ndarray, interpolated: Mapping[str, np.ndarray]
) -> dict[str, np.ndarray]:
    """Sensor and actuator trims of the nominal (healthy) built-in engine solved at each
    record's own condition (alt, mach, dtamb, power) [S, 4], in the engine's units.

    Interpolated trims are off by up to ~0.5 % of some sensors between schedule nodes, as much
    as a fault's signature; the nonlinear steady-state solve of all records of a call at once
    costs ~0.06 ms a record and leaves only the linearisation error. Every point converges on
    its own (the batched Newton drops converged rows), so a record's trim does not depend on
    which records share its call: re-runs stay bit-identical. Records outside the engine's
    envelope, or a batch the solver cannot finish, keep the ``interpolated`` trims.
    """
    from estimation.engine.errors import EngineConvergenceError
    from estimation.engine.sensors import SENSOR_NAMES
    from estimation.engine.steady import ENVELOPE, steady_state

    out = {k: np.array(v, dtype=float, copy=True) for k, v in interpolated.items()}
    if conditions.shape[0] == 0:
        return out
    lo = np.array([ENVELOPE[k][0] for k in ("alt", "mach", "dtamb", "power")])
    hi = np.array([ENVELOPE[k][1] for k in ("alt", "mach", "dtamb", "power")])
    inside = np.all(np.isfinite(conditions) & (conditions >= lo) & (conditions <= hi), axis=1)
    if not inside.any():
        return out
    c = conditions[inside]
    try:
        ss = steady_state(c[:, :3], power=c[:, 3])
    except (EngineConvergenceError, ValueError):
        log.warning("steady-state trims failed for a batch of %d records; interpolating", len(c))
        return out
    for i, name in enumerate(SENSOR_NAMES):
        if name in out:
            out[name][inside] = ss.sensors[:, i]
    for i, name in enumerate(("Wf", "VSV", "VBV")):
        if name in out and name not in SENSOR_NAMES:
            out[name][inside] = ss.u[:, i]
    return out


def engine_schedule_for(
    model: LinearModel, sched: EngineSchedule, exact_trims: bool = True
) -> Schedule:
    """Gains and trims of ``model``'s signals at each record's operating condition, from the
    built-in engine's schedule (corrected-parameter trims, MATH.md section 8). With
    ``exact_trims`` the trims are solved per record (``exact_nominal_trims``); the gains are
    interpolated (they vary slowly)."""
    tmpl = sched.template
    yi = [tmpl.sensor_names.index(n) for n in model.sensor_names]
    ui = [tmpl.input_names.index(n) for n in model.input_names]
    zi = [tmpl.aux_names.index(n) for n in model.aux_names]
    hi = [tmpl.health_names.index(n) for n in model.health_names]
    units_of = {s.name: s.unit for s in (*tmpl.sensors, *tmpl.inputs)}

    def convert(names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        a, b = np.ones(len(names)), np.zeros(len(names))
        for k, name in enumerate(names):
            spec = SNAPSHOT_SIGNALS.get(name)
            if spec is None or units_of[name] in (spec.unit, ""):
                continue
            try:
                a[k], b[k] = units.affine(
                    spec.quantity, units_of[name], spec.unit, reference=spec.percent_reference
                )
            except units.UnknownUnitError:
                a[k], b[k] = np.nan, np.nan
        return a, b

    ya, yb = convert(model.sensor_names)
    ua, ub = convert(model.input_names)
    # The built-in engine's sensor noise is a constant in sensor units (seed 001 Table 2), so
    # in percent of trim it grows with altitude: about four times larger at cruise than at
    # take-off for the pressures. Each record gets its own.
    from estimation.engine.fleet import engine_noise_std
    from estimation.engine.sensors import SENSOR_NAMES

    noise_engine = engine_noise_std()
    noise_abs = np.array([noise_engine[SENSOR_NAMES.index(n)] for n in model.sensor_names])
    noise_abs = noise_abs * np.abs(ya)

    def schedule(conditions: np.ndarray) -> ScheduledGains:
        # Snapshot columns are (alt, mach, dtamb, power); the schedule's axes (alt, mach,
        # power, dtamb).
        c = np.asarray(conditions, float)[:, [0, 1, 3, 2]]
        trims = sched.trims_at(c)
        if exact_trims:
            trims = exact_nominal_trims(np.asarray(conditions, float), trims)
        y_trim = np.stack([trims[n] for n in model.sensor_names], axis=1) * ya + yb
        u_trim = np.stack([trims[n] for n in model.input_names], axis=1) * ua + ub
        Gy = sched.interpolate("Gy", c)[:, yi][:, :, hi]
        Guy = sched.interpolate("Guy", c)[:, yi][:, :, ui]
        Gz = sched.interpolate("Gz", c)[:, zi][:, :, hi]
        noise = 100.0 * noise_abs / np.abs(y_trim)
        return ScheduledGains(y_trim, u_trim, Gy, Guy, Gz, noise)

    return schedule


# ---------------------------------------------------------------------------- detection


def initial_state(est: SnapshotEstimator) -> dict[str, Any]:
    """Pipeline state before an engine's first record."""
    return {
        "filter": SnapshotState.initial(1, est.P0).to_dict(),
        "detector": {"history": [], "S": 0.0, "pending": None},
        "last_epoch": None,
    }


@dataclass
class Detector:
    """Sequential baseline, CUSUM and isolation state of one engine (JSON round trip).

    history: the last N_BASE + GAP tuner estimates, oldest first.
    """

    history: list[list[float]]
    S: float
    pending: dict[str, Any] | None
    s_mean: float | None = None
    s_count: int = 0
    warm: int = 0

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Detector:
        s_mean = d.get("s_mean")
        return cls([list(map(float, q)) for q in d["history"]], float(d["S"]), d.get("pending"),
                   None if s_mean is None else float(s_mean), int(d.get("s_count", 0)),
                   int(d.get("warm", 0)))

    def to_dict(self) -> dict[str, Any]:
        return {"history": [list(q) for q in self.history], "S": self.S, "pending": self.pending,
                "s_mean": self.s_mean, "s_count": self.s_count, "warm": self.warm}

    def reset(self) -> None:
        self.history, self.S, self.pending, self.warm = [], 0.0, None, 0

    def baseline(self) -> np.ndarray | None:
        if len(self.history) < N_BASE + GAP:
            return None
        return np.mean(np.asarray(self.history[:N_BASE]), axis=0)


class EventDraft(NamedTuple):
    seq: int
    epoch: float
    kind: str
    fault: str | None
    magnitude: float | None
    statistic: float
    wssr: dict[str, float]
    shift: dict[str, Any]


def wssr_all(shift: np.ndarray, P: np.ndarray, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """WSSR_i and f_i of every fault for one shift (seed 002 eq. 21-23), solving with P."""
    wssr, f, _ = wssr_and_distance(shift, P, H)
    return wssr, f


def wssr_and_distance(
    shift: np.ndarray, P: np.ndarray, H: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """``wssr_all`` and the shift's squared Mahalanobis distance shift^T P^-1 shift (the
    detector's level statistic) from one solve with P."""
    X = np.linalg.solve(P, np.column_stack([shift, H]))
    Pinv_s, Pinv_H = X[:, 0], X[:, 1:]
    distance = float(shift @ Pinv_s)
    if H.shape[1] == 0:
        return np.zeros(0), np.zeros(0), distance
    norm2 = np.einsum("ij,ij->j", H, Pinv_H)  # H_i^T P^-1 H_i
    proj = H.T @ Pinv_s  # H_i^T P^-1 q
    f = proj / norm2
    return np.maximum(distance - proj * f, 0.0), f, distance


def tuner_update_statistic(
    q: np.ndarray, q_prev: np.ndarray, P: np.ndarray, P_prior: np.ndarray
) -> float:
    """s = dq^T (P_prior - P)^-1 dq for the tuner update dq = q - q_prev = K nu.

    Under no change the innovations nu are white, so dq ~ N(0, K S K^T) = N(0, P_prior - P)
    independently from record to record: chi-squared with m degrees of freedom, the
    independent samples the CUSUM's run-length theory assumes (estimation/detection.py).
    """
    C = P_prior - P
    C = 0.5 * (C + C.T)
    dq = q - q_prev
    try:
        return float(dq @ np.linalg.solve(C, dq))
    except np.linalg.LinAlgError:
        return 0.0


class RecordObservation(NamedTuple):
    """One record's measurement, for isolation in sensor space.

    dy [ny] (percent of trim, NaN = missing), G_y [ny, p], signatures [ny, n_faults] (the
    sensor change of each library fault at nominal magnitude, health and actuator-bias
    columns of the record's own gains), var [ny] (noise variance, percent^2).
    """

    dy: np.ndarray
    G_y: np.ndarray
    signatures: np.ndarray
    var: np.ndarray


def accumulate_sensor_fit(
    est: SnapshotEstimator, pending: dict[str, Any], obs: RecordObservation
) -> None:
    """Add one record to the pending alarm's least-squares fit of each fault in sensor space.

    With r_j = dy_j - G_y,j V*^+ q_0 (the record against the baseline tuners q_0) and g_ij the
    signature of fault i at record j, the weighted fit over the records j after the alarm is
    f_i = b_i / a_i and WSSR_i = c - b_i^2 / a_i (seed 002 eq. 21-23 with H_i the stacked
    g_ij and the noise covariance diagonal), from the sums a_i = sum g^T W g,
    b_i = sum g^T W r, c = sum r^T W r and the count n of sensor values: four numbers a fault
    carry the fit, so the detector state stays small.
    """
    base = np.asarray(pending["baseline"], float)
    r = obs.dy - obs.G_y @ (est.Vp @ base)
    present = np.isfinite(r)
    if not present.any():
        return
    w = np.where(present, 1.0 / obs.var, 0.0)
    r = np.where(present, r, 0.0)
    g = np.where(present[:, None], obs.signatures, 0.0)
    a = np.einsum("i,if,if->f", w, g, g)
    b = np.einsum("i,if,i->f", w, g, r)
    fit = pending.setdefault("fit", {"a": [0.0] * len(a), "b": [0.0] * len(b), "c": 0.0,
                                     "n": 0})
    fit["a"] = (np.asarray(fit["a"]) + a).tolist()
    fit["b"] = (np.asarray(fit["b"]) + b).tolist()
    fit["c"] = float(fit["c"] + np.sum(w * r * r))
    fit["n"] = int(fit["n"] + present.sum())


def _isolate(
    est: SnapshotEstimator, pending: Mapping[str, Any], change: np.ndarray, P: np.ndarray
) -> EventDraft | None:
    """The pending alarm's event: isolated in sensor space when the records after the alarm
    were accumulated (``accumulate_sensor_fit``), else on the tuner change."""
    fit = pending.get("fit")
    if ISOLATE_IN == "sensors" and fit is not None and fit["n"] > 1:
        a, b, c, n = np.asarray(fit["a"]), np.asarray(fit["b"]), float(fit["c"]), fit["n"]
        ok = a > 0
        f = np.where(ok, b / np.where(ok, a, 1.0), 0.0)
        wssr = np.where(ok, np.maximum(c - b * f, 0.0), c)
        return _event(est, pending, change, wssr, f, P,
                      SENSOR_WSSR_MARGIN * float(stats.chi2.ppf(SENSOR_ISOLATION_LEVEL, n - 1)),
                      c, float(stats.chi2.isf(SHIFT_LEVEL, n)))
    wssr, f = wssr_all(change, P, est.H)
    distance = float(change @ np.linalg.solve(P, change))
    return _event(est, pending, change, wssr, f, P, est.wssr_threshold, distance,
                  est.shift_threshold)


def detect_step(
    est: SnapshotEstimator, det: Detector, seq: int, epoch: float, q: np.ndarray,
    P: np.ndarray, q_prev: np.ndarray, P_prior: np.ndarray, reset: bool,
    obs: RecordObservation | None = None,
) -> tuple[np.ndarray, EventDraft | None]:
    """One record through the detector: WSSR per fault against the baseline (NaN without one),
    and the event when an alarm's isolation is due."""
    nan = np.full(est.H.shape[1], np.nan)
    early: EventDraft | None = None
    if reset:
        if det.pending is not None and det.history:
            # The engine left service (or was maintained) before the alarm's isolation was
            # due: isolate on the records there are.
            pending = det.pending
            recent = det.history[-min(N_AVG, len(det.history)) :]
            change = np.mean(np.asarray(recent), axis=0) - np.asarray(pending["baseline"])
            # This record's P is already widened by the maintenance action: isolate with the
            # covariance of the records the change comes from.
            P_last = np.asarray(pending.get("P", P), float)
            early = _isolate(est, pending, change, P_last)
        det.reset()
    base_before = det.baseline()
    det.warm += 1
    det.history.append(q.tolist())
    if len(det.history) > N_BASE + GAP:
        del det.history[0]
    if det.pending is not None:
        pending = det.pending
        pending["wait"] -= 1
        pending["P"] = P.tolist()
        if obs is not None:
            accumulate_sensor_fit(est, pending, obs)
        base = np.asarray(pending["baseline"])
        wssr = wssr_all(q - base, P, est.H)[0]
        if pending["wait"] > 0:
            return wssr, None
        change = np.mean(np.asarray(det.history[-N_AVG:]), axis=0) - base
        draft = _isolate(est, pending, change, P)
        det.reset()
        return wssr, draft
    if DETECTOR_INPUT == "level":
        if base_before is None:
            det.S = 0.0
            return nan, early
        wssr_now, _f, s = wssr_and_distance(q - base_before, P, est.H)
    else:
        s = tuner_update_statistic(q, q_prev, P, P_prior)
        wssr_now = None
    # The statistic's in-control mean is m for a perfect model; model error (interpolated
    # trims, nonlinearity) makes it larger. Its running in-control mean rescales it, so the
    # CUSUM responds to a change against the engine's own normal, not to a steady mismatch.
    m = est.m
    if det.s_mean is None:
        det.s_mean = float(m)
    scaled = s * m / max(det.s_mean, m)
    if det.S == 0.0:
        # A running mean that starts as a plain average (fast) and keeps S_MEAN_RATE memory;
        # capped samples so a real change does not teach the detector to ignore it.
        det.s_count += 1
        rate = max(1.0 / det.s_count, S_MEAN_RATE)
        det.s_mean += (min(s, S_MEAN_CAP * m) - det.s_mean) * rate
    if base_before is None or det.warm < WARMUP:
        det.S = 0.0  # no baseline yet (start-up, or after a reset): nothing to compare with
        return nan, early
    det.S = max(0.0, det.S + scaled - m - est.cusum.reference)
    if det.S > est.cusum.threshold:
        det.pending = {"seq": seq, "epoch": epoch, "statistic": det.S, "wait": N_CONFIRM,
                       "baseline": base_before.tolist(), "P": P.tolist()}
        if obs is not None:
            accumulate_sensor_fit(est, det.pending, obs)
        det.S = 0.0
    if wssr_now is None:
        wssr_now = wssr_all(q - base_before, P, est.H)[0]
    return wssr_now, early


def _event(
    est: SnapshotEstimator, pending: Mapping[str, Any], change: np.ndarray, wssr: np.ndarray,
    f: np.ndarray, P: np.ndarray, wssr_threshold: float, distance: float,
    shift_threshold: float,
) -> EventDraft | None:
    """The event of an alarm, or None when the change is too small to matter.

    Isolated when the smallest WSSR is consistent with its fault and the fitted magnitude is
    a plausible fault (MAGNITUDE_RANGE times the library's nominal shift); an unexplained
    shift when the change is still large (its Mahalanobis distance under P exceeds
    ``est.shift_threshold``); otherwise the alarm is dropped (model error, not a fault).
    """
    names = est.layout.faults
    best = int(np.argmin(wssr)) if len(names) else None
    lo, hi = MAGNITUDE_RANGE
    isolated = (
        best is not None and wssr[best] <= wssr_threshold and lo <= f[best] <= hi
    )
    if not isolated and distance < shift_threshold:
        return None
    h_change = est.Vp @ change
    fault_shift = {}
    if isolated and best is not None:
        fault_shift = {k: round(float(v * f[best]), 4) for k, v in est.fault_shifts[best].items()}
    return EventDraft(
        seq=int(pending["seq"]),
        epoch=float(pending["epoch"]),
        kind="isolated_fault" if isolated else "shift",
        fault=names[best] if isolated and best is not None else None,
        magnitude=float(f[best]) if isolated and best is not None else None,
        statistic=float(pending["statistic"]),
        wssr={n: float(w) for n, w in zip(names, wssr, strict=True)},
        shift={
            "tuners": {n: float(v) for n, v in zip(est.layout.tuners, change, strict=True)},
            "health": {n: float(v) for n, v in zip(est.layout.health, h_change, strict=True)},
            "fault": fault_shift,
            "wssr_threshold": wssr_threshold,
            "nearest": names[best] if best is not None else None,
            "distance": distance,
        },
    )


# ------------------------------------------------------------------------ the filter run


@dataclass
class EngineRun:
    """One engine's records to process and where it starts."""

    engine_id: int
    operator_id: int
    seq0: int
    state: dict[str, Any]
    epoch: np.ndarray  # [S]
    phase: list[str]
    conditions: np.ndarray  # [S, 4]
    y: np.ndarray  # [S, ny] stored units, NaN = missing
    u: np.ndarray  # [S, nu]
    maintenance: np.ndarray  # epochs of the engine's maintenance actions
    redo: dict[float, Event] = field(default_factory=dict)  # events the run recomputes


@dataclass
class EngineOutput:
    """What a run computed for one engine: its records' estimate numbers (the ``packed``
    blobs' values, one row per record from ``EngineRun.seq0``), events, checkpoints and the
    state after its last record."""

    values: list[np.ndarray]  # per chunk [n, width] as VALUE_DTYPE (empty with a sink)
    events: list[EventDraft]
    checkpoints: list[tuple[int, float, dict[str, Any]]]  # seq, epoch, state
    state: dict[str, Any]
    width: int = 0
    n_records: int = 0

    @property
    def packed(self) -> np.ndarray:
        """[S, width] the numbers of every record's blob (``VALUE_DTYPE``)."""
        if not self.values:
            return np.empty((0, self.width), dtype=VALUE_DTYPE)
        return np.concatenate(self.values)

    def blobs(self) -> list[bytes]:
        """Each record's ``packed`` blob, as stored."""
        return [row.tobytes() for row in self.packed]


class ChunkRecords(NamedTuple):
    """One engine's records of a chunk, for isolation in sensor space: dy [n, ny] (percent
    of trim, NaN = missing), G_y [n, ny, p], G_u [n, ny, nu] and var [n, ny] (noise
    variance, percent^2)."""

    dy: np.ndarray
    G_y: np.ndarray
    G_u: np.ndarray
    var: np.ndarray

    def observation(self, est: SnapshotEstimator, j: int) -> RecordObservation:
        """Record ``j`` with each library fault's sensor change at its own condition (health
        columns through G_y, actuator-bias columns through G_u; MATH.md section 4, in sensor
        space), computed only for the records an alarm fits."""
        signatures = est.fault_signatures(self.G_y[j], self.G_u[j])
        return RecordObservation(self.dy[j], self.G_y[j], signatures, self.var[j])


def run_filters(
    est: SnapshotEstimator, runs: Sequence[EngineRun],
    sink: Callable[[estimate_rows.Block], None] | None = None,
) -> list[EngineOutput]:
    """Filter, detect and pack every engine's records; engines are batched in the filter.

    Per chunk the records of every engine are laid out [engine, record] (padding rows NaN),
    scheduled in one call, filtered in one call, and their estimates derived in one pass;
    only the detector goes engine by engine. With a ``sink`` (an ``EstimateWriter``'s
    ``add``) each engine's estimates of a chunk go there as soon as they are computed instead
    of into ``EngineOutput.values``.
    """
    outputs = [EngineOutput([], [], [], r.state, est.layout.width) for r in runs]
    filt = [SnapshotState.from_dict(r.state["filter"]) for r in runs]
    dets = [Detector.from_dict(r.state["detector"]) for r in runs]
    last = [r.state.get("last_epoch") for r in runs]
    longest = max((len(r.epoch) for r in runs), default=0)
    s = est.layout.slices()
    E = len(runs)
    ny = len(est.sensor_columns)
    chunk = max(64, RECORD_SLOTS // max(E, 1))
    for c0 in range(0, longest, chunk):
        c1 = min(c0 + chunk, longest)
        S = c1 - c0
        counts = np.array([max(0, min(c1, len(r.epoch)) - c0) for r in runs], dtype=np.int64)
        # Slot (engine, record) of each of the chunk's records, engine by engine.
        slot_e = np.repeat(np.arange(E), counts)
        slot_j = np.arange(len(slot_e)) - np.repeat(np.cumsum(counts) - counts, counts)
        present = [(r, n) for r, n in zip(runs, counts, strict=True) if n]
        y = np.concatenate([r.y[c0 : c0 + n] for r, n in present])
        u = np.concatenate([r.u[c0 : c0 + n] for r, n in present])
        # One schedule call for the chunk's records of every engine: the steady-state trims
        # are solved in one batch (a record's trim does not depend on its batch).
        g = est.schedule(np.concatenate([r.conditions[c0 : c0 + n] for r, n in present]))
        u_dev = 100.0 * (u - g.u_trim) / g.u_trim
        u_dev = np.where(np.isfinite(u_dev), u_dev, 0.0)  # a missing actuator: at trim
        dy = np.full((E, S, ny), np.nan)
        dy[slot_e, slot_j] = snapshot_deviation(y, g.y_trim, g.G_u, u_dev)
        G_y = np.zeros((E, S, ny, est.Vp.shape[0]))
        G_y[slot_e, slot_j] = g.G_y
        G_u = np.zeros((E, S, *g.G_u.shape[1:]))
        G_u[slot_e, slot_j] = g.G_u
        G_z = np.zeros((E, S, len(est.layout.aux), est.Vp.shape[0]))
        G_z[slot_e, slot_j] = g.G_z
        noise = np.broadcast_to(est.noise_std, (E, S, ny)).copy()
        if g.noise_std is not None:
            noise[slot_e, slot_j] = np.sqrt(g.noise_std**2 + MODEL_ERROR**2)
        resets = np.zeros((E, S), dtype=bool)
        scale = np.zeros((E, S))
        for e, r in enumerate(runs):
            n = int(counts[e])
            if n == 0:
                continue
            epochs = r.epoch[c0 : c0 + n]
            prev = np.concatenate([[np.nan if last[e] is None else last[e]], epochs[:-1]])
            new_flight = ~(epochs - prev < NEW_FLIGHT_S)  # NaN (first record) counts as new
            maint = np.zeros(n, dtype=bool)
            for t in r.maintenance:
                maint |= (t <= epochs) & (t > prev)  # NaN prev (first record): no reset
            resets[e, :n] = maint
            # A maintenance action may move the health: widen P to the fleet spread.
            scale[e, :n] = new_flight.astype(float) + maint * (FLEET_STD / WALK_STD) ** 2
            last[e] = float(epochs[-1])
        state = SnapshotState(
            np.concatenate([f.q_hat for f in filt]), np.concatenate([f.P for f in filt])
        )
        result = snapshot_filter(
            state, dy, G_y, est.vstar, est.Qq, noise, scale, keep_covariance=True
        )
        assert result.P is not None
        q_all, P_all = result.q_hat, result.P
        VpP = est.Vp @ P_all  # [E, S, p, m]
        Gz_Vp = G_z @ est.Vp  # [E, S, nz, m]
        values_all = np.empty((E, S, est.layout.width))
        values_all[..., s["q"]] = q_all
        values_all[..., s["q_sigma"]] = np.sqrt(
            np.maximum(np.diagonal(P_all, axis1=2, axis2=3), 0.0)
        )
        values_all[..., s["h"]] = q_all @ est.Vp.T
        values_all[..., s["h_sigma"]] = np.sqrt(np.maximum((VpP * est.Vp).sum(axis=-1), 0.0))
        values_all[..., s["z"]] = (Gz_Vp @ q_all[..., None])[..., 0]
        z_var = ((Gz_Vp @ P_all) * Gz_Vp).sum(axis=-1)
        values_all[..., s["z_sigma"]] = np.sqrt(np.maximum(z_var, 0.0))
        values_all[..., s["residual"]] = result.innovation
        for e, r in enumerate(runs):
            n = int(counts[e])
            if n == 0:
                continue
            q = q_all[e, :n]
            P = P_all[e, :n]
            values = values_all[e, :n]
            out = outputs[e]
            det = dets[e]
            q_prev = np.concatenate([filt[e].q_hat, q[:-1]])
            P_prior = np.concatenate([filt[e].P, P[:-1]]) + scale[e, :n, None, None] * est.Qq
            _wssr_filled(est, det, r, c0, n, q, P, q_prev, P_prior, resets[e], values, out,
                         ChunkRecords(dy[e, :n], G_y[e, :n], G_u[e, :n], noise[e, :n] ** 2))
            packed = values.astype(VALUE_DTYPE)
            out.n_records += n
            if sink is None:
                out.values.append(packed)
            else:
                sink((r.engine_id, r.seq0 + c0, r.epoch[c0 : c0 + n], r.phase[c0 : c0 + n],
                      packed))
            filt[e] = SnapshotState(q[-1:], P[-1:])
            out.state = {"filter": filt[e].to_dict(), "detector": det.to_dict(),
                         "last_epoch": last[e]}
    return outputs


def _wssr_filled(
    est: SnapshotEstimator, det: Detector, r: EngineRun, c0: int, n: int, q: np.ndarray,
    P: np.ndarray, q_prev: np.ndarray, P_prior: np.ndarray, resets: np.ndarray,
    values: np.ndarray, out: EngineOutput,
    records: ChunkRecords | None = None,
) -> np.ndarray:
    """Run the detector over the chunk, fill the WSSR block, collect events and checkpoints.

    records: the chunk's records of the engine, for isolation in sensor space.

    Same results as ``_wssr_filled_per_record`` (``detect_step`` record by record): between a
    reset and an alarm the baselines, level statistics and WSSR of a run of records are
    computed at once (``estimation.shift_scan``) and only the CUSUM and its running mean go
    record by record; a reset, a pending alarm or the "update" statistic take the per-record
    step.
    """
    if DETECTOR_INPUT != "level":
        return _wssr_filled_per_record(est, det, r, c0, n, q, P, q_prev, P_prior, resets,
                                       values, out, records)
    s = est.layout.slices()["wssr"]
    depth = N_BASE + GAP
    m = est.m
    reset_at = np.flatnonzero(resets)
    j = 0
    while j < n:
        if det.pending is not None or resets[j]:
            _detect_one(est, det, r, c0, j, q, P, q_prev, P_prior, resets, values, out,
                        records)
            j += 1
            continue
        # A run of records with neither reset nor pending alarm, up to the next reset or the
        # chunk's end (an alarm ends it early).
        later = reset_at[reset_at > j]
        end = int(later[0]) if len(later) else n
        L = len(det.history)
        series = np.concatenate([np.asarray(det.history, float).reshape(L, m), q[j:end]])
        first = max(depth - L, 0)  # run index of the first record with a baseline
        bases = sliding_baselines(series[: max(len(series) - GAP, 0)], N_BASE)
        # record i (run index) has history series[L + i - depth : L + i] before its append
        k_idx = np.arange(j + first, end)
        with_base = bases[L + first - depth : L + first - depth + len(k_idx)]
        scan = level_scan(q[k_idx] - with_base, P[k_idx], est.H) if len(k_idx) else None
        stop = end
        # The CUSUM and its running mean, record by record on Python floats, with the same
        # operations as ``detect_step`` (``b if b > a else a`` is ``max(a, b)``, NaN
        # included); records from ``armed`` on (run index) carry their WSSR, those before it
        # NaN. Run index i is a checkpoint when its seq + 1 is a multiple of CHECKPOINT_EVERY.
        distance = scan.distance.tolist() if scan is not None else []
        S, s_mean, s_count, warm = det.S, det.s_mean, det.s_count, det.warm
        threshold, reference = est.cusum.threshold, est.cusum.reference
        cap = S_MEAN_CAP * m
        armed = end - j
        next_checkpoint = -(r.seq0 + c0 + j + 1) % CHECKPOINT_EVERY
        for i in range(end - j):
            warm += 1
            if i < first:
                S = 0.0
            else:
                s_k = distance[i - first]
                if s_mean is None:
                    s_mean = float(m)
                scaled = s_k * m / (m if m > s_mean else s_mean)
                if S == 0.0:
                    s_count += 1
                    inverse = 1.0 / s_count
                    rate = S_MEAN_RATE if S_MEAN_RATE > inverse else inverse
                    s_mean += ((cap if cap < s_k else s_k) - s_mean) * rate
                if warm < WARMUP:
                    S = 0.0
                else:
                    if armed > i:
                        armed = i
                    S = S + scaled - m - reference
                    S = S if S > 0.0 else 0.0
                    if S > threshold:
                        assert scan is not None
                        jj = j + i
                        det.pending = {
                            "seq": r.seq0 + c0 + jj, "epoch": float(r.epoch[c0 + jj]),
                            "statistic": S, "wait": N_CONFIRM,
                            "baseline": with_base[i - first].tolist(), "P": P[jj].tolist(),
                        }
                        if records is not None:
                            accumulate_sensor_fit(est, det.pending, records.observation(est, jj))
                        S = 0.0
                        stop = jj + 1
            if i == next_checkpoint or stop < end:
                det.S, det.s_mean, det.s_count, det.warm = S, s_mean, s_count, warm
                det.history = series[max(L + i + 1 - depth, 0) : L + i + 1].tolist()
                if i == next_checkpoint:
                    _checkpoint(det, r, c0, j + i, q, P, out)
                    next_checkpoint += CHECKPOINT_EVERY
                if stop < end:
                    break
        det.S, det.s_mean, det.s_count, det.warm = S, s_mean, s_count, warm
        det.history = series[max(L + stop - j - depth, 0) : L + stop - j].tolist()
        values[j:stop, s] = np.nan
        if scan is not None and j + armed < stop:
            values[j + armed : stop, s] = scan.wssr[armed - first : stop - j - first]
        j = stop
    return values


def _checkpoint(
    det: Detector, r: EngineRun, c0: int, j: int, q: np.ndarray, P: np.ndarray,
    out: EngineOutput,
) -> None:
    epoch = float(r.epoch[c0 + j])
    out.checkpoints.append(
        (
            r.seq0 + c0 + j + 1,
            epoch,
            {
                "filter": SnapshotState(q[j : j + 1], P[j : j + 1]).to_dict(),
                "detector": det.to_dict(),
                "last_epoch": epoch,
            },
        )
    )


def _detect_one(
    est: SnapshotEstimator, det: Detector, r: EngineRun, c0: int, j: int, q: np.ndarray,
    P: np.ndarray, q_prev: np.ndarray, P_prior: np.ndarray, resets: np.ndarray,
    values: np.ndarray, out: EngineOutput,
    records: ChunkRecords | None,
) -> None:
    """Record ``j`` of the chunk through ``detect_step``, with its event and checkpoint."""
    seq = r.seq0 + c0 + j
    epoch = float(r.epoch[c0 + j])
    obs = None if records is None else records.observation(est, j)
    wssr, draft = detect_step(
        est, det, seq, epoch, q[j], P[j], q_prev[j], P_prior[j], bool(resets[j]), obs
    )
    values[j, est.layout.slices()["wssr"]] = wssr
    if draft is not None:
        out.events.append(draft)
    if (seq + 1) % CHECKPOINT_EVERY == 0:
        _checkpoint(det, r, c0, j, q, P, out)


def _wssr_filled_per_record(
    est: SnapshotEstimator, det: Detector, r: EngineRun, c0: int, n: int, q: np.ndarray,
    P: np.ndarray, q_prev: np.ndarray, P_prior: np.ndarray, resets: np.ndarray,
    values: np.ndarray, out: EngineOutput,
    records: ChunkRecords | None = None,
) -> np.ndarray:
    """``_wssr_filled`` one record at a time through ``detect_step`` (the reference the
    batched run is tested against, and the path of the "update" statistic)."""
    s = est.layout.slices()["wssr"]
    for j in range(n):
        seq = r.seq0 + c0 + j
        epoch = float(r.epoch[c0 + j])
        obs = None if records is None else records.observation(est, j)
        wssr, draft = detect_step(
            est, det, seq, epoch, q[j], P[j], q_prev[j], P_prior[j], bool(resets[j]), obs
        )
        values[j, s] = wssr
        if draft is not None:
            out.events.append(draft)
        done = seq + 1  # records processed once this one is
        if done % CHECKPOINT_EVERY == 0:
            out.checkpoints.append(
                (
                    done,
                    epoch,
                    {
                        "filter": SnapshotState(q[j : j + 1], P[j : j + 1]).to_dict(),
                        "detector": det.to_dict(),
                        "last_epoch": epoch,
                    },
                )
            )
    return values


# ---------------------------------------------------------------------- database side


def _restart_point(
    session: Session, est: SnapshotEstimator, fs: FilterState | None, earliest: datetime | None
) -> tuple[int, dict[str, Any], datetime | None]:
    """(seq0, state, after): where the engine's run starts, deleting what it will redo."""
    if fs is None:
        return 0, initial_state(est), None
    if earliest is None or fs.last_recorded_at is None or earliest > fs.last_recorded_at:
        return fs.n_records, fs.state, fs.last_recorded_at
    checkpoint = session.scalar(
        select(FilterCheckpoint)
        .where(
            FilterCheckpoint.engine_id == fs.engine_id,
            FilterCheckpoint.design_id == fs.design_id,
            FilterCheckpoint.last_recorded_at < earliest,
        )
        .order_by(FilterCheckpoint.seq.desc())
        .limit(1)
    )
    if checkpoint is None:
        seq0, state, after = 0, initial_state(est), None
    else:
        seq0, state, after = checkpoint.seq, checkpoint.state, checkpoint.last_recorded_at
    _delete_from(session, fs.engine_id, fs.design_id, seq0, state)
    return seq0, state, after


def _delete_from(
    session: Session, engine_id: int, design_id: int, seq0: int, state: Mapping[str, Any]
) -> None:
    """Remove what a re-run from ``seq0`` recomputes. Events are not deleted here: the re-run
    updates those it detects again (keeping their status and comments) and deletes the rest
    (``_store``). An alarm pending at the restart point is isolated again by the re-run, so its
    event is redone too."""
    session.execute(
        delete(Estimate).where(
            Estimate.engine_id == engine_id, Estimate.design_id == design_id, Estimate.seq >= seq0
        )
    )
    session.execute(
        delete(FilterCheckpoint).where(
            FilterCheckpoint.engine_id == engine_id,
            FilterCheckpoint.design_id == design_id,
            FilterCheckpoint.seq > seq0,
        )
    )


def _events_to_redo(
    events: Sequence[Event], seq0: int, state: Mapping[str, Any]
) -> dict[float, Event]:
    """Of one engine's ``events``, those a run from ``seq0`` (state ``state``) recomputes, by
    detection time (an alarm's record keeps its time when a late record shifts the sequence
    numbers)."""
    pending = (state.get("detector") or {}).get("pending")
    pending_seq = None if pending is None else int(pending["seq"])
    return {e.detected_at.timestamp(): e for e in events
            if e.seq >= seq0 or e.seq == pending_seq}


def _by_engine(session: Session, query: Any) -> dict[int, list[Any]]:
    """Rows of ``query`` (its first column an engine id) grouped by that id."""
    out: dict[int, list[Any]] = {}
    for row in session.execute(query).all():
        out.setdefault(int(row[0]), []).append(row)
    return out


def _active_designs(
    session: Session, operator_id: int, engines: Sequence[Engine], design_id: int | None
) -> tuple[dict[int, EstimatorDesign], dict[int, list[Engine]], list[str]]:
    """Designs by id, the engines each one runs (the engine type's active design, or
    ``design_id``), and the ESNs of engines with none."""
    if design_id is not None:
        forced = session.get(EstimatorDesign, design_id)
        by_type = {e.engine_type_id: forced for e in engines}
    else:
        by_type = {
            d.engine_type_id: d
            for d in session.scalars(
                select(EstimatorDesign).where(
                    EstimatorDesign.operator_id == operator_id,
                    EstimatorDesign.active.is_(True),
                )
            )
        }
    designs: dict[int, EstimatorDesign] = {}
    groups: dict[int, list[Engine]] = {}
    skipped = []
    for engine in engines:
        design = by_type.get(engine.engine_type_id)
        if design is None or design.operator_id != operator_id:
            skipped.append(engine.esn)
            continue
        designs[design.id] = design
        groups.setdefault(design.id, []).append(engine)
    return designs, groups, skipped


BATCH = 256  # engines filtered together (and committed together by a job)


@contextmanager
def _no_gc_pauses() -> Iterator[None]:
    """The cyclic garbage collector off for a batch: a batch allocates many small lists (states,
    histories) and creates no cycles worth finding, while each full collection walks every
    object of the process (a third of a 1000-engine batch's time in a server process)."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def estimate_engines(
    session: Session,
    operator_id: int,
    affected: Mapping[int, datetime | None],
    progress: Callable[[float, str], None] | None = None,
    design_id: int | None = None,
    commit: Callable[[], None] | None = None,
) -> dict[str, Any]:
    """Bring every affected engine's estimates up to date.

    affected: engine id -> earliest recorded_at of its new records (None: just continue).
    Engines of one design run batched, ``BATCH`` at a time: their records are read in one go
    and their estimates written in one go (``estimate_rows``); ``commit`` (a job's) is called
    after each batch so finished engines survive a restart, else all stays in the caller's
    transaction. Returns counts per outcome.
    """
    engines = session.scalars(
        select(Engine)
        .where(Engine.operator_id == operator_id, Engine.id.in_(list(affected)))
        .order_by(Engine.id)
    ).all()
    designs, by_design, skipped = _active_designs(session, operator_id, engines, design_id)
    summary: dict[str, Any] = {"engines": 0, "records": 0, "events": 0, "reruns": 0,
                               "skipped_no_design": skipped}
    total = sum(len(v) for v in by_design.values()) or 1
    done = 0
    for d_id, group in by_design.items():
        est = estimator_for_design(session, designs[d_id])
        for start in range(0, len(group), BATCH):
            batch = group[start : start + BATCH]
            with _no_gc_pauses():
                runs, states = _prepare_runs(session, est, operator_id, batch, affected,
                                             summary)
                with estimate_rows.EstimateWriter(
                    session, operator_id=operator_id, design_id=est.design_id
                ) as writer:
                    outputs = run_filters(est, runs, sink=writer.add)
                _store_batch(session, est, runs, states, outputs)
            for out in outputs:
                summary["records"] += out.n_records
                summary["events"] += len(out.events)
            summary["engines"] += len(runs)
            done += len(batch)
            if commit is not None:
                commit()
            if progress is not None:
                progress(done / total, f"estimated {done} of {total} engines")
    return summary


def _prepare_runs(
    session: Session, est: SnapshotEstimator, operator_id: int, batch: Sequence[Engine],
    affected: Mapping[int, datetime | None], summary: dict[str, Any],
) -> tuple[list[EngineRun], list[FilterState | None]]:
    """The runs of a batch of engines under one design: restart points (deleting what a
    re-run redoes), records, maintenance actions and the events a run redoes, each read once
    for the batch."""
    ids = [e.id for e in batch]
    states = {
        fs.engine_id: fs
        for fs in session.scalars(
            select(FilterState).where(
                FilterState.design_id == est.design_id, FilterState.engine_id.in_(ids)
            )
        )
    }
    starts = {}
    for engine_id in ids:
        fs = states.get(engine_id)
        starts[engine_id] = _restart_point(session, est, fs, affected.get(engine_id))
        if fs is not None and starts[engine_id][0] < fs.n_records:
            summary["reruns"] += 1
    records = estimate_rows.load_records(
        session, [(engine_id, starts[engine_id][2]) for engine_id in ids],
        est.sensor_columns, est.input_columns, kept=fresh_records.take(session, ids),
    )
    maintenance = _by_engine(
        session,
        select(MaintenanceAction.engine_id, MaintenanceAction.performed_at).where(
            MaintenanceAction.engine_id.in_(ids)
        ),
    )
    events = _by_engine(
        session,
        select(Event.engine_id, Event).where(
            Event.engine_id.in_(ids), Event.design_id == est.design_id
        ),
    )
    runs, kept = [], []
    for engine_id in ids:
        fs = states.get(engine_id)
        seq0, state, _after = starts[engine_id]
        rec = records[engine_id]
        if len(rec.epoch) == 0 and fs is not None and seq0 == fs.n_records:
            continue
        times = sorted(row[1].timestamp() for row in maintenance.get(engine_id, []))
        redo = _events_to_redo([row[1] for row in events.get(engine_id, [])], seq0, state)
        runs.append(EngineRun(engine_id, operator_id, seq0, state, rec.epoch,
                              rec.phase, rec.conditions, rec.y, rec.u,
                              np.array(times, dtype=float), redo))
        kept.append(fs)
    return runs, kept


def _store_batch(
    session: Session, est: SnapshotEstimator, runs: Sequence[EngineRun],
    states: Sequence[FilterState | None], outputs: Sequence[EngineOutput],
) -> None:
    """A batch's checkpoints (one INSERT), then each engine's events and filter state (its
    estimates went in while they were computed)."""
    checkpoints = [
        {"engine_id": run.engine_id, "design_id": est.design_id, "seq": seq,
         "last_recorded_at": datetime.fromtimestamp(epoch, UTC),
         "state": state}
        for run, out in zip(runs, outputs, strict=True)
        for seq, epoch, state in out.checkpoints
    ]
    if checkpoints:
        session.execute(insert(FilterCheckpoint), checkpoints)
    for run, fs, out in zip(runs, states, outputs, strict=True):
        _store(session, est, run, fs, out)
    session.flush()


def _store(
    session: Session, est: SnapshotEstimator, run: EngineRun, fs: FilterState | None,
    out: EngineOutput,
) -> None:
    """One engine's events (redone ones updated in place) and filter state."""
    redo = dict(run.redo)
    fresh = []
    for draft in out.events:
        detection = {
            "detected_at": datetime.fromtimestamp(draft.epoch, UTC), "kind": draft.kind,
            "fault": draft.fault, "magnitude": draft.magnitude, "statistic": draft.statistic,
            "wssr": draft.wssr, "shift": draft.shift,
        }
        existing = redo.pop(draft.epoch, None)
        if existing is not None:
            # Detected again: keep what people did with it (status, comments).
            for key, value in detection.items():
                setattr(existing, key, value)
            existing.seq = draft.seq
        else:
            fresh.append((draft.seq, detection))
    pending = (out.state.get("detector") or {}).get("pending")
    for epoch, stale in redo.items():
        if pending is not None and float(pending["epoch"]) == epoch:
            continue  # still awaiting its isolation: the next run redoes it
        session.delete(stale)
    if run.redo:
        session.flush()  # stale events go before new ones may take their sequence numbers
    for seq, detection in fresh:
        session.add(
            Event(
                operator_id=run.operator_id, engine_id=run.engine_id, design_id=est.design_id,
                seq=seq, status="open", **detection,
            )
        )
    n_records = run.seq0 + len(run.epoch)
    last_time = (
        datetime.fromtimestamp(float(run.epoch[-1]), UTC) if len(run.epoch)
        else (fs.last_recorded_at if fs is not None and run.seq0 == fs.n_records else None)
    )
    if fs is None:
        fs = FilterState(operator_id=run.operator_id, engine_id=run.engine_id,
                         design_id=est.design_id)
        session.add(fs)
    layout = est.layout.to_dict()
    if fs.layout != layout:  # an unchanged layout is not rewritten (JSON is not diffed)
        fs.layout = layout
    fs.state = out.state
    fs.n_records = n_records
    if len(run.epoch) or run.seq0 == 0:
        fs.last_recorded_at = last_time
    fs.updated_at = utcnow()


def pending_work(
    session: Session, operator_id: int, engine_ids: Sequence[int] | None = None
) -> dict[int, datetime]:
    """Engines with snapshots that have no estimate under their type's active design, and the
    earliest such snapshot of each: what the pipeline has still to do (or redo).

    Per engine, from its filter state: the first record after the last processed one (an
    index lookup), and the count of records up to it against the records processed; only
    an engine with a late record (more records than processed up to the last one) is searched
    for its earliest unestimated record.
    """
    active = (
        select(EstimatorDesign.id, EstimatorDesign.engine_type_id)
        .where(EstimatorDesign.operator_id == operator_id, EstimatorDesign.active.is_(True))
        .subquery()
    )
    fs = FilterState.__table__
    snap = Snapshot.__table__
    after_last = or_(fs.c.last_recorded_at.is_(None), snap.c.recorded_at > fs.c.last_recorded_at)
    first_new = (
        select(func.min(snap.c.recorded_at))
        .where(snap.c.engine_id == Engine.id, after_last)
        .scalar_subquery()
    )
    up_to_last = (
        select(func.count())
        .select_from(snap)
        .where(snap.c.engine_id == Engine.id, snap.c.recorded_at <= fs.c.last_recorded_at)
        .scalar_subquery()
    )
    query = (
        select(Engine.id, active.c.id, fs.c.n_records, first_new, up_to_last)
        .join(active, active.c.engine_type_id == Engine.engine_type_id)
        .outerjoin(fs, and_(fs.c.engine_id == Engine.id, fs.c.design_id == active.c.id))
        .where(Engine.operator_id == operator_id)
    )
    if engine_ids is not None:
        query = query.where(Engine.id.in_(list(engine_ids)))
    out = {}
    for engine_id, d_id, n_records, new, counted in session.execute(query).all():
        if n_records is not None and counted is not None and counted > n_records:
            out[int(engine_id)] = _earliest_unestimated(session, engine_id, d_id)
        elif new is not None:
            out[int(engine_id)] = new
    return out


def _earliest_unestimated(session: Session, engine_id: int, design_id: int) -> datetime:
    """The engine's earliest snapshot without an estimate under the design."""
    estimated = select(Estimate.recorded_at).where(
        Estimate.engine_id == engine_id, Estimate.design_id == design_id
    )
    earliest = session.scalar(
        select(func.min(Snapshot.recorded_at)).where(
            Snapshot.engine_id == engine_id, Snapshot.recorded_at.not_in(estimated)
        )
    )
    assert earliest is not None, "more snapshots than estimates, yet none without one"
    return earliest


def catch_up(
    session: Session,
    operator_id: int,
    progress: Callable[[float, str], None] | None = None,
    commit: Callable[[], None] | None = None,
    max_passes: int = 10,
) -> dict[str, Any]:
    """Estimate until no snapshot of the operator lacks an estimate (records that arrive
    meanwhile are picked up by the next pass). Idempotent: a second call finds nothing."""
    totals: dict[str, Any] = {"engines": 0, "records": 0, "events": 0, "reruns": 0, "passes": 0}
    for _ in range(max_passes):
        work = pending_work(session, operator_id)
        if not work:
            break
        result = estimate_engines(session, operator_id, work, progress, commit=commit)
        totals["passes"] += 1
        for key in ("engines", "records", "events", "reruns"):
            totals[key] += result[key]
        if result["records"] == 0:
            break  # nothing could be estimated (no ready design): stop rather than spin
    return totals
