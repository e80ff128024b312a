"""Engineering units of an engine's estimates, and the classic performance deltas.

Estimates keep auxiliary outputs in percent of trim at the record's own operating condition
(z_hat). Engineers read thrust in lbf and in percent of rated, stall margins in margin points,
EGT margin in degrees C and the deltas against the type's baseline. For the built-in engine these
are converted at read time with the record's trims from the engine schedule (the operating
condition comes from the record's snapshot):

- margin SM [pts] = SM_trim (1 + z/100); its change from the baseline SM_trim z/100 [pts];
- thrust Fn [lbf] = Fn_trim (1 + z/100); in percent of rated, 100 Fn / Fn_rated where Fn_rated is
  the schedule's take-off thrust at sea-level static, ISA; thrust deficit -z [%];
- turbine inlet temperature T40 (estimated, not measured): its change from the nominal engine
  at the same condition, T40_trim z/100 [K = degC]; bypass ratio BPR = BPR_trim (1 + z/100);
- EGT is T48 (HPT exit / LPT inlet, the station the built-in engine reports as EGT; T50 is the
  LPT exit). Each delta is the measurement minus the baseline model (the nominal engine solved
  at the record's own condition), in corrected parameters (theta2 = T2/288.15 K,
  delta2 = P2/101325 Pa, seed 004): dEGT = (T48 - T48_base) / theta2 [K = degC];
  dWf, dN2 (Nc), dN1 (Nf) in percent of the baseline (a ratio at one condition, so corrected
  and physical ratios are equal);
- EGT margin = redline - EGT at the reference condition, take-off at sea level on an ISA+15 K
  day (the flat-rate corner where the margin is smallest): EGT_ref = T48_base(ref) + dEGT
  theta2(ref). A nominal engine has margin redline - T48_base(ref).

Deltas and EGT margin are smoothed over flights with an exponential filter
(``estimation.engine.deltas``): one record's scatter (sensor noise 0.75 % of T48, about 6 K)
would otherwise hide a trend of a few degrees.

Every series carries a 1-sigma (``engineering_sigma``): the estimated ones from the aux
estimates' honest sigma, the measured ones from the model error the design's calibration fitted
against the simulator's truth (``designs.calibration.figure_errors``); scored against the truth
in tests/app/services/trends/test_performance_truth.py.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np
from sqlalchemy.orm import Session

from app.models.estimates import EstimateLayout
from app.services.snapshots import rows
from app.services.snapshots.estimator import MEASURED_COLUMNS, schedule_trims
from estimation.engine.atmosphere import flight_condition
from estimation.engine.deltas import (
    DELTA_SENSORS,
    EGT_SENSOR,
    egt_reference,
    reference_egt,
    smoothed_deltas,
    smoothing_growth,
)
from estimation.engine.schedule import EngineSchedule

MARGINS = ("SM_fan", "SM_LPC", "SM_HPC")
THRUST = "Fn"
TURBINE_INLET = "T40"  # estimated (not measured): its change from the nominal engine, K
BYPASS_RATIO = "BPR"
# The series of ``engineering_units`` estimated from each aux output.
SERIES_OF_AUX = {THRUST: ("Fn", "Fn_rated", "thrust_deficit"),
                 **{m: (m, f"{m}_change") for m in MARGINS},
                 TURBINE_INLET: ("T40_change",), BYPASS_RATIO: ("BPR",)}
# Schedule axes order: alt [ft], mach, power [%], dtamb [K].
RATED_CONDITION = (0.0, 0.0, 100.0, 0.0)
RANKINE_PER_KELVIN = 1.8
# The measured sensor behind each measured figure.
DELTA_SOURCES = {"egt_margin": EGT_SENSOR,
                 **{name: sensor for name, sensor, _unit in DELTA_SENSORS}}
ZERO_C = 273.15


@dataclass(frozen=True)
class TypeReference:
    """Values of an engine type's nominal engine at its reference conditions."""

    rated_thrust_lbf: float
    egt_reference_c: float  # T48 of the nominal engine at deltas.EGT_REFERENCE_CONDITION
    theta_reference: float


