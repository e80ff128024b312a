"""C-MAPSS sets other than FD001 through ``import-cmapss``: names after the file, six operating
conditions (FD002, FD004), and two sets in one server kept apart.

NASA's FD002-FD004 files are not shipped beside the repository; the tests write small files in
the same 26-column format: FD001's first cycles with the settings and the inlet temperature of
FD002's six conditions (altitude kft, Mach, TRA; T2 of ISA at that condition)."""

from __future__ import annotations

import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.cli.importers import (
    FD001_TRAIN,
    CmapssImportError,
    CmapssSet,
    import_cmapss,
    read_cmapss,
)
from app.models import Aircraft, Engine, EngineType, EstimatorDesign, Snapshot
from app.services.snapshots import estimator
from app.services.snapshots import store as snapshots_store
from app.services.tenancy import service as tenancy
from estimation.engine.schedule import EngineSchedule, build_schedule
from tests.support.paths import FD001

# FD002's six conditions: altitude (kft), Mach, TRA.
SIX_CONDITIONS = np.array([
    [0.0, 0.0, 100.0], [10.0, 0.25, 100.0], [20.0, 0.7, 100.0],
    [25.0, 0.62, 60.0], [35.0, 0.84, 100.0], [42.0, 0.84, 100.0],
])
CYCLES = 12  # per unit


def isa_t2_degr(alt_kft: np.ndarray, mach: np.ndarray) -> np.ndarray:
    """Inlet total temperature of the ISA day (degR) at altitude and Mach."""
    t_amb = 288.15 - 0.0065 * np.minimum(alt_kft * 1000.0 * 0.3048, 11000.0)
    return t_amb * (1.0 + 0.2 * mach**2) * 1.8


def write_six_condition_file(path: Path, units: int) -> np.ndarray:
    """A C-MAPSS-format file of ``units`` units, ``CYCLES`` cycles each, cycling through the six
    conditions; its rows as written."""
    source = read_cmapss(FD001)
    rows = []
    for unit in range(1, units + 1):
        block = source[source[:, 0] == unit][:CYCLES].copy()
        cond = SIX_CONDITIONS[np.arange(CYCLES) % len(SIX_CONDITIONS)]
        block[:, 2:5] = cond
        block[:, 5] = isa_t2_degr(cond[:, 0], cond[:, 1])
        rows.append(block)
    data = np.concatenate(rows)
    np.savetxt(path, data, fmt="%.6g")
    return data


@pytest.fixture
def analyst_client(client: TestClient, session: Session) -> tuple[TestClient, int]:
    operator = tenancy.create_operator(session, name=f"CMAPSS sets {uuid.uuid4().hex[:8]}")
    _row, key = tenancy.issue_api_key(session, operator=operator, role="analyst", name="import")
    session.commit()
    client.headers["X-API-Key"] = key
    return client, operator.id


