"""Estimator designs: create, run, activate; the design step of the estimation core."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from typing import Any

from sqlalchemy import select, update
from sqlalchemy.orm import Session

from app.errors import Conflict, InvalidInput
from app.models import Engine, EngineModel, EngineType, EstimatorDesign, Snapshot
from app.models.base import utcnow
from app.services.common import owned, paginate, referenced
from app.services.designs.engine_models import (
    get_engine_model,
    load_linear_model,
)
from app.services.snapshots import backlog
from estimation.design import parse_spec
from estimation.design import run_design as run_spec
from estimation.model import LinearModel

# The job kind that makes a design created in the background.
DESIGN_JOB = "create_design"

# The estimation core's design step: (model, spec) -> fleethealth.design/1 dict.
DesignStep = Callable[[LinearModel, Mapping[str, Any]], Mapping[str, Any]]


def create_design(
    session: Session, *, operator_id: int, engine_model_id: int, name: str, spec: Mapping[str, Any]
) -> EstimatorDesign:
    """A pending design of ``spec`` on an engine model; ``complete_design`` fills it in."""
    model_row = referenced(
        session, EngineModel, operator_id, engine_model_id, "engine_model_id", "engine model"
    )
    if model_row.locked_at is None:
        model_row.locked_at = utcnow()
    row = EstimatorDesign(
        operator_id=operator_id,
        engine_type_id=model_row.engine_type_id,
        engine_model_id=model_row.id,
        name=name,
        spec=dict(spec),
        status="pending",
    )
    session.add(row)
    session.flush()
    return row


def check_spec(session: Session, design: EstimatorDesign) -> None:
    """Validate the design's spec against its model now (fast), or 422 naming the key."""
    model = load_linear_model(
        get_engine_model(
            session, operator_id=design.operator_id, engine_model_id=design.engine_model_id
        )
    )
    try:
        parse_spec(design.spec, model)
    except (ValueError, KeyError, TypeError) as exc:
        reason = str(exc) if str(exc) else type(exc).__name__
        raise InvalidInput(
            f"spec: {reason}", details=[{"location": ["body", "spec"], "reason": reason}]
        ) from None


def run_pending_design(
    session: Session,
    *,
    operator_id: int,
    design_id: int,
    step: DesignStep | None = None,
) -> EstimatorDesign:
    """Design a pending design (the ``create_design`` job); a ready or failed one is left as
    it is, so running twice changes nothing. A spec the design step refuses marks the design
    failed with the reason."""
    design = get_design(session, operator_id=operator_id, design_id=design_id)
    if design.status != "pending":
        return design
    try:
        return run_design(session, design, step or design_step)
    except InvalidInput as exc:
        return fail_design(session, design, exc.message)


def complete_design(
    session: Session, design: EstimatorDesign, result: Mapping[str, Any]
) -> EstimatorDesign:
    """Store a ``fleethealth.design/1`` result and its analytic errors; status ready."""
    theory = result.get("theory")
    errors = dict(theory) if isinstance(theory, Mapping) else None
    design.result = json.loads(json.dumps(result, allow_nan=False))
    design.analytic_errors = errors
    design.ssee_health = _number(errors, "ssee_health")
    design.ssee_aux = _number(errors, "ssee_aux")
    design.status = "ready"
    design.failure = None
    design.completed_at = utcnow()
    session.flush()
    return design


def fail_design(session: Session, design: EstimatorDesign, reason: str) -> EstimatorDesign:
    design.status = "failed"
    design.failure = reason
    design.completed_at = utcnow()
    session.flush()
    return design


