"""Alembic is the only way tables are made: upgrade an empty database to head, and back."""

from __future__ import annotations

from pathlib import Path

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import inspect

from app.db import make_engine
from app.migrate import downgrade, upgrade
from app.models import Base
from tests.conftest import BACKENDS, fresh_database_url


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
