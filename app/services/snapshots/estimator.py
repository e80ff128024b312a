"""The estimator of a design: V* and V*^+, the filter's covariances and sensor noise, the
fault library in tuner and sensor space, the gains and trims at each record's operating
condition (``Schedule``) and the CUSUM, ready to run on an engine's snapshots.

On the built-in engine the trims come from the nominal engine's dense trim table
(``estimation.engine.trim_table``, solved once and cached next to the schedule; within 0.1
sigma of every sensor's noise of the exact steady-state solve, where the schedule's own
interpolated trims are off by up to ~0.5 % of a pressure, as much as a fault's signature) and
the sensor noise is constant in sensor units (so in percent of trim it grows with altitude).
On the demo fleet this finds 5 of its 6 detectable faults and names each correctly, with no
stored false alarm (bench/bench_detection.py).

A type described by a model schedule (``fleethealth.model-schedule/1``, docs/model-format.md)
takes each record's trims, gains and sensor noise from its models interpolated at the record's
condition (``model_schedule_for``); an imported model at one operating point gives the same to
every record (``single_point_schedule``).
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from scipy import stats
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import EngineModel, EstimatorDesign
from app.models.estimates import EstimateLayout
from app.services import units
from app.signals import ACTUATORS, SENSORS, SignalSpec, stored_at
from estimation import wear
from estimation.detection import CusumDesign, design_cusum
from estimation.engine.power_setting import held_speed_aux_gains
from estimation.engine.schedule import EngineSchedule
from estimation.engine.trim_table import TrimTable
from estimation.grid import Grid, corner_rows
from estimation.model import LinearModel, Signal
from estimation.schedule import SCHEDULE_FORMAT, ModelSchedule
from estimation.shift_detector import SHIFT_LEVEL
from estimation.snapshot_design import DesignResult, snapshot_design

log = logging.getLogger("fleethealth.pipeline")

# Detector settings an estimator's thresholds are designed from (the detector's own, and
# SHIFT_LEVEL, are in estimation.shift_detector).
CUSUM_REFERENCE = 1.5  # CUSUM allowance per sample, in units of m (robust to model error)
ARL0 = 20_000.0  # mean records between false alarms of the CUSUM (theory, independent samples)
ISOLATION_LEVEL = 0.999  # WSSR quantile below which the best fault explains the change
# Filter settings: tuner random walk per flight (percent), fleet spread at start (percent).
WALK_STD = 0.05
FLEET_STD = 1.5
# What a maintenance action can move the health by (percent, 1-sigma per tuner), widening the
# filter's covariance at its first record: a shop visit or module change anything up to the
# fleet's spread; a water wash only the compressors' fouling, well under a percent (widened to
# the fleet's spread, the filter forgot the engine and its estimates wandered by a percent for
# a day after each wash).
WASH_STD = 0.5
RESET_STD = {"water_wash": WASH_STD, "module_change": FLEET_STD, "shop_visit": FLEET_STD}
START_STD = 5.0
# Sensor model error (percent of trim) added in quadrature to the sensor noise: gains
# interpolated between schedule nodes, and the linearisation of an engine several percent from
# its trim, are off by about this much.
MODEL_ERROR = 0.2
# The built-in engine's power setting: the controller holds this sensor (the fan speed) at its
# demand by moving this input (the fuel flow).
MEASURED_COLUMNS = {"T48": "t48", "Wf": "wf", "Nc": "nc", "Nf": "nf"}  # sensor -> column
HELD_LOOP = ("Nf", "Wf")

SNAPSHOT_SIGNALS: dict[str, SignalSpec] = {s.name: s for s in SENSORS + ACTUATORS}


class PipelineError(RuntimeError):
    """A design or engine model the pipeline cannot run."""


class ScheduledGains(NamedTuple):
    """Linear model quantities at each record's operating condition (S records).

    y_trim [S, ny], u_trim [S, nu] in stored units; G_y [S, ny, p], G_u [S, ny, nu],
    G_z [S, nz, p] in percent of trim per percent. The aux estimate of a record is
    z = G_z h + G_zu du with the record's input deviations du: on the built-in engine G_z and
    G_zu are taken with the fan speed held at the power setting's demand
    (``estimation.engine.power_setting``), so the fuel-flow column of G_zu is zero; a model
    at one operating point gives its open-loop gains (the inputs as measured).
    """

    y_trim: np.ndarray
    u_trim: np.ndarray
    G_y: np.ndarray
    G_u: np.ndarray
    G_z: np.ndarray
    noise_std: np.ndarray | None = None  # [S, ny] sensor noise, percent of y_trim (None: the
    # design model's)
    constant: bool = False  # the same trims and gains at every condition (a linear model)
    G_zu: np.ndarray | None = None  # [S, nz, nu] aux per input deviation (None: no input term)


Schedule = Callable[[np.ndarray], ScheduledGains]  # conditions [S, 4] -> gains


def _stored_unit(name: str, unit: str, value: float) -> float:
    """A trim value from the model's unit into the unit snapshots are stored in: the
    catalogue's for a catalogue signal (NaN when the unit does not convert), the model file's
    for any other (an engine type's own signal, ``fleet.parameter_sets.stored_spec``)."""
    spec = SNAPSHOT_SIGNALS.get(name)
    if spec is None:
        return value
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
    G_u, G_zu = model.steady_state_input_gains()
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
            constant=True,
            G_zu=np.broadcast_to(G_zu, (S, *G_zu.shape)),
        )

    return schedule


