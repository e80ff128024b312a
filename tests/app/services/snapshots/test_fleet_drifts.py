"""The wear detector's fleet direction learns from the fleet's drifts as the pass found them
(``app.services.snapshots.drifts``): engine groups estimated in parallel store the same numbers
whichever group commits first.

Two operators of the same simulated fleet (the built-in engine, the demo's designs), on a
really-committing PostgreSQL database: a first upload estimated alone leaves every engine a
drift; a second upload is then spread over engine groups, once with the job's own group done
first and once with the other groups done and committed before it (what a fast worker does).
Before the pass read the drifts once, a group read the drifts stored when it started, so the
second order gave the job's group the others' new drifts and the first the old ones.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.db import transaction
from app.models import Engine
from app.models.estimates import Estimate, Event, FilterCheckpoint, FilterState
from app.services.snapshots import estimator, groups, run, store
from app.services.snapshots.drifts import FleetDrifts
from app.services.uploads.store import ingest_snapshots
from estimation.engine.schedule import EngineSchedule
from tests.support.builtin_fleet import coarse_schedule, seed_fleet, upload
from tests.support.jobs import live_database


@pytest.fixture
def builtin(monkeypatch: pytest.MonkeyPatch) -> EngineSchedule:
    monkeypatch.setattr(estimator, "builtin_schedule", coarse_schedule)
    return coarse_schedule()


class JobFirst:
    """Two workers, the second never starting: the job does every group, its own first."""

    workers = 2

    def launch(self, operator_id: int, parts: Sequence[Sequence[int]],
               drifts: FleetDrifts) -> None:
        pass


class WorkerFirst:
    """Two workers, the second doing every group it is given, committed, before the job
    starts its own."""

    workers = 2

    def __init__(self, factory: sessionmaker[Session]) -> None:
        self.factory = factory

    def launch(self, operator_id: int, parts: Sequence[Sequence[int]],
               drifts: FleetDrifts) -> None:
        for part in parts:
            with self.factory() as session:
                store.run_group(session, operator_id, part, drifts)


def _store_records(session: Session, operator_id: int, table: pa.Table) -> None:
    """Records stored as an upload stores them (their estimation left to the caller)."""
    sink = io.BytesIO()
    pq.write_table(table, sink)
    ingest_snapshots(session, operator_id=operator_id, api_key_id=None, body=sink.getvalue(),
                     content_format="parquet")


def _stored(session: Session, operator_id: int) -> dict[str, Any]:
    """Per ESN every estimate, checkpoint and filter state, and the events."""
    esn = dict(session.execute(
        select(Engine.id, Engine.esn).where(Engine.operator_id == operator_id)).all())
    out: dict[str, Any] = {}
    for engine_id, name in esn.items():
        out[name] = (
            [(s, t, bytes(b)) for s, t, b in session.execute(
                select(Estimate.seq, Estimate.recorded_at, Estimate.packed)
                .where(Estimate.engine_id == engine_id).order_by(Estimate.seq))],
            [(c.seq, c.state) for c in session.scalars(
                select(FilterCheckpoint).where(FilterCheckpoint.engine_id == engine_id)
                .order_by(FilterCheckpoint.seq))],
            [(f.n_records, f.state) for f in session.scalars(
                select(FilterState).where(FilterState.engine_id == engine_id))],
            sorted((e.seq, e.detected_at, e.kind, e.fault, e.magnitude, e.statistic)
                   for e in session.scalars(select(Event).where(Event.engine_id == engine_id))),
        )
    return out


def test_engine_groups_learn_from_the_drifts_the_pass_found_whoever_commits_first(
    builtin: EngineSchedule, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    # What each group's run learns from (its ``fleet``) is the check: on this small fleet a
    # stretch keeps the direction it adopted in the first upload, so the stored results of the
    # second would not show the difference by themselves.
    calls: list[list[tuple[float, ...]]] = []
    learnt: dict[str, list[list[tuple[float, ...]]]] = {}
    real = run.run_filters

    def recording(est: Any, runs: Any, sink: Any = None, fleet: Any = (),
                  wear_settings: Any = None) -> Any:
        calls.append(sorted(fleet))
        return real(est, runs, sink=sink, fleet=fleet, wear_settings=wear_settings)

    monkeypatch.setattr(store, "run_filters", recording)
    with live_database("postgresql", tmp_path) as (_url, factory):
        operators: list[int] = []
        table: pa.Table | None = None
        for name in ("Drift Air One", "Drift Air Two"):
            with transaction(factory) as session:
                operator_id, table = seed_fleet(session, name)
            operators.append(operator_id)
        assert table is not None
        times = table["recorded_at"].to_numpy().astype("datetime64[s]").astype(np.int64)
        cut = int(np.quantile(times, 0.5))
        first, second = table.filter(pa.array(times < cut)), table.filter(pa.array(times >= cut))
        for operator_id in operators:
            with factory() as session:
                upload(session, operator_id, first)
                session.commit()
        with factory() as session:
            drifts = FleetDrifts.read(session, operators[0])
        assert drifts.by_design and all(len(d) >= 3 for d in drifts.by_design.values()), \
            "at least three engines have a drift to learn from after the first upload"
        for operator_id, launcher, name in ((operators[0], JobFirst(), "job first"),
                                            (operators[1], WorkerFirst(factory),
                                             "worker first")):
            calls.clear()
            with factory() as session:
                _store_records(session, operator_id, second)
                session.commit()
                groups.configure(launcher)
                try:
                    counts = store.catch_up(session, operator_id, commit=session.commit)
                finally:
                    groups.configure(None)
                session.commit()
            assert counts["groups"] >= 2
            learnt[name] = list(calls)
        with factory() as session:
            one, two = _stored(session, operators[0]), _stored(session, operators[1])
    assert sorted(learnt["job first"]) == sorted(learnt["worker first"])
    assert one == two
