"""Confidence per event: the posterior over the fault hypotheses, computed when it is read.

From the event's stored WSSR per hypothesis (seed 002 eq. 21-23: chi-squared for the right
fault, with the degrees of freedom and model-error margin of the isolation that computed it,
``wssr_fit``: m - 1 in tuner space for a design of m tuners, n - 1 for a sensor-space fit of n
values) and the measured confusion of the design that isolated it
(``estimation.posterior.fault_posterior``, p_i ∝ pi_i exp(-WSSR_i / 2 s) C_ij with j the
isolated fault and s that margin). The confusion is the design's latest evaluation on the
built-in nonlinear engine when there is one, else its linear Monte Carlo confusion (WSSR on
tuner estimates), else none (WSSR alone); ``source`` says which. With the nonlinear engine's
confusion, a sensor-space isolation's posterior is tempered as that evaluation fitted it on
events of known fault (p_i ∝ exp(-WSSR_i / 2 s) C_ij^beta, ``posterior.fit_tempering``): the
untempered product claimed 95 % where it was right 73 % of the time (bench_confidence.py).
The label names the fewest faults holding 90 % of the posterior ("HPT or Wf"); the ambiguity
group is the isolated fault and the faults the design's confusion mixes it with; the
confusion row is how the design isolates that fault.

A wear event is attributed among module deteriorations fitted with a positive magnitude (wear
is no actuator bias: ``estimation.wear.best_fault``), so its confidence ranks those hypotheses
only, with the confusion among them: the event stores them (``shift.wear.hypotheses``); one
stored before that ranks the design's module faults (``estimation.wear.wear_hypotheses``).
The faults left out are named (``left_out``), so the page can say when one of them fits the
change better than any wear hypothesis.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from scipy import stats
from sqlalchemy.orm import Session

from app.models.estimates import Event
from app.services.designs import engine_evaluation
from app.services.designs.evaluation import latest_evaluation
from app.services.designs.service import get_design
from app.services.snapshots.estimator import ISOLATION_LEVEL
from estimation.isolation import SEED_002_FAULTS
from estimation.posterior import Tempering, fault_posterior
from estimation.shift_detector import SENSOR_WSSR_MARGIN, sensor_fit_dof
from estimation.wear import explained, wear_hypotheses

CREDIBLE_MASS = 0.9
# A fault left out of a wear event's hypotheses fits its change clearly better than the
# isolated one below this share of the isolated fault's WSSR.
BETTER_FIT = 0.5
LIBRARY_ORDER = {f.name: i for i, f in enumerate(SEED_002_FAULTS)}
LINEAR_VARIANT = "wssr_q"  # the pipeline isolates on tuner estimates
SOURCES = {
    "nonlinear_engine": "the design's measured confusion on the built-in nonlinear engine",
    "linear_monte_carlo": "the design's linear Monte Carlo confusion (no nonlinear-engine run)",
    "wssr_only": "WSSR alone: the design has no evaluation with a confusion matrix",
}


@dataclass(frozen=True)
class DesignEvidence:
    """What an event's confidence needs from its design: tuners, confusion, where from."""

    n_tuners: int
    source: str
    faults: tuple[str, ...] | None = None
    confusion: np.ndarray | None = None  # percent, rows true, columns isolated
    not_visible: tuple[str, ...] = ()
    evaluation_job_id: int | None = None
    wear_faults: tuple[str, ...] | None = None  # the design's module faults (wear_hypotheses)
    # The nonlinear-engine evaluation's tempering of a sensor-space isolation's posterior
    # (None: an evaluation stored before it, or none on the engine).
    tempering: Tempering | None = None


def design_evidence(session: Session, operator_id: int, design_id: int) -> DesignEvidence:
    """The design's tuner count and its best measured confusion (see the module docstring)."""
    design = get_design(session, operator_id=operator_id, design_id=design_id)
    design_result: Mapping[str, Any] = design.result or {}
    n_tuners = len(design_result.get("vstar") or []) or 1
    library = (design_result.get("faults") or {}).get("library")
    wear_faults = None if not library else wear_hypotheses(
        [(f["name"], f["shifts"]) for f in library], design_result.get("health") or ())
    job = latest_evaluation(session, operator_id=operator_id, design_id=design_id)
    result: Mapping[str, Any] = (job.result or {}) if job is not None else {}
    engine = result.get(engine_evaluation.RESULT_KEY)
    if engine:
        tempered = engine.get("posterior")
        return DesignEvidence(
            n_tuners, "nonlinear_engine", tuple(engine["faults"]),
            np.asarray(engine["confusion_percent"], float),
            tuple(engine.get("visibility", {}).get("not_visible", ())), job.id if job else None,
            wear_faults, Tempering.from_dict(tempered) if tempered else None,
        )
    linear = (result.get("confusion") or {}).get(LINEAR_VARIANT)
    if linear:
        return DesignEvidence(
            n_tuners, "linear_monte_carlo", tuple(linear["faults"]),
            np.asarray(linear["percent"], float), (), job.id if job else None, wear_faults,
        )
    return DesignEvidence(n_tuners, "wssr_only", wear_faults=wear_faults)


def hypotheses(event: Event, evidence: DesignEvidence, faults: tuple[str, ...]) -> tuple[str, ...]:
    """The faults of ``faults`` (the event's WSSR) that its confidence ranks: all of them, or
    for a wear event those its attribution chose from (see the module docstring); all of
    them where that leaves none."""
    if event.kind != "wear":
        return faults
    stored = ((event.shift or {}).get("wear") or {}).get("hypotheses")
    chosen = stored if stored else evidence.wear_faults
    kept = tuple(f for f in faults if chosen is not None and f in chosen)
    return kept or faults


