"""An engine type's parameter set: the columns its snapshots are received in, read from its
models.

Every engine type is described the same way, the built-in one included:

- its signals are the ``signals.inputs`` and ``signals.sensors`` of its models, with the names
  and units of the model files (the built-in engine's model declares Wf, VSV, VBV, Nf ... P15 in
  pps, %, rpm, degR, psia);
- its operating-condition columns (alt_ft, mach, dtamb_k, power_pct) are required when a model
  is scheduled on them (a model linearised from the built-in engine: the estimator schedules
  its trims and gains on each record's condition; a model schedule, on its scheduling variables
  and, when it corrects trims, the altitude, Mach and dTamb that theta2 and delta2 come from)
  and optional otherwise (a single-point model uses none);
- ``phase`` is required with a scheduled model (the built-in engine's trends are read per flight
  phase) and optional otherwise; ``recorded_at``, ``tail`` and ``position`` always, ``flight_id``
  never.

A type none of whose models declares a signal (a type created a moment ago, before any model)
has no parameter set of its own yet: it receives the signal catalogue (``app.signals``, the
built-in engine's names and units), as every type did before its models named its signals.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import EngineModel, EngineType
from app.services import units
from app.signals import CONDITION_COLUMNS, MEASURED, OPERATING_CONDITION, SignalSpec
from estimation.schedule import SCHEDULE_FORMAT, ModelSchedule

CATALOGUE: dict[str, SignalSpec] = {s.name: s for s in MEASURED}
CONDITIONS: dict[str, SignalSpec] = {s.name: s for s in OPERATING_CONDITION}
SCHEDULED_SOURCES = ("builtin",)  # model sources scheduled on the operating condition


@dataclass(frozen=True)
class ParameterSet:
    """The columns one engine type's snapshots carry.

    ``signals`` in the units of the model files (``inputs`` and ``sensors`` name them by
    role); ``scheduled_on`` the operating-condition columns its rows must carry;
    ``from_models`` False when no model declares a signal yet and the catalogue stands in."""

    engine_type_id: int
    engine_type: str
    signals: tuple[SignalSpec, ...]
    scheduled_on: tuple[str, ...]
    phase_required: bool
    from_models: bool = True
    inputs: tuple[str, ...] = ()
    sensors: tuple[str, ...] = ()

    def signal(self, name: str) -> SignalSpec | None:
        for spec in self.signals:
            if spec.name == name:
                return spec
        return None

    def knows(self, name: str) -> bool:
        """A signal or operating-condition column of this type (conditions are always
        accepted: they describe the flight, and a single-point type ignores them)."""
        return name in CONDITIONS or self.signal(name) is not None

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.signals)

    def required(self, kind: str) -> tuple[str, ...]:
        """The columns every row of this type must carry beyond the keys: the operating
        condition it is scheduled on, and for a snapshot the ``phase`` when its trends are
        read per phase (a stream's phase is found from its samples)."""
        phase = ("phase",) if kind == "snapshots" and self.phase_required else ()
        return self.scheduled_on + phase


def quantity_of(unit: str) -> str | None:
    """The quantity a unit belongs to (the first known one: ``K`` is a temperature), or None
    for a unit fleethealth does not convert (values are then taken as the file's unit)."""
    for name, quantity in units.QUANTITIES.items():
        if unit in quantity.units:
            return name
    return None


def stored_spec(spec: SignalSpec) -> SignalSpec:
    """How a type's signal is stored: a catalogue signal in the catalogue's unit and bounds
    (the estimator converts model trims into it), any other in its model file's unit."""
    return CATALOGUE.get(spec.name, spec)


def _declared(entries: Any) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    if not isinstance(entries, list):
        return out
    for entry in entries:
        if isinstance(entry, Mapping) and isinstance(entry.get("name"), str):
            out.append((str(entry["name"]), str(entry.get("unit") or "")))
    return out


def parameter_set_of(
    engine_type_id: int, engine_type: str, models: Iterable[tuple[str, Mapping[str, Any]]]
) -> ParameterSet:
    """The parameter set of a type from its models, each given as (source, model file)."""
    signals: dict[str, SignalSpec] = {}
    scheduled = False
    conditions: set[str] = set()
    roles: dict[str, dict[str, None]] = {"inputs": {}, "sensors": {}}  # ordered sets
    for source, content in models:
        if isinstance(content, Mapping) and content.get("format") == SCHEDULE_FORMAT:
            try:
                schedule = ModelSchedule.from_dict(content)
            except (ValueError, KeyError, TypeError):
                continue  # stored content is validated on import; nothing to read otherwise
            conditions.update(schedule.required_conditions)
            content = schedule.template.to_dict()
        block = content.get("signals") if isinstance(content, Mapping) else None
        if not isinstance(block, Mapping):
            continue
        given = {"inputs": _declared(block.get("inputs")),
                 "sensors": _declared(block.get("sensors"))}
        declared = given["inputs"] + given["sensors"]
        scheduled = scheduled or (source in SCHEDULED_SOURCES and bool(declared))
        for role, entries in given.items():
            roles[role].update((name, None) for name, _unit in entries
                               if name not in CONDITIONS)
        for name, unit in declared:
            if name in signals or name in CONDITIONS:
                continue  # the first model to declare a signal gives its unit
            quantity = quantity_of(unit) or ""
            catalogue = CATALOGUE.get(name)
            reference = catalogue.percent_reference if catalogue is not None else None
            signals[name] = SignalSpec(name, quantity, unit, percent_reference=reference)
    if not signals:
        return ParameterSet(engine_type_id, engine_type, MEASURED, CONDITION_COLUMNS, True,
                            from_models=False)
    required = CONDITION_COLUMNS if scheduled else tuple(
        c for c in CONDITION_COLUMNS if c in conditions)
    sensors = tuple(n for n in roles["sensors"] if n not in roles["inputs"])
    return ParameterSet(engine_type_id, engine_type, tuple(signals.values()), required,
                        scheduled, inputs=tuple(roles["inputs"]), sensors=sensors)


def parameter_sets(session: Session, engine_type_ids: Sequence[int]) -> dict[int, ParameterSet]:
    """Parameter sets of the given engine types (two queries whatever their number)."""
    ids = sorted(set(engine_type_ids))
    if not ids:
        return {}
    names: dict[int, str] = {type_id: name for type_id, name in session.execute(
        select(EngineType.id, EngineType.name).where(EngineType.id.in_(ids)))}
    models: dict[int, list[tuple[str, Mapping[str, Any]]]] = {i: [] for i in ids}
    for type_id, source, content in session.execute(
        select(EngineModel.engine_type_id, EngineModel.source, EngineModel.content)
        .where(EngineModel.engine_type_id.in_(ids))
        .order_by(EngineModel.id)
    ):
        models[type_id].append((source, content or {}))
    return {i: parameter_set_of(i, names[i], models[i]) for i in ids}
