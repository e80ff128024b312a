"""The EGT windows the pipeline keeps (``app.services.snapshots.egt``): after every run (first
upload, a continuation, a late record that re-runs an engine) each engine's window is stamped
with its filter state, and the fleet status read from the windows equals, field for field, the
status read from the engines' last records (what it read before the windows, and still reads
for an engine whose window is stale), without reading a snapshot."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import UTC, datetime
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from sqlalchemy import Connection, delete, event, select, update
from sqlalchemy.orm import Session

from app.models import EstimatorDesign
from app.models.estimates import EgtWindow, FilterState
from app.services.designs import calibration
from app.services.fleet import status
from app.services.snapshots import estimator
from estimation.engine.deltas import STATUS_EGT_MARGIN
from estimation.engine.schedule import EngineSchedule
from estimation.uncertainty import Calibration
from tests.support.builtin_fleet import coarse_schedule, seed_fleet, upload


@pytest.fixture
def builtin(monkeypatch: pytest.MonkeyPatch) -> EngineSchedule:
    monkeypatch.setattr(estimator, "builtin_schedule", coarse_schedule)
    return coarse_schedule()


@pytest.fixture
def statements(connection: Connection) -> Iterator[list[str]]:
    seen: list[str] = []

    def record(_conn: Any, _cursor: Any, statement: str, *_: Any) -> None:
        seen.append(statement)

    event.listen(connection, "before_cursor_execute", record)
    yield seen
    event.remove(connection, "before_cursor_execute", record)


def from_records(session: Session, operator_id: int) -> dict[str, Any]:
    """The status with no EGT window kept: every engine's last records read."""
    nested = session.begin_nested()
    session.execute(delete(EgtWindow))
    out = status.fleet_status(session, operator_id)
    nested.rollback()
    return out


def assert_windows_stamped(session: Session, schedule: EngineSchedule) -> None:
    states = {(r.engine_id, r.design_id): (r.n_records, r.last_recorded_at)
              for r in session.execute(select(FilterState.engine_id, FilterState.design_id,
                                              FilterState.n_records,
                                              FilterState.last_recorded_at))}
    windows = session.scalars(select(EgtWindow)).all()
    assert states and {(w.engine_id, w.design_id) for w in windows} == set(states)
    for w in windows:
        assert (w.n_records, w.last_recorded_at) == states[(w.engine_id, w.design_id)]
        assert w.fingerprint == schedule.fingerprint
    assert any(w.median is not None for w in windows)


def test_status_from_kept_egt_windows_equals_the_status_from_records(
    session: Session, builtin: EngineSchedule, statements: list[str],
) -> None:
    operator_id, table = seed_fleet(session, "EGT Window Air")
    times = table["recorded_at"].to_numpy().astype("datetime64[s]").astype(np.int64)
    cut = int(np.quantile(times, 0.7))
    gap = (int(np.quantile(times, 0.4)), int(np.quantile(times, 0.5)))
    first_tail = table["tail"][0].as_py()
    late = (pa.compute.equal(table["tail"], first_tail).to_numpy(zero_copy_only=False)
            & (times >= gap[0]) & (times < gap[1]))
    first = (times < cut) & ~late
    # The first upload; then the rest with the late records: a continuation for most engines,
    # a re-run for the first tail's.
    for part, reruns in ((first, 0), (~first, 2)):
        assert upload(session, operator_id, table.filter(pa.array(part)))["reruns"] == reruns
        assert_windows_stamped(session, builtin)
        statements.clear()
        kept = status.fleet_status(session, operator_id)
        assert not [s for s in statements if "snapshots" in s], "read records"
        checks = [c["limit"] for e in kept["engines"] for c in e["checks"]]
        assert "egt_margin" in checks and "rate_of_change" in checks
        assert kept == from_records(session, operator_id)

    # The window is what the status shows while its stamp is the filter state's, and is
    # passed over once it is not.
    engine = next(e for e in kept["engines"] if any(c["limit"] == "egt_margin"
                                                    for c in e["checks"]))
    margin = next(c["value"] for c in engine["checks"] if c["limit"] == "egt_margin")
    key = (EgtWindow.engine_id == engine["engine_id"]) & (EgtWindow.design_id
                                                          == engine["design_id"])
    median = session.scalar(select(EgtWindow.median).where(key))
    assert median is not None
    session.execute(update(EgtWindow).where(key).values(median=median + 10.0))

    def shown() -> float:
        body = status.fleet_status(session, operator_id)
        item = next(e for e in body["engines"] if e["engine_id"] == engine["engine_id"])
        return next(c["value"] for c in item["checks"] if c["limit"] == "egt_margin")

    ref = status.performance.type_reference(builtin)
    assert shown() == pytest.approx(margin - 10.0 * ref.theta_reference, abs=2e-3)
    session.execute(update(EgtWindow).where(key).values(
        last_recorded_at=datetime(2000, 1, 1, tzinfo=UTC)))
    assert shown() == margin
    assert status.fleet_status(session, operator_id) == from_records(session, operator_id)
    # Without a calibration the margin has no 1-sigma; with one, the status's EGT margin's
    # (the calibration's fit of the median of the last raw dEGTs against the truth).
    item = next(e for e in status.fleet_status(session, operator_id)["engines"]
                if e["engine_id"] == engine["engine_id"])
    assert next(c for c in item["checks"] if c["limit"] == "egt_margin")["sigma"] is None
    design = session.get(EstimatorDesign, engine["design_id"])
    assert design is not None
    calibration.store_calibration(session, design, Calibration(
        names=("fan_eff",), level_std=np.zeros(1), change_std=np.zeros(1),
        slope_error=np.zeros(1), bias2=np.zeros(1), drift=np.zeros(1),
        observable=np.ones(1, bool),
        delta_names=(STATUS_EGT_MARGIN,), delta_std=np.array([3.25])))
    item = next(e for e in status.fleet_status(session, operator_id)["engines"]
                if e["engine_id"] == engine["engine_id"])
    check = next(c for c in item["checks"] if c["limit"] == "egt_margin")
    assert check["sigma"] == 3.25 and check["value"] == pytest.approx(margin, abs=1e-3)
