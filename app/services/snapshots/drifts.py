"""The fleet's wear drifts as a pass of the estimation found them: what the wear detector's
fleet direction learns from (``run.run_filters``), the same in every process of the pass.

An engine's fleet direction is learnt from the drifts (``estimation.wear.latest_drift``) of the
design's other engines: those estimated in the same run, and the others' as stored. Engine
groups estimated in parallel (``groups``) commit their engines' states while the other groups
run, so "as stored" read at a group's start would depend on which group committed first: the
same records could raise their wear alerts at other times, or attribute them otherwise, from
one run to the next. A pass therefore reads the stored drifts once, before any group starts
(``FleetDrifts.read``), and hands the same ``FleetDrifts`` to every group, in this process and
in the workers (``message``, ``from_message``). Within one process, a batch's engines then
replace their drifts with those after the batch (``updated``), for the process's later
batches: the same as reading them back, as one process estimating alone always did.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models.estimates import FilterState

Drift = tuple[float, ...]


@dataclass(frozen=True)
class FleetDrifts:
    """Per design, per engine, the wear drift the design's stored state holds (engines whose
    state has none left out)."""

    by_design: Mapping[int, Mapping[int, Drift]] = field(default_factory=dict)

    @classmethod
    def read(cls, session: Session, operator_id: int) -> FleetDrifts:
        """The drifts stored now in the operator's filter states (the drift alone is read,
        not the whole state)."""
        found: dict[int, dict[int, Drift]] = {}
        rows = session.execute(
            select(FilterState.design_id, FilterState.engine_id,
                   FilterState.state["wear"]["drift"])
            .where(FilterState.operator_id == operator_id)
            .order_by(FilterState.design_id, FilterState.engine_id)
        )
        for design_id, engine_id, drift in rows:
            if drift is not None:
                found.setdefault(design_id, {})[engine_id] = tuple(float(v) for v in drift)
        return cls(found)

    def others(self, design_id: int, exclude: Iterable[int]) -> list[Drift]:
        """The drifts of the design's engines other than ``exclude``, by engine id."""
        left_out = set(exclude)
        kept = self.by_design.get(design_id, {})
        return [kept[e] for e in sorted(kept) if e not in left_out]

    def updated(self, design_id: int, drifts: Mapping[int, Drift | None]) -> FleetDrifts:
        """These drifts with the design's engines in ``drifts`` at their new values (None: the
        engine's state holds none now)."""
        design = {e: d for e, d in self.by_design.get(design_id, {}).items()
                  if e not in drifts}
        design.update({e: tuple(d) for e, d in drifts.items() if d is not None})
        return FleetDrifts({**self.by_design, design_id: design})

    def message(self) -> list[list[Any]]:
        """As a worker's message carries them (JSON: no integer keys)."""
        return [[d, e, list(v)] for d, design in sorted(self.by_design.items())
                for e, v in sorted(design.items())]

    @classmethod
    def from_message(cls, rows: Sequence[Sequence[Any]]) -> FleetDrifts:
        found: dict[int, dict[int, Drift]] = {}
        for design_id, engine_id, drift in rows:
            found.setdefault(int(design_id), {})[int(engine_id)] = tuple(float(v) for v in drift)
        return cls(found)