def stored_affine(signals: Sequence[Signal]) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) per signal taking a value in its model unit to the unit snapshots store it in
    (stored = a value + b): the identity for a signal outside the catalogue (stored in its
    model's unit) or given in the stored unit, NaN where the unit does not convert."""
    a, b = np.ones(len(signals)), np.zeros(len(signals))
    for k, sig in enumerate(signals):
        spec = SNAPSHOT_SIGNALS.get(sig.name)
        if spec is None or sig.unit in (spec.unit, ""):
            continue
        try:
            a[k], b[k] = units.affine(
                spec.quantity, sig.unit, spec.unit, reference=spec.percent_reference
            )
        except units.UnknownUnitError:
            a[k], b[k] = np.nan, np.nan
    return a, b


def node_interpolation(
    grid: Grid, corners: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    blocks: Mapping[str, np.ndarray],
) -> Callable[[np.ndarray], dict[str, np.ndarray]]:
    """Interpolation of several node quantities at once: ``blocks`` name -> values over the
    grid [*grid.shape, ...] at the records' conditions (``Grid.corners``, given here as the
    schedule's ``corners``, which reads the schedule's own conditions) -> name -> [S, ...].
    One sparse matrix of the records' corner weights (``corner_rows``) times each block's
    values over the nodes [n_nodes, F]: the same sums as ``corner_sums`` of all the blocks
    side by side, each quantity a contiguous array of its own (what reads it reads
    contiguous memory, and no array is the size of all of them)."""
    n_nodes = int(np.prod(grid.shape))
    shapes = {k: v.shape[len(grid.shape):] for k, v in blocks.items()}
    flats = {k: np.ascontiguousarray(v.reshape(n_nodes, -1)) for k, v in blocks.items()}

    def interpolate(c: np.ndarray) -> dict[str, np.ndarray]:
        rows = corner_rows(*corners(c), n_nodes)
        return {name: np.asarray(rows @ flat).reshape(-1, *shapes[name])
                for name, flat in flats.items()}

    return interpolate


def template_indices(
    template: LinearModel, model: LinearModel
) -> tuple[list[int], list[int], list[int], list[int]]:
    """Where ``model``'s sensors, inputs, aux outputs and health parameters sit in the
    schedule's template model (the rows and columns of its gains)."""
    return ([template.sensor_names.index(n) for n in model.sensor_names],
            [template.input_names.index(n) for n in model.input_names],
            [template.aux_names.index(n) for n in model.aux_names],
            [template.health_names.index(n) for n in model.health_names])


def model_gains(
    values: Mapping[str, np.ndarray], yi: list[int], ui: list[int], zi: list[int], hi: list[int]
) -> dict[str, np.ndarray]:
    """A schedule's node gains restricted to a model's signals (``template_indices``): G_y,
    G_uy, G_z and G_uz over the nodes."""
    return {"Gy": values["Gy"][..., yi, :][..., hi], "Guy": values["Guy"][..., yi, :][..., ui],
            "Gz": values["Gz"][..., zi, :][..., hi], "Guz": values["Guz"][..., zi, :][..., ui]}


def model_schedule_for(model: LinearModel, sched: ModelSchedule) -> Schedule:
    """Gains, trims and sensor noise of ``model``'s signals (a design's selection of the
    schedule's signals) at each record's operating condition, interpolated between the nodes of
    an imported model schedule (trims as corrected parameters, docs/model-format.md). The aux
    gains are open-loop, the inputs as measured, as for a model at one operating point."""
    tmpl = sched.template
    missing = [n for n in (*model.sensor_names, *model.input_names) if n not in sched.trim_names]
    if missing:
        raise PipelineError(f"the model schedule trims none of the signals {missing}")
    yi, ui, zi, hi = template_indices(tmpl, model)
    ya, yb = stored_affine(model.sensors)
    ua, ub = stored_affine(model.inputs)
    if not np.all(np.isfinite(ya)):
        bad = [s.name for s, v in zip(model.sensors, ya, strict=True) if not np.isfinite(v)]
        raise PipelineError(f"no trim in a stored unit for the engine model's sensors {bad}")
    values = sched.values
    gains_at = node_interpolation(sched.grid, sched.corners, {
        **model_gains(values, yi, ui, zi, hi), "noise": values["noise"][..., yi]})

    def schedule(conditions: np.ndarray) -> ScheduledGains:
        # Snapshot columns are (alt, mach, dtamb, power): the schedule's CONDITIONS.
        conditions = np.asarray(conditions, float)
        trims = sched.trims_at(conditions)
        y_trim = np.stack([trims[n] for n in model.sensor_names], axis=1) * ya + yb
        u_trim = (np.stack([trims[n] for n in model.input_names], axis=1) * ua + ub
                  if model.input_names else np.zeros((conditions.shape[0], 0)))
        g = gains_at(conditions)
        return ScheduledGains(y_trim, u_trim, g["Gy"], g["Guy"], g["Gz"], g["noise"],
                              G_zu=g["Guz"])

    return schedule


@dataclass(frozen=True, eq=False)
class SnapshotEstimator:
    """Everything the pipeline needs of one design, ready to run."""

    design_id: int
    layout: EstimateLayout
    sensor_columns: tuple[str, ...]  # where each design sensor is stored (``stored_at``)
    input_columns: tuple[str, ...]  # the same per input ("" = not used)
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
        [..., ny, nu] (docs/math.md section 4, in sensor space) -> [..., ny, n_faults]."""
        p = G_y.shape[-1]
        return G_y @ self.S_full[:p] + G_u[..., list(self.bias_inputs)] @ self.S_full[p:]


@functools.lru_cache(maxsize=32)
def cusum_for(m: int) -> CusumDesign:
    """The CUSUM for m tuners at the pipeline's false-alarm rate. Its design takes a fraction
    of a second; it is kept in the data directory's cache, so each process reads it."""
    from app.engine_cache import arrays

    reference = CUSUM_REFERENCE * m

    def build() -> dict[str, float]:
        d = design_cusum(m, arl0=ARL0, reference=reference)
        return {"threshold": d.threshold, "arl0": d.arl0}

    table = arrays(Path(cache_dir()), "cusum",
                   {"m": m, "arl0": ARL0, "reference": reference}, build)
    return CusumDesign(m, reference, float(table["threshold"]), float(table["arl0"]))


def build_estimator(
    design_id: int, model: LinearModel, result: Mapping[str, Any],
    schedule: Schedule | None = None,
) -> SnapshotEstimator:
    """A runnable estimator from a design document and its engine model.

    The document (read by ``DesignResult``) gives V*, optionally the sensor suite, the fleet
    health covariance Ph and the fault library; defaults fill the rest. The numbers are
    ``estimation.snapshot_design``'s.
    """
    doc = DesignResult.from_document(result)
    if doc.vstar is None:
        raise PipelineError(f"design {design_id} has no V* (vstar)")
    if doc.sensors is not None:
        model = model.select_sensors(list(doc.sensors))
    vstar = doc.vstar
    m, p = vstar.shape
    if p != model.n_health:
        raise PipelineError(f"design {design_id}: V* has {p} columns, the model {model.n_health}")
    d = snapshot_design(model, vstar, doc.Ph, doc.faults, WALK_STD, FLEET_STD, START_STD,
                        MODEL_ERROR)
    library = d.library

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
        health_from_tuners=tuple(tuple(float(x) for x in row) for row in d.Vp),
    )
    sensor_columns = tuple(stored_at(s.name) for s in model.sensors)
    # An actuator is used only where its trim converts to the stored unit.
    input_columns = tuple(
        stored_at(s.name)
        if np.isfinite(_stored_unit(s.name, s.unit, model.trim.get(s.name, math.nan)))
        else ""
        for s in model.inputs
    )
    return SnapshotEstimator(
        design_id=design_id,
        layout=layout,
        sensor_columns=sensor_columns,
        input_columns=input_columns,
        vstar=vstar,
        Vp=d.Vp,
        Qq=d.Qq,
        P0=d.P0,
        noise_std=d.noise_std,
        H=d.H,
        S_full=d.S_full,
        fault_shifts=tuple(dict(f.shifts) for f in library),
        bias_inputs=d.bias_inputs,
        schedule=schedule or single_point_schedule(model),
        cusum=cusum_for(m),
        wssr_threshold=float(stats.chi2.ppf(ISOLATION_LEVEL, max(m - 1, 1))),
        shift_threshold=float(stats.chi2.isf(SHIFT_LEVEL, m)),
    )


