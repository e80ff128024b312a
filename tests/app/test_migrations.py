"""Alembic is the only way tables are made: upgrade an empty database to head, and back."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import inspect, select, text

from app.db import make_engine, make_sessionmaker, transaction
from app.migrate import downgrade, upgrade
from app.models import Base, DeteriorationBucket, EgtWindow, Engine, FilterState, FleetPeriod
from app.services.snapshots import estimator
from app.services.trends.service import load_trend_data
from estimation.uncertainty import pair_products
from tests.app.services.trends.test_trends import (
    LAYOUT,
    add_aircraft,
    add_engine,
    add_estimates,
    make_fleet,
)
from tests.conftest import BACKENDS, fresh_database_url
from tests.support.builtin_fleet import coarse_schedule, seed_fleet, upload
from tests.support.periods import periods_from_estimates, stored_periods


@pytest.mark.parametrize("backend", BACKENDS)
def test_upgrade_to_head_matches_the_models_and_downgrades_to_empty(
    backend: str, tmp_path: Path
) -> None:
    urls = fresh_database_url(backend, tmp_path)
    url = next(urls)
    try:
        upgrade(url)
        engine = make_engine(url)
        with engine.connect() as connection:
            tables = set(inspect(connection).get_table_names()) - {"alembic_version"}
            assert tables == set(Base.metadata.tables)
            context = MigrationContext.configure(connection, opts={"compare_type": False})
            assert compare_metadata(context, Base.metadata) == []

        downgrade(url, "base")
        with engine.connect() as connection:
            assert set(inspect(connection).get_table_names()) <= {"alembic_version"}

        upgrade(url)  # and up again: the downgrade left nothing behind that blocks it
        with engine.connect() as connection:
            assert set(inspect(connection).get_table_names()) - {"alembic_version"} == tables
        engine.dispose()
    finally:
        urls.close()


def test_migrations_form_one_line_of_history() -> None:
    from alembic.script import ScriptDirectory

    from app.migrate import alembic_config

    script = ScriptDirectory.from_config(alembic_config("sqlite://"))
    assert len(script.get_heads()) == 1, f"several migration heads: {script.get_heads()}"


@pytest.mark.parametrize("backend", BACKENDS)
def test_engine_type_limits_come_and_go_with_migration_0011(
    backend: str, tmp_path: Path
) -> None:
    urls = fresh_database_url(backend, tmp_path)
    url = next(urls)
    try:
        upgrade(url)
        engine = make_engine(url)

        def columns() -> set[str]:
            with engine.connect() as connection:
                return {c["name"] for c in inspect(connection).get_columns("engine_types")}

        assert "limits" in columns()
        downgrade(url, "0010")
        assert "limits" not in columns() and "name" in columns()
        upgrade(url)
        assert "limits" in columns()
        engine.dispose()
    finally:
        urls.close()


@pytest.mark.parametrize("backend", BACKENDS)
def test_migration_0013_fills_the_deterioration_periods_from_stored_estimates(
    backend: str, tmp_path: Path
) -> None:
    """Estimates stored before 0013 get their periods at the upgrade: the same rows the
    pipeline keeps (here, those the test helper writes beside its estimates); 0022 rewrites
    the fleet's squares as second moments and back."""
    urls = fresh_database_url(backend, tmp_path)
    url = next(urls)
    try:
        upgrade(url)
        engine = make_engine(url)
        factory = make_sessionmaker(engine)
        rng = np.random.default_rng(3)
        with transaction(factory) as session:
            fleet = make_fleet(session, "Migrating Air")
            aircraft = add_aircraft(session, fleet, "F-MIG")
            for esn in ("M1", "M2"):
                times = [datetime(2026, 1, 1, tzinfo=UTC) + timedelta(hours=20 * k)
                         for k in range(150)]
                add_estimates(session, fleet, add_engine(session, fleet, esn), aircraft,
                              rng.normal(size=(150, LAYOUT.width)), times)

        def periods() -> list[tuple]:
            with factory() as session:
                return sorted(
                    [(b.engine_id, b.period, b.start, b.n, bytes(b.sums))
                     for b in session.scalars(select(DeteriorationBucket))]
                    + [(0, f.period, f.start, f.n_engines, bytes(f.sums) + bytes(f.squares))
                       for f in session.scalars(select(FleetPeriod))])

        kept = periods()
        assert len({(p[1], p[2]) for p in kept}) > 10
        downgrade(url, "0012")
        upgrade(url)
        assert periods() == kept
        # 0022: the fleet's squares hold the health means' products; back at 0021, the squares.
        downgrade(url, "0021")
        with factory() as session:
            buckets: dict[tuple, list[np.ndarray]] = {}
            for b in session.scalars(select(DeteriorationBucket)):
                buckets.setdefault((b.period, b.start), []).append(
                    np.frombuffer(b.sums, "<f8") / b.n)
            for row in session.scalars(select(FleetPeriod)):
                means = np.array(buckets[(row.period, row.start)])
                np.testing.assert_allclose(np.frombuffer(row.squares, "<f8"),
                                           np.square(means).sum(0), rtol=1e-12)
        upgrade(url)
        assert periods() == kept
        # 0023: the aux-by-health moments follow; back at 0022, the health products and the
        # aux squares alone.
        downgrade(url, "0022")
        p = len(LAYOUT.health)
        with factory() as session:
            for row in session.scalars(select(FleetPeriod)):
                means = np.array(buckets[(row.period, row.start)])
                np.testing.assert_allclose(
                    np.frombuffer(row.squares, "<f8"),
                    np.concatenate([pair_products(means[:, :p]), np.square(means[:, p:])],
                                   axis=1).sum(0), rtol=1e-12)
        upgrade(url)
        assert periods() == kept
        # ... and they are the periods of the stored estimates, computed here on their own.
        with factory() as session:
            engine_ids = session.scalars(select(FilterState.engine_id)).all()
            assert len(engine_ids) == 2
            for engine_id in engine_ids:
                stored = stored_periods(session, engine_id)
                expected = periods_from_estimates(session, engine_id, LAYOUT)
                assert stored.keys() == expected.keys()
                for key, (n, sums) in expected.items():
                    assert stored[key][0] == n
                    assert np.allclose(np.frombuffer(stored[key][1], "<f8"), sums, atol=1e-9)
            for row in session.scalars(select(FleetPeriod)):
                assert row.n_engines == 2
        engine.dispose()
    finally:
        urls.close()