def run_design(session: Session, design: EstimatorDesign, step: DesignStep) -> EstimatorDesign:
    """Run the design step on the design's model and spec; a bad spec is a 422, nothing kept."""
    model = load_linear_model(
        get_engine_model(
            session, operator_id=design.operator_id, engine_model_id=design.engine_model_id
        )
    )
    try:
        result = step(model, design.spec)
    except (ValueError, KeyError, TypeError) as exc:
        # DesignSpecError, UnknownSignalError, DimensionError, UnobservableDesignError...
        reason = str(exc) if str(exc) else type(exc).__name__
        raise InvalidInput(
            f"spec: {reason}", details=[{"location": ["body", "spec"], "reason": reason}]
        ) from None
    return complete_design(session, design, result)


def _number(document: Mapping[str, Any] | None, key: str) -> float | None:
    value = (document or {}).get(key)
    return float(value) if isinstance(value, int | float) else None


def get_design(session: Session, *, operator_id: int, design_id: int) -> EstimatorDesign:
    return owned(session, EstimatorDesign, operator_id, design_id, "design")


def list_designs(
    session: Session,
    *,
    operator_id: int,
    limit: int,
    offset: int,
    engine_type_id: int | None = None,
    engine_model_id: int | None = None,
    active: bool | None = None,
) -> tuple[list[EstimatorDesign], int]:
    stmt = select(EstimatorDesign).where(EstimatorDesign.operator_id == operator_id)
    if engine_type_id is not None:
        stmt = stmt.where(EstimatorDesign.engine_type_id == engine_type_id)
    if engine_model_id is not None:
        stmt = stmt.where(EstimatorDesign.engine_model_id == engine_model_id)
    if active is not None:
        stmt = stmt.where(EstimatorDesign.active.is_(active))
    stmt = stmt.order_by(EstimatorDesign.created_at.desc(), EstimatorDesign.id.desc())
    return paginate(session, stmt, limit=limit, offset=offset)


def activate_design(session: Session, *, operator_id: int, design_id: int) -> EstimatorDesign:
    """Make a ready design the one in service for its engine type (the previous one retires)."""
    design = get_design(session, operator_id=operator_id, design_id=design_id)
    if design.status != "ready":
        raise Conflict(f"design {design.id} is {design.status}; only a ready design can be active")
    # Lock the engine type so two activations of one type run one after the other.
    session.scalar(
        select(EngineType.id).where(EngineType.id == design.engine_type_id).with_for_update()
    )
    if not design.active:
        session.execute(
            update(EstimatorDesign)
            .where(
                EstimatorDesign.engine_type_id == design.engine_type_id,
                EstimatorDesign.active.is_(True),
            )
            .values(active=False)
            .execution_options(synchronize_session="fetch")
        )
        session.flush()
        design.active = True
        design.activated_at = utcnow()
        session.flush()
        # Every engine of the type with data is to be estimated (or continued) under it.
        backlog.mark_from_start(session, operator_id, session.scalars(
            select(Engine.id).where(
                Engine.operator_id == operator_id,
                Engine.engine_type_id == design.engine_type_id,
                select(Snapshot.engine_id).where(Snapshot.engine_id == Engine.id).exists(),
            )
        ))
    return design


def deactivate_design(session: Session, *, operator_id: int, design_id: int) -> EstimatorDesign:
    design = get_design(session, operator_id=operator_id, design_id=design_id)
    design.active = False
    session.flush()
    return design


def active_design(
    session: Session, *, operator_id: int, engine_type_id: int
) -> EstimatorDesign | None:
    """The engine type's design in service (None: none activated yet)."""
    return session.scalar(
        select(EstimatorDesign).where(
            EstimatorDesign.operator_id == operator_id,
            EstimatorDesign.engine_type_id == engine_type_id,
            EstimatorDesign.active.is_(True),
        )
    )


def design_step(model: LinearModel, spec: Mapping[str, Any]) -> Mapping[str, Any]:
    """The estimation core's design step: spec on ``model`` -> fleethealth.design/1 dict.

    The spec's own ``model`` key (a file name for command-line use) is ignored: the API names
    the stored engine model by id.
    """
    return run_spec(spec, model)