def cache_dir() -> str:
    """The data directory's cache of what estimation computes once: engine schedule and trim
    table, detector designs and calibrations (``app.engine_cache``)."""
    from app.config import get_settings

    return str(get_settings().data_dir.resolve() / "cache")


@functools.lru_cache(maxsize=4)
def _calibration_store(directory: str) -> wear.CalibrationStore:
    from app.engine_cache import arrays

    return functools.partial(arrays, Path(directory), "wear-bank")


def estimator_for_design(session: Session, design: EstimatorDesign) -> SnapshotEstimator:
    """The estimator of a stored design: the design's model (sensors and health selected) and,
    for the built-in engine or a model schedule, its operating-condition schedule. The wear
    bank's calibrations are kept in the data directory's cache from here on."""
    wear.keep_calibrations(_calibration_store(cache_dir()))
    if design.status != "ready" or design.result is None:
        raise PipelineError(f"design {design.id} is not ready")
    row = session.get(EngineModel, design.engine_model_id)
    if row is None:
        raise PipelineError(f"design {design.id}: engine model {design.engine_model_id} missing")
    embedded = design.result.get("model")
    model = LinearModel.from_dict(embedded if isinstance(embedded, Mapping) else row.content)
    schedule = None
    if row.source == "builtin":
        schedule = engine_schedule_for(model, builtin_schedule(), builtin_trim_table())
    elif row.format == SCHEDULE_FORMAT:
        schedule = model_schedule_for(model, ModelSchedule.from_dict(row.content))
    return build_estimator(design.id, model, design.result, schedule)


