"""A design judged on the built-in nonlinear engine: part of the ``evaluate_design`` job.

The linear Monte Carlo (``app.services.designs.evaluation``) runs on the model the design was
made from, where theory and experiment agree by construction. This run puts the design on the
truth the demo's fleet flies: ``estimation.evaluate_engine`` simulates a fleet of the built-in
engine (manufacturing scatter, deterioration, actuator biases) over the envelope, each engine
given one of the seed 002 Table 3 faults after ``records_before`` snapshots, and scores the
design's baseline health (RMS and 95 % coverage against the true health) and its WSSR
isolation (seed 002 eq. 21-23: confusion matrix, percent correct).

How much of each fault the snapshots can show at all is measured beside it
(``evaluate_engine.fault_sigmas``: the fault's sensor change in noise sigmas, root sum of
squares over the event's records). A fault whose median event signature is below
``VISIBLE_SIGMAS`` cannot be isolated by any design (on the built-in engine the VBV bias, and
nearly the VSV bias): the result names those faults and gives the percent correct over the
visible faults too, the ceiling the faults' evidence allows when those under one sigma are
isolated at chance (``evaluate_engine.chance_ceiling``; 89.1 % of the eight on the built-in
engine, where the VBV bias shows 0.04 sigma over an event; with each fault's magnitude held
to the library's range the VBV bias is named by elimination, so the percent correct can pass
it, and the percent named on evidence, as the product names faults, is given beside it), and
the ambiguity groups
(``estimation.posterior.ambiguity_groups``, among the visible faults) name the faults the
design confuses.

The events' confidence is tempered on a second faulted fleet of the same run
(``posterior.fit_tempering``): the WSSR scale and the confusion's weight that make the
posterior right as often as it says there, stored as ``posterior`` and read by the event page
(``app.services.events.confidence``).

Only designs of the built-in engine (engine model source ``builtin``, health parameters of the
built-in engine) are run; for others the result says why the run is absent.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimation import evaluate_engine as ee
from estimation import isolation
from estimation.engine.health import HEALTH_NAMES
from estimation.engine.schedule import EngineSchedule
from estimation.engine.sensors import SENSOR_NAMES
from estimation.posterior import ambiguity_groups, fit_tempering
from estimation.shift_detector import SENSOR_WSSR_MARGIN

RESULT_KEY = "nonlinear_engine"
NOTE_KEY = "nonlinear_engine_note"
VISIBLE_SIGMAS = 3.0  # median event signature (noise sigmas) for a fault to count as visible
AMBIGUITY_PERCENT = 10.0  # C_ij + C_ji above which two faults form an ambiguity group
TEMPERING_FLEETS = 3  # the tempering's fleet: this many times the confusion's engines per fault
TURBOMACHINERY = HEALTH_NAMES[:10]
Progress = Callable[[float, str | None], None]


@dataclass(frozen=True)
class EngineRunSettings:
    """How big the nonlinear-engine run is (the job's parameters)."""

    engines_per_fault: int = 25
    records_before: int = 30
    records_after: int = 20
    signatures: str = "linear"
    seed: int = 0


def engine_design(
    result: Mapping[str, Any], *, source: str, name: str, signatures: str = "linear"
) -> tuple[ee.EngineDesign | None, str | None]:
    """The design as the engine run scores it, or (None, why it cannot be run).

    V* is spread over the engine's 13 health parameters (zero columns for those the design
    does not estimate); fuel flow is a sensor at the closed-loop gain when the design has
    the Wf sensor, else a measured input (the product's pipeline).
    """
    if source != "builtin":
        return None, (
            "the nonlinear-engine run needs a design of the built-in engine; this design's "
            f"engine model was {source}, and fleethealth has no nonlinear model of that engine"
        )
    sensors = list(result.get("sensors") or [])
    health = list(result.get("health") or [])
    unknown = [s for s in sensors if s not in SENSOR_NAMES] + [
        h for h in health if h not in HEALTH_NAMES
    ]
    if unknown:
        return None, f"signals {unknown} are not the built-in engine's"
    vstar = np.asarray(result.get("vstar"), float)
    if vstar.ndim != 2 or vstar.shape[1] != len(health):
        return None, "the design's V* does not match its health parameters"
    full = np.zeros((vstar.shape[0], len(HEALTH_NAMES)))
    full[:, [HEALTH_NAMES.index(h) for h in health]] = vstar
    wf = "sensor" if "Wf" in sensors else "input"
    try:
        return ee.EngineDesign(name, tuple(sensors), full, wf=wf, signatures=signatures), None
    except ee.EngineEvaluationError as exc:
        return None, str(exc)


def run_engine_evaluation(
    design: ee.EngineDesign,
    schedule: EngineSchedule,
    health: tuple[str, ...],
    settings: EngineRunSettings,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Simulate the faulted fleet, score the design, measure each fault's visibility; the
    ``nonlinear_engine`` dict of the evaluation result (JSON-ready).

    health: the design's health parameters (reported beside the ten turbomachinery ones).
    Raises numpy.linalg.LinAlgError when the design's baseline fit is singular on the engine.
    """

    def report(fraction: float, label: str) -> None:
        if progress is not None:
            progress(fraction, label)

    rng = np.random.default_rng(settings.seed)
    faults = isolation.SEED_002_FAULTS
    n = settings.engines_per_fault
    report(0.0, f"nonlinear engine: simulating {n * len(faults)} engines")
    rec = ee.simulate_records(
        n, rng=rng, faults=faults, n_before=settings.records_before,
        n_after=settings.records_after,
    )
    report(0.4, "nonlinear engine: fault signatures in noise sigmas")
    event_sigmas = np.sqrt(np.sum(ee.fault_sigmas(rec) ** 2, axis=1))  # [E]
    median = np.array([np.median(event_sigmas[rec.fault == i]) for i in range(len(faults))])
    visible = median >= VISIBLE_SIGMAS
    report(0.6, f"nonlinear engine: isolating with {design.signatures} signatures")
    result = ee.evaluate_design(design, rec, schedule)
    conf = np.nan_to_num(result.confusion)
    # The event confidence's tempering, fitted on a second faulted fleet (not the one the
    # confusion was measured on): how far to trust the WSSR and the confusion together.
    report(0.7, "nonlinear engine: tempering the event confidence on a second fleet")
    second = ee.evaluate_design(design, ee.simulate_records(
        TEMPERING_FLEETS * n, rng=rng, faults=faults, n_before=settings.records_before,
        n_after=settings.records_after), schedule)
    tempering = fit_tempering(second.wssr, second.dof, second.true_fault, result.faults,
                              conf, SENSOR_WSSR_MARGIN)
    diag = np.diag(conf)
    # Groups among the visible faults: an invisible fault is isolated by elimination or at
    # random, and its row would chain every fault into one group.
    vis_idx = np.flatnonzero(visible)
    vis_names = [result.faults[i] for i in vis_idx]
    groups = ambiguity_groups(conf[np.ix_(vis_idx, vis_idx)], vis_names, AMBIGUITY_PERCENT)
    rows = [sum(conf[i, result.faults.index(g)] for g in groups.group_of(result.faults[i]))
            for i in vis_idx]
    shown = [h for h in HEALTH_NAMES if h in TURBOMACHINERY or h in health]
    idx = [HEALTH_NAMES.index(h) for h in shown]
    turbo = [HEALTH_NAMES.index(h) for h in TURBOMACHINERY]
    # The least 1-sigma the design's sensors allow from the same records as the baseline
    # (records_before, half take-off, half cruise): how far the design is from the bound.
    per_phase = max(settings.records_before // len(ee.DEFAULT_PHASES), 1)
    floors = ee.information_floors(schedule, design.sensors, per_phase)
    report(1.0, "nonlinear engine done")
    return {
        "engine": "built-in two-spool turbofan (estimation.engine), seed 002 Table 3 faults",
        "settings": {
            "engines_per_fault": n,
            "records_before": settings.records_before,
            "records_after": settings.records_after,
            "phases": list(ee.DEFAULT_PHASES),
            "signatures": design.signatures,
            "wf": design.wf,
            "seed": settings.seed,
        },
        "faults": list(result.faults),
        "confusion_percent": np.round(conf, 2).tolist(),
        "percent_correct": float(np.mean(diag)),
        # counting only the faults named on evidence, as the product names them (a fault of
        # no signature is isolated here by elimination, never in service)
        "percent_correct_on_evidence": result.percent_on_evidence,
        "visibility": {
            "threshold_sigmas": VISIBLE_SIGMAS,
            "event_sigmas": np.round(median, 3).tolist(),
            "visible": [f for f, v in zip(result.faults, visible, strict=True) if v],
            "not_visible": [f for f, v in zip(result.faults, visible, strict=True) if not v],
            "percent_correct_visible": float(np.mean(diag[visible])) if visible.any() else None,
            # the most the faults' evidence allows: those under one sigma at chance (with the
            # magnitudes held to the library's range, a fault of no signature is named by
            # elimination, so percent_correct can pass it; percent_correct_on_evidence cannot)
            "ceiling_percent_correct": ee.chance_ceiling(median),
        },
        "ambiguity_groups": [list(g) for g in groups.groups if len(g) > 1],
        # An event's confidence: p_i ∝ exp(-WSSR_i / 2 s) C_ij^beta, s and beta fitted on the
        # second fleet's events (``posterior.fit_tempering``).
        "posterior": tempering.to_dict(),
        "group_percent_correct": float(np.mean(rows)) if rows else None,
        "health": {
            "names": shown,
            "rms": result.health_rms[idx].tolist(),
            "coverage_95": result.coverage[idx].tolist(),
            "rms_turbomachinery": float(np.sqrt(np.mean(result.health_rms[turbo] ** 2))),
            "coverage_turbomachinery": float(np.mean(result.coverage[turbo])),
            # The least 1-sigma the design's sensors allow each level from the baseline's
            # records (``evaluate_engine.information_floors``).
            "floor": np.round(floors[idx], 4).tolist(),
            "floor_records": per_phase * len(ee.DEFAULT_PHASES),
        },
        "n_engines": int(len(rec.fault)),
    }
