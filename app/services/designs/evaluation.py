"""Monte Carlo evaluation of a stored estimator design, and the latest one for the dashboard.

The evaluation is the seed 002 Table 5 experiment (squared error of h_hat per health parameter,
Monte Carlo next to the design's analytic bias and variance) and the Tables 6-9 isolation
experiment (confusion matrices, percent) of ``estimation.evaluate``, run on the design's own
result document; for a design of the built-in engine, also the run on the nonlinear engine's
faulted fleet (``engine_evaluation``, under its own key ``nonlinear_engine``). It runs as an
``evaluate_design`` job; its result is the job's JSON result, so the latest succeeded job of a
design is its evaluation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.errors import Conflict
from app.models import EngineModel
from app.models.jobs import Job
from app.services.designs import engine_evaluation as engine_run
from app.services.designs.service import get_design
from estimation import evaluate as ev
from estimation.design import design_from_result
from estimation.engine.schedule import EngineSchedule
from estimation.evaluate_engine import EngineDesign
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
    engine: EngineDesign | None = None  # the design on the built-in nonlinear engine
    engine_note: str | None = None  # why ``engine`` is None
    health: tuple[str, ...] = ()


def evaluation_input(
    session: Session, *, operator_id: int, design_id: int, engine_signatures: str = "linear"
) -> EvaluationInput:
    """The design's rebuilt filter, truth model, fault library and (built-in engine only) its
    form for the nonlinear-engine run; 404 / 409 as the API says."""
    design = get_design(session, operator_id=operator_id, design_id=design_id)
    if design.status != "ready" or design.result is None:
        raise Conflict(f"design {design.id} is {design.status}; only a ready design is evaluated")
    result = design.result
    truth = LinearModel.from_dict(result["source_model"]) if "source_model" in result else None
    library = (result.get("faults") or {}).get("library")
    faults = tuple(faults_from_list(library)) if library else None
    model_row = session.get(EngineModel, design.engine_model_id)
    engine, note = engine_run.engine_design(
        result, source=model_row.source if model_row is not None else "unknown",
        name=design.name, signatures=engine_signatures,
    )
    return EvaluationInput(
        design.id, design_from_result(result), truth, faults, engine, note,
        tuple(result.get("health") or ()),
    )


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
    engine_settings: engine_run.EngineRunSettings | None = None,
    schedule: Callable[[], EngineSchedule] | None = None,
) -> dict[str, Any]:
    """Run the SSEE and isolation experiments, and the nonlinear-engine run; the evaluation
    dict (no database access).

    The isolation experiment needs a fault library that fits the design's model; where it
    does not, ``confusion`` is absent and ``isolation_note`` says why. The nonlinear-engine
    run needs a design of the built-in engine (``schedule`` gives that engine's scheduled
    linear models, the built-in cache by default); where it is not one, or the run is
    skipped (``engine_settings`` None), ``nonlinear_engine`` is null and
    ``nonlinear_engine_note`` says why.
    """
    rng = np.random.default_rng(seed)

    def stage(lo: float, hi: float, label: str) -> Callable[[float], None]:
        def report(fraction: float) -> None:
            if progress is not None:
                progress(lo + (hi - lo) * float(fraction), label)

        return report

    mc = ev.ssee_monte_carlo(
        data.design, n_cases, rng=rng, duration=duration_s, window=window_s, start=start,
        progress=stage(0.0, 0.4, f"SSEE Monte Carlo ({n_cases} cases)"),
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
            progress=stage(0.4, 0.7, f"isolation ({fault_duration_s:g} s per fault)"),
        )
    except ValueError as exc:
        out["isolation_note"] = f"isolation experiment not possible: {exc}"
    else:
        out["confusion"] = {name: c.to_dict() for name, c in iso.confusion.items()}
        out["isolation_settings"] = {
            "duration_s": iso.duration, "runs_per_fault": iso.runs_per_fault,
        }
    out[engine_run.RESULT_KEY] = None
    if engine_settings is None:
        out[engine_run.NOTE_KEY] = "the nonlinear-engine run was not requested"
    elif data.engine is None:
        out[engine_run.NOTE_KEY] = data.engine_note
    else:
        if schedule is None:
            from app.services.snapshots.estimator import builtin_schedule

            schedule = builtin_schedule

        def engine_progress(fraction: float, label: str | None) -> None:
            if progress is not None:
                progress(0.7 + 0.3 * fraction, label)

        try:
            out[engine_run.RESULT_KEY] = engine_run.run_engine_evaluation(
                data.engine, schedule(), data.health, engine_settings, progress=engine_progress,
            )
        except np.linalg.LinAlgError as exc:
            out[engine_run.NOTE_KEY] = (
                f"the design's baseline fit is singular on the nonlinear engine ({exc})"
            )
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
