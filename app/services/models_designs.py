"""Engine models (imported ``fleethealth.linear-model/1`` dicts or built-in) and estimator designs.

A model is validated by the estimation core (``LinearModel.from_dict``) and stored in its
normalised dict form with a checksum; versions count up per (engine type, name), and a model
is immutable: re-importing identical content returns the stored version, a change is a new
version, and a model that a design uses is locked against deletion. A design stores its spec,
the estimation core's ``fleethealth.design/1`` result and its analytic errors; at most one
design per engine type is active.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping
from typing import Any

from sqlalchemy import func, select, update
from sqlalchemy.orm import Session

from app.errors import Conflict, InvalidInput
from app.models import Engine, EngineModel, EngineType, EstimatorDesign, Snapshot
from app.models.base import utcnow
from app.services import backlog
from app.services.fleet import delete_or_conflict, owned, paginate, referenced
from estimation.design import parse_spec
from estimation.design import run_design as run_spec
from estimation.engine.errors import EngineConvergenceError
from estimation.engine.linearize import linearize
from estimation.model import MODEL_FORMAT, LinearModel

# ------------------------------------------------------------------------ engine models


def parse_linear_model(content: Any, *, field: str = "model") -> LinearModel:
    """The estimation core's model from a dict, or 422 naming the key or matrix at fault."""
    try:
        return LinearModel.from_dict(content)
    except (ValueError, KeyError, TypeError) as exc:
        # ModelFormatError, DimensionError, UnknownSignalError and plain value errors all
        # carry a message that names the key, matrix or signal.
        reason = str(exc) if str(exc) else type(exc).__name__
        raise InvalidInput(
            f"{field}: {reason}", details=[{"location": ["body", field], "reason": reason}]
        ) from None


def checksum(document: Mapping[str, Any]) -> str:
    """SHA-256 of the canonical JSON form (sorted keys, no spaces)."""
    canonical = json.dumps(document, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(canonical.encode()).hexdigest()


def store_engine_model(
    session: Session,
    *,
    operator_id: int,
    engine_type_id: int,
    name: str,
    model: LinearModel,
    source: str,
) -> tuple[EngineModel, bool]:
    """Store ``model`` as the next version of ``name``; (row, created).

    Identical content to a stored version of the same name returns that version
    (created False), so importing a file twice stores nothing new.
    """
    engine_type = referenced(
        session, EngineType, operator_id, engine_type_id, "engine_type_id", "engine type"
    )
    # Serialise version numbering per engine type.
    session.scalar(select(EngineType.id).where(EngineType.id == engine_type.id).with_for_update())
    content = model.to_dict()
    digest = checksum(content)
    same = session.scalar(
        select(EngineModel).where(
            EngineModel.engine_type_id == engine_type.id,
            EngineModel.name == name,
            EngineModel.checksum == digest,
        )
    )
    if same is not None:
        return same, False
    latest = session.scalar(
        select(func.max(EngineModel.version)).where(
            EngineModel.engine_type_id == engine_type.id, EngineModel.name == name
        )
    )
    row = EngineModel(
        operator_id=operator_id,
        engine_type_id=engine_type.id,
        name=name,
        version=(latest or 0) + 1,
        source=source,
        format=MODEL_FORMAT,
        content=content,
        checksum=digest,
        dt=model.dt,
        n_states=model.n_states,
        sensor_names=model.sensor_names,
        health_names=model.health_names,
        aux_names=model.aux_names,
    )
    session.add(row)
    session.flush()
    return row, True


def import_engine_model(
    session: Session, *, operator_id: int, engine_type_id: int, name: str, content: Any
) -> tuple[EngineModel, bool]:
    """Validate a ``fleethealth.linear-model/1`` dict and store it (see ``store_engine_model``)."""
    referenced(session, EngineType, operator_id, engine_type_id, "engine_type_id", "engine type")
    model = parse_linear_model(content)
    return store_engine_model(
        session,
        operator_id=operator_id,
        engine_type_id=engine_type_id,
        name=name,
        model=model,
        source="imported",
    )


def register_builtin_model(
    session: Session, *, operator_id: int, engine_type_id: int, name: str, model: LinearModel
) -> tuple[EngineModel, bool]:
    """Store a model linearised from the built-in engine (source ``builtin``)."""
    return store_engine_model(
        session,
        operator_id=operator_id,
        engine_type_id=engine_type_id,
        name=name,
        model=model,
        source="builtin",
    )


def build_builtin_model(
    session: Session,
    *,
    operator_id: int,
    engine_type_id: int,
    name: str,
    alt_ft: float,
    mach: float,
    power_pct: float,
    dtamb_k: float = 0.0,
) -> tuple[EngineModel, bool]:
    """Linearise the built-in engine at an operating condition and store it (source builtin).

    A condition outside the envelope, or one where the engine has no steady state, is a 422.
    """
    referenced(session, EngineType, operator_id, engine_type_id, "engine_type_id", "engine type")
    try:
        model = linearize(alt_ft, mach, power_pct, dtamb_k)
    except (ValueError, EngineConvergenceError) as exc:
        reason = str(exc)
        raise InvalidInput(
            f"operating condition: {reason}", details=[{"location": ["body"], "reason": reason}]
        ) from None
    return register_builtin_model(
        session, operator_id=operator_id, engine_type_id=engine_type_id, name=name, model=model
    )


def get_engine_model(session: Session, *, operator_id: int, engine_model_id: int) -> EngineModel:
    return owned(session, EngineModel, operator_id, engine_model_id, "engine model")


def load_linear_model(row: EngineModel) -> LinearModel:
    return LinearModel.from_dict(row.content)


def list_engine_models(
    session: Session,
    *,
    operator_id: int,
    limit: int,
    offset: int,
    engine_type_id: int | None = None,
    name: str | None = None,
) -> tuple[list[EngineModel], int]:
    stmt = select(EngineModel).where(EngineModel.operator_id == operator_id)
    if engine_type_id is not None:
        stmt = stmt.where(EngineModel.engine_type_id == engine_type_id)
    if name is not None:
        stmt = stmt.where(EngineModel.name == name)
    stmt = stmt.order_by(EngineModel.engine_type_id, EngineModel.name, EngineModel.version.desc())
    return paginate(session, stmt, limit=limit, offset=offset)


def delete_engine_model(session: Session, *, operator_id: int, engine_model_id: int) -> None:
    row = get_engine_model(session, operator_id=operator_id, engine_model_id=engine_model_id)
    if row.locked_at is not None:
        raise Conflict(
            f"engine model {row.name!r} version {row.version} is used by a design "
            "and cannot be deleted"
        )
    delete_or_conflict(session, row, f"engine model {row.id} is still referenced")


# ----------------------------------------------------------------------------- designs

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