@pytest.mark.parametrize("backend", BACKENDS)
def test_migration_0018_keeps_interval_schedules_and_uploads_and_checks_cron_or_interval(
    backend: str, tmp_path: Path
) -> None:
    from sqlalchemy import text
    from sqlalchemy.exc import IntegrityError

    urls = fresh_database_url(backend, tmp_path)
    url = next(urls)
    try:
        upgrade(url, "0017")
        engine = make_engine(url)
        with engine.begin() as connection:
            connection.execute(text("INSERT INTO operators (name, created_at) "
                                    "VALUES ('Before Air', CURRENT_TIMESTAMP)"))
            connection.execute(text(
                "INSERT INTO job_schedules (operator_id, kind, parameters, interval_seconds, "
                "enabled, next_run_at, created_at) SELECT id, 'fleet_diagnostics', '{}', 86400, "
                "true, CURRENT_TIMESTAMP, CURRENT_TIMESTAMP FROM operators"))
        upgrade(url)
        with engine.connect() as connection:
            assert connection.execute(text(
                "SELECT kind, interval_seconds, cron FROM job_schedules")).all() == [
                ("fleet_diagnostics", 86400, None)]
        for interval, cron in ((None, None), (3600, "0 6 * * *")):  # neither, both
            with pytest.raises(IntegrityError), engine.begin() as connection:
                connection.execute(text(
                    "INSERT INTO job_schedules (operator_id, kind, parameters, interval_seconds, "
                    "cron, enabled, next_run_at, created_at) SELECT id, 'x', '{}', :i, :c, "
                    "true, CURRENT_TIMESTAMP, CURRENT_TIMESTAMP FROM operators"
                ).bindparams(i=interval, c=cron))
        with engine.begin() as connection:
            connection.execute(text(
                "INSERT INTO job_schedules (operator_id, kind, parameters, cron, enabled, "
                "next_run_at, created_at) SELECT id, 'x', '{}', '0 6 * * *', true, "
                "CURRENT_TIMESTAMP, CURRENT_TIMESTAMP FROM operators"))
        downgrade(url, "0017")  # the cron schedule has no interval: it goes, the other stays
        with engine.connect() as connection:
            assert connection.execute(text(
                "SELECT kind, interval_seconds FROM job_schedules")).all() == [
                ("fleet_diagnostics", 86400)]
        engine.dispose()
    finally:
        urls.close()