def prepare() -> None:
    """What estimation in this process needs of the built-in engine, made now (a job or worker
    process's start) rather than in its first job: the sensor noise (a steady-state solve),
    and the schedule and trim table where the data directory's cache holds them (a missing one
    is built by the first job that needs it, not here)."""
    from app.engine_cache import cache_path, trim_table_path
    from estimation.engine.fleet import engine_noise_std

    engine_noise_std()
    directory = Path(cache_dir())
    if cache_path(directory).exists():
        builtin_schedule()
    if trim_table_path(directory).exists():
        builtin_trim_table()


def builtin_schedule() -> EngineSchedule:
    """The built-in engine's schedule from the data directory's cache (built on first use)."""
    return _cached_schedule(cache_dir())


@functools.lru_cache(maxsize=2)
def _cached_schedule(directory: str) -> EngineSchedule:
    from app.engine_cache import engine_schedule

    return engine_schedule(Path(directory))


def builtin_trim_table() -> TrimTable | None:
    """The built-in engine's nominal trim table from the data directory's cache (solved on
    first use); None if it cannot be solved (the trims are then solved per record)."""
    return _cached_trim_table(cache_dir())


@functools.lru_cache(maxsize=2)
def _cached_trim_table(directory: str) -> TrimTable | None:
    from app.engine_cache import engine_trim_table
    from estimation.engine.errors import EngineConvergenceError

    try:
        return engine_trim_table(Path(directory))
    except EngineConvergenceError as exc:
        log.warning("the nominal trim table could not be solved (%s); solving per record", exc)
        return None


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


def builtin_schedule_for_design(session: Session, design_id: int) -> EngineSchedule | None:
    """The built-in engine's schedule when the design's engine model is the built-in one."""
    source = session.scalar(
        select(EngineModel.source)
        .join(EstimatorDesign, EstimatorDesign.engine_model_id == EngineModel.id)
        .where(EstimatorDesign.id == design_id)
    )
    if source != "builtin":
        return None
    return builtin_schedule()


def schedule_trims(schedule: EngineSchedule, conditions: np.ndarray) -> dict[str, np.ndarray]:
    """The schedule's interpolated trims at records' conditions [n, 4] (snapshot order)."""
    cond = np.asarray(conditions, float)
    if cond.shape[0] == 0:
        return {k: np.empty(0) for k in schedule.trim_names}
    return schedule.trims_at(cond[:, [0, 1, 3, 2]])


