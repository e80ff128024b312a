"""The import contracts of pyproject.toml hold, and a forbidden import breaks them."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.paths import ROOT

pytest.importorskip("importlinter")


def lint_imports(root: Path) -> subprocess.CompletedProcess[str]:
    """Run lint-imports on the packages under ``root`` with its pyproject.toml."""
    script = "from importlinter.cli import lint_imports_command; lint_imports_command()"
    env = {**os.environ, "PYTHONPATH": str(root)}
    return subprocess.run(
        [sys.executable, "-c", script, "--no-cache"],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def copy_tree(destination: Path) -> Path:
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for package in ("app", "estimation"):
        shutil.copytree(ROOT / package, destination / package, ignore=ignore)
    shutil.copy(ROOT / "pyproject.toml", destination / "pyproject.toml")
    return destination


def test_the_contracts_are_kept() -> None:
    result = lint_imports(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


FORBIDDEN = [
    # (module, the import added to it, the contract it breaks)
    ("estimation/__init__.py", "import app.config", "estimation is independent of app"),
    ("app/routers/health.py", "import app.models", "Routers use services"),
    ("app/routers/me.py", "import app.routers.keys", "Routers do not import one another"),
    ("app/services/common.py", "import app.jobs", "Layers:"),
]


def test_forbidden_imports_break_their_contracts(tmp_path: Path) -> None:
    root = copy_tree(tmp_path)
    for module, bad_import, _ in FORBIDDEN:
        path = root / module
        path.write_text(path.read_text() + f"\n{bad_import}  # noqa: E402\n")
    result = lint_imports(root)
    assert result.returncode != 0, result.stdout
    # The summary lists each contract with KEPT or BROKEN; names wrap, so collapse whitespace.
    summary = " ".join(result.stdout.split("Broken contracts")[0].split())
    for _, _, contract in FORBIDDEN:
        verdict = re.search(re.escape(contract) + r".*?\b(KEPT|BROKEN)\b", summary)
        assert verdict is not None and verdict.group(1) == "BROKEN", result.stdout