@pytest.mark.parametrize("backend", BACKENDS)
def test_migration_0019_keeps_snapshots_and_takes_rows_of_any_engine_type(
    backend: str, tmp_path: Path
) -> None:
    from sqlalchemy import text

    columns = ("operator_id, engine_id, aircraft_id, position, upload_id, recorded_at, phase, "
               "alt_ft, mach, dtamb_k, power_pct, t30")
    urls = fresh_database_url(backend, tmp_path)
    url = next(urls)
    try:
        upgrade(url, "0018")
        engine = make_engine(url)
        with engine.begin() as connection:
            connection.execute(text(
                f"INSERT INTO snapshots ({columns}) VALUES (1, 7, 3, 1, 5, "
                "'2026-05-01 00:00:00+00:00', 'cruise', 35000, 0.8, 0, 85, 1400.5)"))
        upgrade(url)
        with engine.connect() as connection:
            assert connection.execute(text(
                "SELECT engine_id, phase, alt_ft, t30, other_signals FROM snapshots")).all() == [
                (7, "cruise", 35000.0, 1400.5, None)]
        with engine.begin() as connection:  # a single-point type's row: no condition, no phase
            connection.execute(text(
                "INSERT INTO snapshots (operator_id, engine_id, aircraft_id, position, "
                "upload_id, recorded_at, other_signals) VALUES (1, 8, 3, 2, 6, "
                "'2026-05-01 00:00:00+00:00', :doc)"), {"doc": '{"N1": 98.5, "EGT": 505}'})
        with engine.connect() as connection:
            other = connection.execute(text(
                "SELECT other_signals FROM snapshots WHERE engine_id = 8")).scalar_one()
            other = other if isinstance(other, dict) else json.loads(other)  # SQLite: text
            assert other == {"N1": 98.5, "EGT": 505}
        downgrade(url, "0018")  # the row the old table cannot hold goes, the other stays
        with engine.connect() as connection:
            assert connection.execute(text(
                "SELECT engine_id, phase, t30 FROM snapshots")).all() == [(7, "cruise", 1400.5)]
            names = {c["name"] for c in inspect(connection).get_columns("snapshots")}
            assert "other_signals" not in names
        engine.dispose()
    finally:
        urls.close()


