"""The C-MAPSS FD001 importer, run against the app through the same REST upload as any client."""

from __future__ import annotations

import uuid
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.cli.importers import CMAPSS_START, FD001_TRAIN, import_cmapss
from app.models import Engine, Snapshot
from app.services.tenancy import service as tenancy
from tests.support.paths import FD001

UNITS = 3


def read_by_hand(path: Path, units: int) -> dict[int, list[list[str]]]:
    """Unit -> its lines as text fields, parsed without numpy."""
    out: dict[int, list[list[str]]] = {}
    for line in path.read_text().splitlines():
        fields = line.split()
        unit = int(fields[0])
        if unit <= units:
            out.setdefault(unit, []).append(fields)
    return out


@pytest.fixture
def analyst_client(client: TestClient, session: Session) -> tuple[TestClient, int]:
    operator = tenancy.create_operator(session, name=f"CMAPSS {uuid.uuid4().hex[:8]}")
    _row, key = tenancy.issue_api_key(session, operator=operator, role="analyst", name="import")
    session.commit()
    client.headers["X-API-Key"] = key
    return client, operator.id


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_import_creates_one_engine_per_unit_and_one_snapshot_per_cycle(
    analyst_client: tuple[TestClient, int], session: Session, tmp_path: Path
) -> None:
    client, operator_id = analyst_client
    expected = read_by_hand(FD001, UNITS)
    seen: list[int] = []
    summary = import_cmapss(FD001, client, units=UNITS, batch_rows=250, progress=seen.append)
    n = sum(len(lines) for lines in expected.values())
    assert (summary.units, summary.snapshots, summary.stored, summary.duplicates) == (
        UNITS,
        n,
        n,
        0,
    )
    assert sum(seen) == n and len(summary.uploads) == -(-n // 250)
    history = client.get("/api/v1/uploads", params={"limit": 100}).json()["items"]
    assert {(u["filename"], u["source"]) for u in history if u["id"] in summary.uploads} == {
        (FD001.name, "cli")
    }

    for unit, lines in expected.items():
        engine = session.scalar(
            select(Engine).where(Engine.operator_id == operator_id,
                                 Engine.esn == FD001_TRAIN.esn(unit))
        )
        assert engine is not None
        rows = session.execute(
            select(Snapshot.recorded_at, Snapshot.t30, Snapshot.nc, Snapshot.p30, Snapshot.ps30)
            .where(Snapshot.engine_id == engine.id)
            .order_by(Snapshot.recorded_at)
        ).all()
        assert len(rows) == len(lines)
        # Cycle c is day c - 1; T30 is field 8, Nc field 14, P30 field 12 (SOURCE.md order).
        for row, fields in zip(rows, lines, strict=True):
            assert (row.recorded_at - CMAPSS_START).days == int(fields[1]) - 1
            assert (row.t30, row.nc, row.p30) == (
                float(fields[7]),
                float(fields[13]),
                float(fields[11]),
            )
            assert row.ps30 is None  # not on P30's scale: left out

    # Through the API as well: the first unit's trend, as a client would read it.
    engine_id = session.scalar(
        select(Engine.id).where(Engine.operator_id == operator_id, Engine.esn == FD001_TRAIN.esn(1))
    )
    body = client.get(f"/api/v1/engines/{engine_id}/snapshots").json()
    assert body["count"] == len(expected[1])
    assert body["snapshots"][0]["tail"] == FD001_TRAIN.tail(1)
    assert body["snapshots"][0]["phase"] == "takeoff"
    assert body["snapshots"][0]["power_pct"] == float(expected[1][0][4])

    # Running it again creates nothing and stores nothing.
    before = session.scalar(
        select(func.count()).select_from(Snapshot).where(Snapshot.operator_id == operator_id)
    )
    again = import_cmapss(FD001, client, units=UNITS, batch_rows=250)
    assert (again.stored, again.duplicates) == (0, n) and again.uploads == summary.uploads
    after = session.scalar(
        select(func.count()).select_from(Snapshot).where(Snapshot.operator_id == operator_id)
    )
    assert before == after == n


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_the_command_line_runs_the_import_with_a_progress_bar(
    analyst_client: tuple[TestClient, int],
    session: Session,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from typer.testing import CliRunner

    from app.cli import app as cli
    from app.cli import importers

    client, operator_id = analyst_client
    key = client.headers["X-API-Key"]
    opened: list[dict] = []

    def fake_client(**kwargs: object) -> TestClient:
        # The command's own httpx.Client, pointed at the app under test.
        opened.append(kwargs)
        return client

    monkeypatch.setattr(importers.httpx, "Client", fake_client)
    result = CliRunner().invoke(
        cli, ["import-cmapss", str(FD001), "--api-key", key, "--units", "1"]
    )
    assert result.exit_code == 0, result.output
    n = len(read_by_hand(FD001, 1)[1])
    assert f"1 engines, {n} snapshots: {n} stored" in result.output
    assert opened[0]["headers"] == {"X-API-Key": key}
    stored = session.scalar(
        select(func.count()).select_from(Snapshot).where(Snapshot.operator_id == operator_id)
    )
    assert stored == n


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_import_leaves_a_ready_active_design_at_fd001s_condition(
    analyst_client: tuple[TestClient, int], session: Session
) -> None:
    """The engine type gets the built-in engine linearised at sea level static, TRA 100, and
    an active, ready SVD design on the C-MAPSS sensors; importing again keeps that design, and
    ``design=False`` (``--no-design``) makes none."""
    from app.cli.importers import (
        CMAPSS_SENSORS,
        FD001_CONDITION,
        FD001_TRAIN,
        FD001_TUNERS,
        ensure_engine_type,
    )
    from app.models import EngineModel, EstimatorDesign
    from app.services.designs.engine_models import checksum

    client, operator_id = analyst_client
    first = import_cmapss(FD001, client, units=1)
    assert first.design_created and first.design_id is not None
    design = session.get(EstimatorDesign, first.design_id)
    assert design is not None and design.operator_id == operator_id
    assert design.status == "ready" and design.active
    assert design.spec["tuners"] == FD001_TUNERS and design.spec["sensors"] == list(CMAPSS_SENSORS)
    model = session.get(EngineModel, design.engine_model_id)
    assert model is not None and model.source == "builtin"
    # The model's operating point: its trims are the built-in engine's at FD001's condition.
    from estimation.engine.linearize import linearize

    reference = linearize(FD001_CONDITION["alt_ft"], FD001_CONDITION["mach"],
                          FD001_CONDITION["power_pct"], FD001_CONDITION["dtamb_k"])
    assert model.checksum == checksum(reference.to_dict())
    active = client.get(f"/api/v1/engine-types/{design.engine_type_id}/active-design").json()
    assert active["id"] == design.id

    again = import_cmapss(FD001, client, units=1)
    assert again.design_id == design.id and not again.design_created
    assert session.scalar(select(func.count()).select_from(EstimatorDesign).where(
        EstimatorDesign.operator_id == operator_id)) == 1

    # Without an active design and not asked for one: none is made.
    assert client.post(f"/api/v1/designs/{design.id}/deactivate").status_code == 200
    none = import_cmapss(FD001, client, units=1, design=False)
    assert none.design_id is None
    type_id = ensure_engine_type(client, FD001_TRAIN)
    assert client.get(f"/api/v1/engine-types/{type_id}/active-design").json() is None
