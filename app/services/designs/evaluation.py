"""Monte Carlo evaluation of a stored estimator design, and the latest one for the dashboard.

The evaluation is the seed 002 Table 5 experiment (squared error of h_hat per health parameter,
Monte Carlo next to the design's analytic bias and variance) and the Tables 6-9 isolation
experiment (confusion matrices, percent) of ``estimation.evaluate``, run on the design's own
result document. It runs as an ``evaluate_design`` job; its result is the job's JSON result,
so the latest succeeded job of a design is its evaluation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.errors import Conflict
from app.models.jobs import Job
from app.services.designs.service import get_design
from estimation import evaluate as ev
from estimation.design import design_from_result
from estimation.isolation import Fault, faults_from_list
from estimation.model import LinearModel
from estimation.tuners import TunerDesign

EVALUATION_FORMAT = "fleethealth.evaluation/1"
JOB_KIND = "evaluate_design"
Progress = Callable[[float, str | None], None]


@dataclass(frozen=True)
class EvaluationInput:
    """What the experiments need from a stored design (read before the long computation)."""

    design_id: int
    design: TunerDesign
    truth: LinearModel | None
    faults: tuple[Fault, ...] | None


def evaluation_input(session: Session, *, operator_id: int, design_id: int) -> EvaluationInput:
    """The design's rebuilt filter, truth model and fault library; 404 / 409 as the API says."""
    design = get_design(session, operator_id=operator_id, design_id=design_id)
    if design.status != "ready" or design.result is None:
        raise Conflict(f"design {design.id} is {design.status}; only a ready design is evaluated")
    result = design.result
    truth = LinearModel.from_dict(result["source_model"]) if "source_model" in result else None
    library = (result.get("faults") or {}).get("library")
    faults = tuple(faults_from_list(library)) if library else None
    return EvaluationInput(design.id, design_from_result(result), truth, faults)


def run_evaluation(
    data: EvaluationInput,
    *,
    n_cases: int,
    duration_s: float,
    window_s: float,
    fault_duration_s: float,
    seed: int,
    start: str = "steady",
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Run the SSEE and isolation experiments; the evaluation dict (no database access).

    The isolation experiment needs a fault library that fits the design's model; where it
    does not, ``confusion`` is absent and ``isolation_note`` says why.
    """
    rng = np.random.default_rng(seed)

    def stage(lo: float, hi: float, label: str) -> Callable[[float], None]:
        def report(fraction: float) -> None:
            if progress is not None:
                progress(lo + (hi - lo) * float(fraction), label)

        return report

    mc = ev.ssee_monte_carlo(
        data.design, n_cases, rng=rng, duration=duration_s, window=window_s, start=start,
        progress=stage(0.0, 0.5, f"SSEE Monte Carlo ({n_cases} cases)"),
    )
    out: dict[str, Any] = {
        "format": EVALUATION_FORMAT,
        "design_id": data.design_id,
        "seed": seed,
        "monte_carlo": mc.to_dict(),
        "monte_carlo_settings": {
            "cases": n_cases, "duration_s": duration_s, "window_s": window_s, "start": start,
        },
    }
    try:
        iso = ev.isolation_experiment(
            data.design, data.faults, rng=rng, truth=data.truth, duration=fault_duration_s,
            progress=stage(0.5, 1.0, f"isolation ({fault_duration_s:g} s per fault)"),
        )
    except ValueError as exc:
        out["isolation_note"] = f"isolation experiment not possible: {exc}"
    else:
        out["confusion"] = {name: c.to_dict() for name, c in iso.confusion.items()}
        out["isolation_settings"] = {
            "duration_s": iso.duration, "runs_per_fault": iso.runs_per_fault,
        }
    if progress is not None:
        progress(1.0, "evaluation done")
    return out


def latest_evaluation(session: Session, *, operator_id: int, design_id: int) -> Job | None:
    """The newest succeeded ``evaluate_design`` job of a design (None: never evaluated).

    Raises NotFound for another operator's design.
    """
    get_design(session, operator_id=operator_id, design_id=design_id)
    jobs = session.scalars(
        select(Job)
        .where(Job.operator_id == operator_id, Job.kind == JOB_KIND, Job.status == "succeeded")
        .order_by(Job.finished_at.desc(), Job.id.desc())
        .limit(500)
    )
    # Parameters are JSON; matching in Python keeps the query the same on every backend.
    return next((job for job in jobs if job.parameters.get("design_id") == design_id), None)