def type_reference(schedule: EngineSchedule) -> TypeReference:
    """Rated thrust (take-off, sea-level static, ISA) and the nominal EGT at the reference."""
    return _reference(id(schedule), schedule)


@functools.lru_cache(maxsize=4)
def _reference(_key: int, schedule: EngineSchedule) -> TypeReference:
    rated = schedule.trims_at(np.array([RATED_CONDITION]))
    ref = egt_reference(schedule)
    return TypeReference(rated_thrust_lbf=float(rated[THRUST][0]),
                         egt_reference_c=ref.t48_k - ZERO_C, theta_reference=ref.theta)


@dataclass(frozen=True)
class RecordConditions:
    """Operating condition and measured EGT, Wf, N2, N1 of n records (NaN: missing).

    conditions : [n, 4] alt [ft], mach, dtamb [K], power [%] (snapshot order);
    measured : name -> [n] in stored units (degR, pps, rpm).
    """

    conditions: np.ndarray
    measured: Mapping[str, np.ndarray]


def engineering_units(
    schedule: EngineSchedule,
    layout: EstimateLayout,
    z: np.ndarray,
    records: RecordConditions,
    egt_redline_c: float,
    baseline: Mapping[str, np.ndarray] | None = None,
    trims: Mapping[str, np.ndarray] | None = None,
) -> list[tuple[str, str, np.ndarray]]:
    """Series (name, unit, [n] values) in engineering units for estimates z [n, n_aux].

    ``baseline``: sensor trims of the nominal engine at each record's condition (name -> [n],
    engine units); None takes the schedule's interpolated trims. ``trims``: the schedule's
    interpolated trims at the records (``schedule_trims``), when the caller has them.
    """
    cond = np.asarray(records.conditions, float)
    n = cond.shape[0]
    if trims is None:
        trims = schedule_trims(schedule, cond)
    base = dict(trims)
    if baseline is not None:
        base.update({k: np.asarray(v, float) for k, v in baseline.items()})
    ref = type_reference(schedule)
    out: list[tuple[str, str, np.ndarray]] = []
    aux = list(layout.aux)
    if THRUST in aux and THRUST in trims:
        zt = z[:, aux.index(THRUST)].astype(float)
        fn = trims[THRUST] * (1.0 + zt / 100.0)
        out.append(("Fn", "lbf", fn))
        out.append(("Fn_rated", "% of rated", 100.0 * fn / ref.rated_thrust_lbf))
        out.append(("thrust_deficit", "%", -zt))
    for name in MARGINS:
        if name in aux and name in trims:
            zm = z[:, aux.index(name)].astype(float)
            out.append((name, "pts", trims[name] * (1.0 + zm / 100.0)))
            out.append((f"{name}_change", "pts", trims[name] * zm / 100.0))
    if TURBINE_INLET in aux and TURBINE_INLET in trims:
        z40 = z[:, aux.index(TURBINE_INLET)].astype(float)
        out.append(("T40_change", "degC", trims[TURBINE_INLET] * z40 / 100.0 / RANKINE_PER_KELVIN))
    if BYPASS_RATIO in aux and BYPASS_RATIO in trims:
        zb = z[:, aux.index(BYPASS_RATIO)].astype(float)
        out.append(("BPR", "1", trims[BYPASS_RATIO] * (1.0 + zb / 100.0)))
    theta = flight_condition(cond[:, 0], cond[:, 1], cond[:, 2]).theta if n else np.empty(0)
    deltas = smoothed_deltas(records.measured, base, theta)
    for name, unit, smoothed in deltas:
        if name == "dEGT":
            egt_ref = reference_egt(smoothed, ref.egt_reference_c, ref.theta_reference)
            out.append(("egt_margin", "degC", egt_redline_c - egt_ref))
        out.append((name, unit, smoothed))
    return out


