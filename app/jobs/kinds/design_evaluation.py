"""``evaluate_design``: Monte Carlo check of an estimator design (theory next to Monte Carlo,
confusion matrices), with progress for the dashboard."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.orm import Session

from app.services.designs import engine_evaluation as engine_run
from app.services.designs import evaluation
from app.services.jobs.registry import Progress, registry


class EvaluateDesign(BaseModel):
    model_config = ConfigDict(extra="forbid")

    design_id: int
    n_cases: int = Field(200, ge=2, le=5000, description="Monte Carlo cases of the SSEE run")
    duration_s: float = Field(30.0, gt=0, le=600, description="seconds per SSEE case")
    window_s: float = Field(10.0, gt=0, le=600, description="error window at the end, s")
    fault_duration_s: float = Field(300.0, gt=0, le=3600, description="seconds per fault case")
    seed: int = Field(0, ge=0)
    start: Literal["steady", "healthy"] = Field(
        "steady",
        description=(
            "steady: each case starts in the stationary regime the theory describes; healthy: "
            "seed 002's protocol, truth and filter from zero (slow tuners may not converge in "
            "duration_s, and the Monte Carlo then measures the transient as well)"
        ),
    )
    engine_run: bool = Field(
        True, description="also run the design on the built-in nonlinear engine's faulted fleet"
    )
    engine_per_fault: int = Field(
        25, ge=2, le=200, description="nonlinear engine: simulated engines per library fault"
    )
    engine_records_before: int = Field(
        30, ge=2, le=200, description="nonlinear engine: snapshots before the fault (baseline)"
    )
    engine_records_after: int = Field(
        20, ge=1, le=200, description="nonlinear engine: snapshots with the fault"
    )
    engine_signatures: Literal["linear", "secant"] = Field(
        "linear",
        description=(
            "fault signatures of the WSSR isolation on the nonlinear engine: linear (the "
            "scheduled gains at the nominal engine, as the pipeline isolates) or secant (the "
            "engine's own change from the estimated baseline)"
        ),
    )


@registry.job(
    evaluation.JOB_KIND,
    parameters=EvaluateDesign,
    description=(
        "Monte Carlo SSEE next to the design's theory, WSSR confusion matrices, and the "
        "design on the built-in nonlinear engine's faulted fleet."
    ),
    role="analyst",
)
def evaluate_design(
    session: Session, parameters: EvaluateDesign, progress: Progress, *, operator_id: int
) -> dict[str, Any]:
    data = evaluation.evaluation_input(
        session, operator_id=operator_id, design_id=parameters.design_id,
        engine_signatures=parameters.engine_signatures,
    )
    # End the read transaction before the long run: on SQLite a transaction that read before
    # a progress report committed could not write the result afterwards.
    session.commit()
    return evaluation.run_evaluation(
        data, n_cases=parameters.n_cases, duration_s=parameters.duration_s,
        window_s=parameters.window_s, fault_duration_s=parameters.fault_duration_s,
        seed=parameters.seed, start=parameters.start, progress=progress,
        engine_settings=engine_run.EngineRunSettings(
            engines_per_fault=parameters.engine_per_fault,
            records_before=parameters.engine_records_before,
            records_after=parameters.engine_records_after,
            signatures=parameters.engine_signatures, seed=parameters.seed,
        ) if parameters.engine_run else None,
    )