@pytest.mark.parametrize("backend", BACKENDS)
def test_migration_0020_packs_the_stored_estimates_and_unpacks_them_again(
    backend: str, tmp_path: Path
) -> None:
    """Down to 0019 the estimates are float32 blobs with their phase and operator again; up
    to 0020 they are packed, the layout gains the design's V*^+ and the numbers come back
    within the stored precision."""
    urls = fresh_database_url(backend, tmp_path)
    url = next(urls)
    try:
        upgrade(url)
        engine = make_engine(url)
        factory = make_sessionmaker(engine)
        rng = np.random.default_rng(21)
        vstar = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # tuners: hpc_eff, hpc_flow
        vp = np.linalg.solve(vstar @ vstar.T, vstar).T
        s = LAYOUT.slices()
        values = rng.normal(size=(40, LAYOUT.width))
        for block in ("q_sigma", "z_sigma"):
            values[:, s[block]] = 0.1 + rng.random((40, s[block].stop - s[block].start))
        values[:, s["h"]] = values[:, s["q"]] @ vp.T
        values[:, s["h_sigma"]] = values[:, s["q_sigma"]] @ np.abs(vp).T
        values[:, s["wssr"]] = 4.0 * rng.random((40, 2))
        times = [datetime(2026, 2, 1, tzinfo=UTC) + timedelta(hours=7 * k) for k in range(40)]
        with transaction(factory) as session:
            fleet = make_fleet(session, "Packing Air")
            fleet.design.result = {"vstar": vstar.tolist()}
            aircraft = add_aircraft(session, fleet, "F-PACK")
            engine_id = add_engine(session, fleet, "P1").id
            add_estimates(session, fleet, session.get(Engine, engine_id), aircraft, values, times)
        phases = ["cruise" if i % 2 else "takeoff" for i in range(40)]

        def float32_rows() -> tuple[np.ndarray, list[str], set[int]]:
            with engine.connect() as connection:
                rows = connection.execute(text(
                    "SELECT phase, operator_id, packed FROM estimates WHERE engine_id = :e "
                    "ORDER BY seq"), {"e": engine_id}).all()
            return (LAYOUT.unpack([bytes(r[2]) for r in rows]), [r[0] for r in rows],
                    {r[1] for r in rows})

        def layout_doc() -> dict:
            with factory() as session:
                return session.scalars(select(FilterState.layout)).one()

        def decoded() -> np.ndarray:
            with factory() as session:
                data = load_trend_data(session, engine_id, fleet.design.id)
                assert data is not None and data.phase == phases
                return data.values

        stored = decoded()  # as written at head: h stored (the layout names no V*^+)
        downgrade(url, "0019")
        back, got_phases, operators = float32_rows()
        assert got_phases == phases and operators == {fleet.operator_id}
        np.testing.assert_allclose(back, stored, rtol=1e-6, atol=1e-6)
        assert "health_from_tuners" not in layout_doc()

        upgrade(url)
        np.testing.assert_allclose(layout_doc()["health_from_tuners"], vp)
        packed = decoded()
        for block in ("q", "z"):
            error = np.abs(packed[:, s[block]] - values[:, s[block]])
            assert np.all(error <= values[:, s[block + "_sigma"]] / 7)  # packed twice
        np.testing.assert_allclose(packed[:, s["h"]], packed[:, s["q"]] @ vp.T)
        np.testing.assert_allclose(packed[:, s["h_sigma"]], packed[:, s["q_sigma"]] @ vp.T)
        downgrade(url, "0019")
        np.testing.assert_allclose(float32_rows()[0], packed, rtol=1e-6, atol=1e-6)
        upgrade(url)
        np.testing.assert_allclose(decoded(), packed, rtol=1e-6, atol=1e-6)
        engine.dispose()
    finally:
        urls.close()


@pytest.mark.parametrize("backend", BACKENDS)
def test_migration_0021_takes_the_egt_windows_of_the_stored_estimates(
    backend: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Down to 0020 the EGT windows are gone; up to 0021 they are taken from the stored
    estimates and snapshots, equal to those the pipeline kept."""
    monkeypatch.setattr(estimator, "builtin_schedule", coarse_schedule)
    urls = fresh_database_url(backend, tmp_path)
    url = next(urls)
    try:
        upgrade(url)
        engine = make_engine(url)
        factory = make_sessionmaker(engine)
        with transaction(factory) as session:
            operator_id, table = seed_fleet(session, "Window Migration Air")
            upload(session, operator_id, table)

        def windows() -> list[tuple]:
            with factory() as session:
                return sorted((w.engine_id, w.design_id, w.n_records, w.last_recorded_at,
                               w.fingerprint, w.median)
                              for w in session.scalars(select(EgtWindow)))

        kept = windows()
        assert kept and any(w[-1] is not None for w in kept)
        downgrade(url, "0020")
        with engine.connect() as connection:
            assert "egt_windows" not in inspect(connection).get_table_names()
        upgrade(url)
        assert windows() == kept
        engine.dispose()
    finally:
        urls.close()