def test_the_set_is_read_from_nasas_file_names(tmp_path: Path) -> None:
    assert CmapssSet.of_file(Path("/x/train_FD001.txt")) == FD001_TRAIN
    fd002 = CmapssSet.of_file(tmp_path / "test_FD002.txt")
    assert (fd002.dataset, fd002.split) == ("FD002", "test")
    assert fd002.esn(7) == "FD002-test-007" and fd002.tail(7) == "CM-FD002-test-007"
    assert fd002.engine_type == "CMAPSS-FD002"
    assert CmapssSet.of_file(Path("TRAIN_fd004.txt")) == CmapssSet("FD004", "train")
    for bad in ("train_FD005.txt", "RUL_FD001.txt", "fd001.csv"):
        with pytest.raises(CmapssImportError, match="not a C-MAPSS file name"):
            CmapssSet.of_file(Path(bad))
    with pytest.raises(CmapssImportError, match="unknown C-MAPSS set"):
        CmapssSet("FD001", "validation")


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_sets_imported_into_one_server_keep_their_engines_tails_and_types_apart(
    analyst_client: tuple[TestClient, int], session: Session, tmp_path: Path
) -> None:
    client, operator_id = analyst_client
    fd002 = write_six_condition_file(tmp_path / "train_FD002.txt", units=2)
    fd004 = write_six_condition_file(tmp_path / "test_FD004.txt", units=1)
    first = import_cmapss(tmp_path / "train_FD002.txt", client)
    second = import_cmapss(tmp_path / "test_FD004.txt", client, design=False)
    third = import_cmapss(FD001, client, units=1)
    n1 = int((read_cmapss(FD001)[:, 0] == 1).sum())
    assert (first.units, first.stored, first.duplicates) == (2, len(fd002), 0)
    assert (second.units, second.stored, second.duplicates) == (1, len(fd004), 0)
    assert (third.units, third.stored, third.duplicates) == (1, n1, 0)

    engines = {e.esn: e for e in session.scalars(
        select(Engine).where(Engine.operator_id == operator_id))}
    assert sorted(engines) == ["FD001-train-001", "FD002-train-001", "FD002-train-002",
                               "FD004-test-001"]
    types = {t.id: t.name for t in session.scalars(
        select(EngineType).where(EngineType.operator_id == operator_id))}
    assert sorted(types.values()) == ["CMAPSS-FD001", "CMAPSS-FD002", "CMAPSS-FD004"]
    assert {esn: types[e.engine_type_id] for esn, e in engines.items()} == {
        "FD001-train-001": "CMAPSS-FD001", "FD002-train-001": "CMAPSS-FD002",
        "FD002-train-002": "CMAPSS-FD002", "FD004-test-001": "CMAPSS-FD004"}
    tails = set(session.scalars(select(Aircraft.tail).where(Aircraft.operator_id == operator_id)))
    assert tails == {"CM-FD001-train-001", "CM-FD002-train-001", "CM-FD002-train-002",
                     "CM-FD004-test-001"}

    # Each engine holds its own unit's rows: unit 1 of FD002 is not unit 1 of FD001.
    for esn, data, unit in (("FD002-train-001", fd002, 1), ("FD002-train-002", fd002, 2),
                            ("FD004-test-001", fd004, 1)):
        rows = session.execute(
            select(Snapshot.alt_ft, Snapshot.mach, Snapshot.power_pct, Snapshot.dtamb_k,
                   Snapshot.t30)
            .where(Snapshot.engine_id == engines[esn].id).order_by(Snapshot.recorded_at)
        ).all()
        mine = data[data[:, 0] == unit]
        got = np.array([tuple(r) for r in rows], dtype=float)
        assert got.shape == (CYCLES, 5)
        # The six conditions as the operating condition: altitude in ft, Mach, TRA as power,
        # an ISA day (the inlet temperature written from ISA gives dTamb ~ 0).
        np.testing.assert_allclose(got[:, 0], mine[:, 2] * 1000.0)
        np.testing.assert_allclose(got[:, 1], mine[:, 3])
        np.testing.assert_allclose(got[:, 2], mine[:, 4])
        np.testing.assert_allclose(got[:, 3], 0.0, atol=0.01)
        np.testing.assert_allclose(got[:, 4], mine[:, 7])
    fd001_t30 = session.scalars(
        select(Snapshot.t30).where(Snapshot.engine_id == engines["FD001-train-001"].id)
        .order_by(Snapshot.recorded_at)).all()
    assert len(fd001_t30) == n1 and fd001_t30[CYCLES] == read_cmapss(FD001)[CYCLES, 7]

    # Designs per type: FD002 and FD001 each got a ready, active one; FD004 was not asked.
    designs = {types[d.engine_type_id]: d for d in session.scalars(
        select(EstimatorDesign).where(EstimatorDesign.operator_id == operator_id))}
    assert sorted(designs) == ["CMAPSS-FD001", "CMAPSS-FD002"]
    assert first.design_id == designs["CMAPSS-FD002"].id
    assert third.design_id == designs["CMAPSS-FD001"].id
    assert all(d.status == "ready" and d.active for d in designs.values())
    assert designs["CMAPSS-FD002"].name == "FD002 SVD 7 tuners"

    # The test set of FD002 joins the train set's type and design, with engines of its own.
    write_six_condition_file(tmp_path / "test_FD002.txt", units=1)
    fourth = import_cmapss(tmp_path / "test_FD002.txt", client)
    assert fourth.design_id == first.design_id and not fourth.design_created
    test_engine = session.scalar(select(Engine).where(
        Engine.operator_id == operator_id, Engine.esn == "FD002-test-001"))
    assert test_engine is not None
    assert test_engine.engine_type_id == engines["FD002-train-001"].engine_type_id
    assert fourth.stored == CYCLES  # not a replay of train_FD002's batch


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_the_command_line_names_a_renamed_file_by_its_options(
    analyst_client: tuple[TestClient, int], session: Session, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from typer.testing import CliRunner

    from app.cli import app as cli
    from app.cli import importers

    client, operator_id = analyst_client
    key = str(client.headers["X-API-Key"])
    monkeypatch.setattr(importers.httpx, "Client", lambda **kwargs: client)
    path = tmp_path / "fd003 copy.txt"
    write_six_condition_file(path, units=1)
    refused = CliRunner().invoke(cli, ["import-cmapss", str(path), "--api-key", key])
    assert refused.exit_code != 0 and "not a C-MAPSS file name" in refused.output
    result = CliRunner().invoke(cli, ["import-cmapss", str(path), "--api-key", key,
                                      "--dataset", "fd003", "--split", "test", "--no-design"])
    assert result.exit_code == 0, result.output
    esns = session.scalars(select(Engine.esn).where(Engine.operator_id == operator_id)).all()
    assert esns == ["FD003-test-001"]


@pytest.fixture(scope="module")
def default_schedule() -> EngineSchedule:
    """The built-in engine's schedule on its default grid (0 to 40,000 ft): what a server
    builds on first use."""
    return build_schedule()


def _numbers(value: Any) -> list[float]:
    if isinstance(value, dict):
        return [x for v in value.values() for x in _numbers(v)]
    if isinstance(value, list):
        return [x for v in value for x in _numbers(v)]
    return [float(value)] if isinstance(value, int | float) and not isinstance(value, bool) \
        else []


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_six_condition_sets_trend_on_the_design_import_cmapss_makes(
    analyst_client: tuple[TestClient, int], session: Session, tmp_path: Path,
    default_schedule: EngineSchedule, monkeypatch: pytest.MonkeyPatch,
) -> None:
    """FD002's six conditions, the 42 kft one above the schedule's edge included: the
    estimation job estimates every record and the trend reads finite health."""
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: default_schedule)
    client, operator_id = analyst_client
    data = write_six_condition_file(tmp_path / "train_FD002.txt", units=2)
    summary = import_cmapss(tmp_path / "train_FD002.txt", client)
    assert summary.design_created
    totals = snapshots_store.catch_up(session, operator_id)
    assert totals["records"] == len(data) and totals["engines"] == 2
    engine = session.scalar(select(Engine).where(
        Engine.operator_id == operator_id, Engine.esn == "FD002-train-001"))
    assert engine is not None
    trend = client.get(f"/api/v1/engines/{engine.id}/trend").json()
    assert trend["n_records"] == CYCLES and trend["design_id"] == summary.design_id
    health = [g for g in trend["groups"] if g["key"] == "health"]
    assert len(health) == 1 and len(health[0]["series"]) == 10  # the design's ten
    values = _numbers(health[0]["series"])
    assert len(values) >= 10 * CYCLES and np.isfinite(values).all()
