"""NASA C-MAPSS FD001 through the pipeline's own filter, in memory (no database).

The rows become each unit's snapshots exactly as ``fleethealth import-cmapss`` uploads them
(``app.cli.importers.cmapss_snapshots``: one take-off snapshot per cycle, sensors in C-MAPSS
units converted to the stored ones as the ingest does), a design on the built-in engine at
FD001's operating condition (the one of tests/app/test_fd001.py: SVD, 7 tuners, the seven
C-MAPSS sensors the built-in engine has, the ten turbomachinery health parameters) and
``pipeline.run_filters`` as after an upload. Used by bench/bench_wear.py and the wear tests.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.cli.importers import CMAPSS_SENSORS, cmapss_snapshots, read_cmapss, select_units
from app.services import units
from app.services.designs import service as designs
from app.services.snapshots import detector, estimator
from app.services.snapshots import run as snapshots_run
from estimation.engine.schedule import EngineSchedule, build_schedule
from estimation.model import LinearModel
from estimation.snapshot import snapshot_deviation
from estimation.wear import WearSettings

# FD001 flies one condition (sea level static, TRA 100): a small grid around it.
FD001_AXES = {"alt": (0.0, 2000.0), "mach": (0.0, 0.1), "power": (90.0, 100.0)}
FD001_POINT = (0.0, 0.0, 100.0)  # alt ft, Mach, power %: where the design model is linearised
FD001_TUNERS = 7


def fd001_schedule() -> EngineSchedule:
    """The built-in engine's schedule on ``FD001_AXES`` (about a second to build)."""
    return build_schedule(dict(FD001_AXES))


def fd001_design_spec(model: LinearModel, tuners: int = FD001_TUNERS) -> dict[str, Any]:
    """The design spec an FD001 user starts with (also what ``import-cmapss`` should create):
    SVD tuners over the ten turbomachinery health parameters, the C-MAPSS sensors."""
    return {
        "format": "fleethealth.design-spec/1", "method": "svd", "tuners": tuners,
        "sensors": list(CMAPSS_SENSORS), "health": list(model.health_names[:10]),
        "noise": {"Q": 1e-4, "Qh": 1e-4, "Ph": 4.0},
    }


def fd001_estimator(
    sched: EngineSchedule, tuners: int = FD001_TUNERS
) -> estimator.SnapshotEstimator:
    """The design's estimator, as ``estimator_for_design`` builds it for a built-in model."""
    model = sched.model_at(*FD001_POINT)
    result = designs.design_step(model, fd001_design_spec(model, tuners))
    embedded = LinearModel.from_dict(result["model"])
    return estimator.build_estimator(
        0, embedded, result, estimator.engine_schedule_for(embedded, sched)
    )


@dataclass(frozen=True)
class Fd001Engine:
    """One unit's pipeline run; cycle [S] is C-MAPSS's cycle count (the last one fails)."""

    unit: int
    cycle: np.ndarray
    run: snapshots_run.EngineRun


def fd001_runs(
    path: Path, est: estimator.SnapshotEstimator, n_units: int | None = None
) -> list[Fd001Engine]:
    """The first ``n_units`` units (all: None) as pipeline runs from a fresh state."""
    data, unit_ids = select_units(read_cmapss(path), n_units)
    table = cmapss_snapshots(data)
    col = {name: table[name].to_numpy() for name in table.column_names}
    cond = np.stack([col["alt_ft"], col["mach"], col["dtamb_k"], col["power_pct"]], axis=1)
    by_column = {spec.column: spec for spec in estimator.SNAPSHOT_SIGNALS.values()}
    upload = {v.split("[")[0]: v for v in CMAPSS_SENSORS.values()}
    y = np.full((len(data), len(est.sensor_columns)), np.nan)
    for i, column in enumerate(est.sensor_columns):
        spec = by_column.get(column)
        if spec is None or spec.name not in upload:
            continue
        unit = upload[spec.name].split("[")[1].rstrip("]")
        a, b = units.affine(spec.quantity, unit, spec.unit, reference=spec.percent_reference)
        y[:, i] = a * col[upload[spec.name]] + b
    u = np.full((len(data), len(est.input_columns)), np.nan)
    epoch = col["recorded_at"].astype("datetime64[s]").astype(np.int64).astype(float)
    out = []
    for k, unit_id in enumerate(unit_ids):
        idx = np.flatnonzero(data[:, 0].astype(int) == unit_id)
        run = snapshots_run.EngineRun(
            engine_id=k, operator_id=0, seq0=0, state=snapshots_run.PipelineState.initial(est),
            epoch=epoch[idx], phase=["takeoff"] * len(idx), conditions=cond[idx], y=y[idx],
            u=u[idx], maintenance=np.zeros(0),
        )
        out.append(Fd001Engine(unit_id, data[idx, 1].astype(int), run))
    return out


@dataclass(frozen=True)
class FilterTrack:
    """One engine's filter output: q_hat [S, m], the final filter covariance P [m, m] (the
    filter's steady state on one condition), h_hat [S, p] and the product's events."""

    q: np.ndarray
    P: np.ndarray
    h: np.ndarray
    events: tuple[detector.EventDraft, ...]
    drift: tuple[float, ...] | None = None  # the wear drift after the run (``latest_drift``)


def filter_tracks(
    est: estimator.SnapshotEstimator, runs: Sequence[snapshots_run.EngineRun], batch: int = 64,
    wear_settings: WearSettings | None = None,
) -> list[FilterTrack]:
    """``pipeline.run_filters`` over the runs, in batches, unpacked per engine; each batch's
    fleet direction also learns from the earlier batches' drifts (as a job's batches read
    the stored states of the engines estimated before them); ``wear_settings`` the wear
    detector's (None: the product's)."""
    s = est.layout.slices()
    out: list[FilterTrack] = []
    fleet: list[tuple[float, ...]] = []  # the earlier batches' drifts, as a job reads them
    for start in range(0, len(runs), batch):
        results = snapshots_run.run_filters(est, list(runs[start : start + batch]),
                                            fleet=list(fleet), wear_settings=wear_settings)
        fleet += [r.state.wear.drift for r in results if r.state.wear.drift is not None]
        for res in results:
            values = res.packed.astype(np.float64)
            P = np.asarray(res.state.filter.P, float).reshape(-1, est.m, est.m)[-1]
            out.append(FilterTrack(values[:, s["q"]], P, values[:, s["h"]], tuple(res.events),
                                   res.state.wear.drift))
    return out


def sensor_deviations(
    est: estimator.SnapshotEstimator, run: snapshots_run.EngineRun
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A run's sensor deviations dy [S, ny] (percent of trim, as the filter sees them), the
    noise variance [S, ny] (percent^2, with the model error) and each library fault's sensor
    signature [S, ny, n_faults] at the record's condition."""
    g = est.schedule(run.conditions)
    u_dev = 100.0 * (run.u - g.u_trim) / g.u_trim
    u_dev = np.where(np.isfinite(u_dev), u_dev, 0.0)
    dy = snapshot_deviation(run.y, g.y_trim, g.G_u, u_dev)
    noise = est.noise_std if g.noise_std is None else np.sqrt(
        g.noise_std**2 + estimator.MODEL_ERROR**2)
    var = np.broadcast_to(noise**2, dy.shape)
    return dy, var, est.fault_signatures(g.G_y, g.G_u)