class WssrFit(NamedTuple):
    """How a right fault's WSSR of an event is distributed: chi-squared with ``dof`` degrees of
    freedom once divided by ``scale``; ``sensor_space``: the fit was the shift detector's in
    sensor space (the kind the design's nonlinear-engine run measures and tempers)."""

    dof: int
    scale: float
    sensor_space: bool


def wssr_fit(event: Event, evidence: DesignEvidence) -> WssrFit:
    """The chi-squared degrees of freedom of a right fault's WSSR, and the model-error scale it
    is divided by (``fault_posterior``'s dof and scale): stored with an abrupt event (the shift
    detector's isolation, ``Isolation.wssr_dof``: in tuner space m - 1 at scale 1; in sensor
    space the fit's n - 1 values, held to its margin); for one stored before them, a threshold
    other than the tuner space's quantile is a sensor-space fit's, read back to its n - 1; a
    wear event's WSSR (tuner space, weighted as the health change) takes m - 1."""
    shift = event.shift or {}
    tuner = max(evidence.n_tuners - 1, 1)
    if shift.get("wssr_dof"):
        scale = float(shift.get("wssr_scale") or 1.0)
        return WssrFit(int(shift["wssr_dof"]), scale, scale != 1.0)
    threshold = shift.get("wssr_threshold")
    if event.kind == "wear" or threshold is None or np.isclose(
            float(threshold), stats.chi2.ppf(ISOLATION_LEVEL, tuner), rtol=1e-9):
        return WssrFit(tuner, 1.0, False)
    return WssrFit(sensor_fit_dof(float(threshold)), SENSOR_WSSR_MARGIN, True)


def _explained(event: Event, wssr: float) -> float | None:
    """For a wear event, the share of its accumulated change that a fault of this WSSR
    explains (``estimation.wear.explained``): the change weighed as its health change
    (W = V*^+T V*^+, so d^T W d is the sum of the stored health change's squares). None for
    other events, or no change."""
    if event.kind != "wear":
        return None
    health = np.fromiter(((event.shift or {}).get("health") or {}).values(), float)
    total = float(health @ health)
    return None if total <= 0 else float(explained(wssr, total))


def event_confidence(event: Event, evidence: DesignEvidence) -> dict[str, Any] | None:
    """The ``confidence`` of an event (``EventConfidence``); None without stored WSSR."""
    wssr_map = {k: float(v) for k, v in (event.wssr or {}).items()}
    if not wssr_map:
        return None
    # JSON objects come back in another key order from PostgreSQL: the library's order.
    every = tuple(sorted(wssr_map, key=lambda f: (LIBRARY_ORDER.get(f, len(LIBRARY_ORDER)), f)))
    faults = hypotheses(event, evidence, every)
    wssr = np.array([wssr_map[f] for f in faults])
    source, C = evidence.source, None
    if evidence.confusion is not None and evidence.faults is not None:
        # Measured on the event's library: its rows and columns of the ranked hypotheses (a
        # wear event's module faults: P(isolated j | true i) renormalised over them).
        if set(evidence.faults) == set(every):
            order = [evidence.faults.index(f) for f in faults]
            C = evidence.confusion[np.ix_(order, order)]
        else:
            source = "wssr_only"  # the confusion was measured on another fault library
    dof, scale, sensor_space = wssr_fit(event, evidence)
    # A sensor-space isolation, the kind the design's nonlinear-engine run measures: its
    # posterior tempered as fitted there (the WSSR scale, the confusion's weight); the fit's
    # own tail probability keeps the isolation's margin.
    tempering = (evidence.tempering
                 if sensor_space and event.kind != "wear" and C is not None
                 and evidence.source == "nonlinear_engine"
                 else None)
    post = fault_posterior(
        wssr, dof, faults, confusion=C,
        scale=scale if tempering is None else tempering.scale,
        confusion_power=1.0 if tempering is None else tempering.confusion_power)
    isolated = faults[int(post.isolated)]
    out: dict[str, Any] = {
        "source": source,
        "source_note": SOURCES[source],
        "evaluation_job_id": evidence.evaluation_job_id if C is not None else None,
        "faults": list(faults),
        "posterior": post.posterior.tolist(),
        "wssr_posterior": post.wssr_only.tolist(),
        "isolated": isolated,
        "probability": float(post.posterior[int(post.isolated)]),
        "label": post.label(CREDIBLE_MASS)[0],
        "credible_mass": CREDIBLE_MASS,
        "fit_probability": float(stats.chi2.sf(wssr.min() / scale, dof)),
        "tempering": None if tempering is None else tempering.to_dict(),
        "fit_level": 1.0 - ISOLATION_LEVEL,
        "ambiguity_group": [isolated],
        "confusion_row": None,
        "not_visible": [f for f in evidence.not_visible if f in faults],
        "left_out": [f for f in every if f not in faults],
        "fits_better": [f for f in every if f not in faults
                        and wssr_map[f] < BETTER_FIT * wssr_map[isolated]],
        "explained": _explained(event, wssr_map[isolated]),
    }
    if C is not None:
        # The isolated fault and those it is confused with directly (C_ij + C_ji above the
        # threshold): the connected component of ``ambiguity_groups`` can chain a weak design's
        # confusions into most of the library, which says nothing about this event.
        j = faults.index(isolated)
        mixed = (C[:, j] + C[j, :]) > engine_evaluation.AMBIGUITY_PERCENT
        out["ambiguity_group"] = [f for i, f in enumerate(faults) if i == j or mixed[i]]
        row = faults.index(event.fault) if event.fault in faults else int(post.isolated)
        out["confusion_row"] = {
            "true_fault": faults[row], "faults": list(faults), "percent": C[row].tolist(),
        }
    return out
