"""Engine models: imported linear-model files and model schedules, or the built-in engine's,
validated by the estimation core and stored.

A model schedule (``fleethealth.model-schedule/1``, docs/model-format.md) is stored as one
engine model: designs are made on its design-point model, the estimator interpolates its
models at each record's operating condition."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.errors import Conflict, InvalidInput
from app.models import EngineModel, EngineType
from app.services.common import delete_or_conflict, owned, paginate, referenced
from estimation.engine.errors import EngineConvergenceError
from estimation.engine.linearize import linearize
from estimation.model import MODEL_FORMAT, LinearModel
from estimation.schedule import SCHEDULE_FORMAT, ModelSchedule, schedule_of


def _invalid(field: str, exc: Exception) -> InvalidInput:
    # ModelFormatError, DimensionError, UnknownSignalError and plain value errors all carry a
    # message that names the key, matrix or signal.
    reason = str(exc) if str(exc) else type(exc).__name__
    return InvalidInput(
        f"{field}: {reason}", details=[{"location": ["body", field], "reason": reason}]
    )


def parse_linear_model(content: Any, *, field: str = "model") -> LinearModel:
    """The estimation core's model from a dict, or 422 naming the key or matrix at fault."""
    try:
        return LinearModel.from_dict(content)
    except (ValueError, KeyError, TypeError) as exc:
        raise _invalid(field, exc) from None


def parse_model_schedule(content: Any, *, field: str = "model") -> ModelSchedule:
    """A ``fleethealth.model-schedule/1`` dict read by the estimation core, or 422 naming the
    key, model or operating point at fault."""
    try:
        return ModelSchedule.from_dict(content)
    except (ValueError, KeyError, TypeError) as exc:
        raise _invalid(field, exc) from None


def schedule_from_files(
    files: list[Any], variables: list[str], corrections: Mapping[str, Any] | None,
    design_point: int,
) -> ModelSchedule:
    """One schedule of several ``fleethealth.linear-model/1`` files at operating points (the
    ``models`` form of an import), or 422 naming the file or point at fault."""
    models = [parse_linear_model(f, field=f"models[{i}]") for i, f in enumerate(files)]
    try:
        return schedule_of(models, variables, corrections or {}, design_point)
    except (ValueError, KeyError, TypeError) as exc:
        raise _invalid("models", exc) from None


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
    model: LinearModel | ModelSchedule,
    source: str,
) -> tuple[EngineModel, bool]:
    """Store ``model`` (a linear model or a model schedule) as the next version of ``name``;
    (row, created).

    Identical content to a stored version of the same name returns that version
    (created False), so importing a file twice stores nothing new.
    """
    engine_type = referenced(
        session, EngineType, operator_id, engine_type_id, "engine_type_id", "engine type"
    )
    # Serialise version numbering per engine type.
    session.scalar(select(EngineType.id).where(EngineType.id == engine_type.id).with_for_update())
    content = model.to_dict()
    if isinstance(model, ModelSchedule):
        fmt, model = SCHEDULE_FORMAT, model.template
    else:
        fmt = MODEL_FORMAT
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
        format=fmt,
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
    session: Session, *, operator_id: int, engine_type_id: int, name: str,
    content: Any = None, schedule: ModelSchedule | None = None,
) -> tuple[EngineModel, bool]:
    """Validate a ``fleethealth.linear-model/1`` or ``fleethealth.model-schedule/1`` dict (or
    take a schedule already read) and store it (see ``store_engine_model``)."""
    referenced(session, EngineType, operator_id, engine_type_id, "engine_type_id", "engine type")
    model: LinearModel | ModelSchedule
    if schedule is not None:
        model = schedule
    elif isinstance(content, Mapping) and content.get("format") == SCHEDULE_FORMAT:
        model = parse_model_schedule(content)
    else:
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
    """The model designs are made on: the stored model, or a schedule's design-point model."""
    if row.format == SCHEDULE_FORMAT:
        return ModelSchedule.from_dict(row.content).template
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