def engineering_sigma(
    schedule: EngineSchedule,
    layout: EstimateLayout,
    z_sigma: np.ndarray,
    records: RecordConditions,
    delta_std: Mapping[str, float] | None = None,
    value_sigma: np.ndarray | None = None,
    trims: Mapping[str, np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """1-sigma [n] of each series of ``engineering_units`` that has one, in its unit.

    The estimated ones (thrust, stall margins, T40, bypass ratio and their changes) from the
    aux estimates' 1-sigma z_sigma [n, n_aux] (percent of the record's trim; honest when the
    trend has made it so with the design's calibration, ``Calibration.aux_sigma``); a value
    (not a change) from ``value_sigma`` [n, n_aux] (percent of trim, which holds its trim's
    interpolation error too: ``Calibration.value_sigma``; None: z_sigma). The measured ones
    (the smoothed deltas and the EGT margin) from the calibrated ``delta_std`` (name ->
    1-sigma of a settled record), grown over a trend's first records as the smoothing's noise
    is (``deltas.smoothing_growth``); without it they have none.
    """
    n = len(records.conditions)
    out: dict[str, np.ndarray] = {}
    if n == 0:
        return out
    if trims is None:
        trims = schedule_trims(schedule, records.conditions)
    aux = list(layout.aux)

    values = z_sigma if value_sigma is None else value_sigma

    def of(name: str, sigma: np.ndarray) -> np.ndarray | None:  # percent of trim
        if name not in aux or name not in trims:
            return None
        return np.asarray(sigma[:, aux.index(name)], float)

    def unit(name: str, sigma: np.ndarray) -> np.ndarray:  # percent of trim -> its unit
        return trims[name] * sigma / 100.0

    sz, sv = of(THRUST, z_sigma), of(THRUST, values)
    if sz is not None and sv is not None:
        fn = unit(THRUST, sv)
        out.update(Fn=fn, Fn_rated=100.0 * fn / type_reference(schedule).rated_thrust_lbf,
                   thrust_deficit=sz)
    for name in MARGINS:
        sm, sv = of(name, z_sigma), of(name, values)
        if sm is not None and sv is not None:
            out[name] = unit(name, sv)
            out[f"{name}_change"] = unit(name, sm)
    s40 = of(TURBINE_INLET, z_sigma)
    if s40 is not None:
        out["T40_change"] = unit(TURBINE_INLET, s40) / RANKINE_PER_KELVIN
    sb = of(BYPASS_RATIO, values)
    if sb is not None:
        out["BPR"] = unit(BYPASS_RATIO, sb)
    growth = smoothing_growth(n)
    for name, std in (delta_std or {}).items():
        sensor = DELTA_SOURCES.get(name)
        if sensor is not None and sensor in records.measured:
            out[name] = std * growth
    return out


def nominal_margin_c(schedule: EngineSchedule, egt_redline_c: float) -> float:
    """EGT margin of the nominal engine (dEGT = 0)."""
    return egt_redline_c - type_reference(schedule).egt_reference_c


def record_conditions(
    session: Session, engine_id: int, epoch: np.ndarray
) -> RecordConditions:
    """The snapshot of each estimate (engine, time) [n]: condition and measured sensors (NaN
    where no snapshot matches or a value is missing). The engine's snapshots from the first
    estimate's time on are read as the estimation reads them (``rows.load_records``: on
    PostgreSQL one binary value for all of them, not a row object each)."""
    n = len(epoch)
    cond = np.full((n, 4), np.nan)
    measured = {k: np.full(n, np.nan) for k in MEASURED_COLUMNS}
    if n == 0:
        return RecordConditions(cond, measured)
    after = datetime.fromtimestamp(float(np.min(epoch)) - 1.0, UTC)
    found = rows.load_records(session, [(engine_id, after)], list(MEASURED_COLUMNS.values()),
                              [])[engine_id]
    at = found.epoch
    if len(at) == 0:
        return RecordConditions(cond, measured)
    # Estimate and snapshot share (engine, recorded_at): match to the nearest within half a
    # second.
    i = np.clip(np.searchsorted(at, epoch), 1, len(at) - 1) if len(at) > 1 else (
        np.zeros(n, dtype=int))
    if len(at) > 1:
        left = i - 1
        closer = np.abs(at[left] - epoch) <= np.abs(at[i] - epoch)
        i = np.where(closer, left, i)
    hit = np.abs(at[i] - epoch) < 0.5
    cond[hit] = found.conditions[i[hit]]
    for k, name in enumerate(MEASURED_COLUMNS):
        measured[name][hit] = found.y[i[hit], k]
    return RecordConditions(cond, measured)