def baseline_trims(
    conditions: np.ndarray, schedule: EngineSchedule,
    trims: Mapping[str, np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """Sensor trims of the nominal built-in engine at each record's condition [n, 4]
    (snapshot order), as the estimation takes them: from the dense trim table (within 0.1
    sigma of every sensor's noise of the steady-state solve, ``bench_trim_table.py``), solved
    per record when the table cannot be had, and the schedule's interpolation (``trims``,
    computed when not given) outside the engine's envelope."""
    cond = np.ascontiguousarray(conditions, dtype=float)
    interpolated = trims if trims is not None else schedule_trims(schedule, cond)
    out = {k: np.array(v, dtype=float, copy=True) for k, v in interpolated.items()
           if k in MEASURED_COLUMNS}
    table = builtin_trim_table()
    if table is None:
        return exact_nominal_trims(cond, out)
    inside = table.inside(cond)
    if inside.any():
        solved = table.trims_at(cond[inside])
        for i, name in enumerate(table.names):
            if name in out:
                out[name][inside] = solved[:, i]
    return out


def engine_schedule_for(
    model: LinearModel, sched: EngineSchedule, trims: TrimTable | None = None,
    exact_trims: bool = True,
) -> Schedule:
    """Gains and trims of ``model``'s signals at each record's operating condition, from the
    built-in engine's schedule (corrected-parameter trims, docs/math.md section 8). The trims
    come from the dense nominal trim table ``trims`` (records outside the envelope keep the
    schedule's own, as the exact solve's do); without one,
    with ``exact_trims`` they are solved per record (``exact_nominal_trims``), else the
    schedule's own. The gains are interpolated (they vary slowly)."""
    tmpl = sched.template
    yi, ui, zi, hi = template_indices(tmpl, model)
    ya, yb = stored_affine(model.sensors)
    ua, ub = stored_affine(model.inputs)
    # The built-in engine's sensor noise is a constant in sensor units (seed 001 Table 2), so
    # in percent of trim it grows with altitude: about four times larger at cruise than at
    # take-off for the pressures. Each record gets its own.
    from estimation.engine.fleet import engine_noise_std
    from estimation.engine.sensors import SENSOR_NAMES

    # The controller holds the fan speed at the power setting's demand through the fuel flow:
    # the aux gains are taken along that loop (``estimation.engine.power_setting``).
    loop = (model.input_names.index(HELD_LOOP[1])
            if HELD_LOOP[0] in tmpl.sensor_names and HELD_LOOP[1] in model.input_names else None)
    held = tmpl.sensor_names.index(HELD_LOOP[0]) if loop is not None else 0
    noise_engine = engine_noise_std()
    noise_abs = np.array([noise_engine[SENSOR_NAMES.index(n)] for n in model.sensor_names])
    noise_abs = noise_abs * np.abs(ya)
    table = trims

    values = sched.values
    gains_at = node_interpolation(sched.grid, sched.corners, {
        **model_gains(values, yi, ui, zi, hi),
        "Gy_held": values["Gy"][..., held, :][..., hi],
        "Guy_held": values["Guy"][..., held, :][..., ui],
    })

    trimmed = {*model.sensor_names, *model.input_names}

    def nominal_trims(conditions: np.ndarray, c: np.ndarray) -> dict[str, np.ndarray]:
        """The nominal engine's trims at the records' conditions (snapshot columns, and the
        schedule's axes ``c``): from the dense table, else solved or interpolated."""
        if table is None:
            trims = sched.trims_at(c)
            return exact_nominal_trims(conditions, trims) if exact_trims else trims
        inside = table.inside(conditions)
        solved = table.trims_at(conditions)
        out = {n: solved[:, i] for i, n in enumerate(table.names)}
        if not trimmed.issubset(table.names):  # signals the table does not hold
            own = sched.trims_at(c)
            out.update({n: own[n] for n in trimmed if n not in out})
        if not inside.all():  # outside the envelope: the schedule's own trims
            own = sched.trims_at(c[~inside])
            for n in trimmed:
                out[n][~inside] = own[n]
        return out

    def schedule(conditions: np.ndarray) -> ScheduledGains:
        # Snapshot columns are (alt, mach, dtamb, power); the schedule's axes (alt, mach,
        # power, dtamb).
        conditions = np.asarray(conditions, float)
        c = conditions[:, [0, 1, 3, 2]]
        trims = nominal_trims(conditions, c)
        y_trim = np.stack([trims[n] for n in model.sensor_names], axis=1) * ya + yb
        u_trim = np.stack([trims[n] for n in model.input_names], axis=1) * ua + ub
        g = gains_at(c)
        Gy, Guy, Gz, Guz = g["Gy"], g["Guy"], g["Gz"], g["Guz"]
        if loop is not None:
            Gz, Guz = held_speed_aux_gains(Gz, Guz, g["Gy_held"], g["Guy_held"], loop)
        noise = 100.0 * noise_abs / np.abs(y_trim)
        return ScheduledGains(y_trim, u_trim, Gy, Guy, Gz, noise, G_zu=Guz)

    return schedule
