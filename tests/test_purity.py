"""The numeric core stays pure: no web, database or data-frame library is imported by it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import estimation

FORBIDDEN = ("fastapi", "sqlalchemy", "pydantic", "starlette", "pandas", "app")


def test_estimation_imports_no_service_or_dataframe_library() -> None:
    root = Path(estimation.__file__).parent
    modules = sorted(
        ".".join(path.relative_to(root.parent).with_suffix("").parts).removesuffix(".__init__")
        for path in root.rglob("*.py")
    )
    assert "estimation" in modules
    script = (
        "import importlib, sys\n"
        f"for name in {modules!r}: importlib.import_module(name)\n"
        f"bad = sorted(m for m in sys.modules if m.split('.')[0] in {FORBIDDEN!r})\n"
        "print(','.join(bad))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=root.parent, check=True
    )
    assert result.stdout.strip() == "", f"estimation pulled in: {result.stdout.strip()}"


def test_the_signal_catalogue_needs_no_database_library() -> None:
    """Parsing, estimation and schemas read the catalogue of signals without SQLAlchemy."""
    script = (
        "import sys, app.signals\n"
        "print(','.join(sorted(m for m in sys.modules if m.split('.')[0] == 'sqlalchemy')))\n"
    )
    root = Path(estimation.__file__).parent.parent
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=root, check=True
    )
    assert result.stdout.strip() == "", f"app.signals pulled in: {result.stdout.strip()[:200]}"
