"""The runtime install: ``pip install .`` without extras gives a working service.

The Dockerfile installs the project this way, and every compose service runs the CLI it
installs, so a runtime import of a test-only library breaks every deployment. Two checks:

- the runtime dependencies declared in pyproject.toml are exactly the distributions the
  shipped code imports (plus the few it needs without importing them, each with its reason);
- a clean virtual environment with ``pip install .`` runs ``fleethealth --help``,
  ``fleethealth engine trim`` and ``fleethealth serve`` until ``/health`` answers and the
  dashboard is served.

The Docker image is built from that install where a Docker daemon answers.
"""

from __future__ import annotations

import ast
import json
import os
import re
import shutil
import subprocess
import sys
import time
import tomllib
import urllib.request
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest

from tests.support.server import free_port

pytestmark = pytest.mark.long(seconds=55)

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ("app", "estimation", "migrations")

# Needed at run time without an import statement in the shipped code.
USED_WITHOUT_IMPORT = {
    "plotly": "the dashboard's plotly.min.js is read from the package's files",
    "python-multipart": "FastAPI parses multipart upload forms with it",
    "uvicorn": "imported inside `fleethealth serve`",
    "kaleido": "plotly renders the report plots to PNG with it (its wheel ships the browser)",
    "pillow": "openpyxl reads the size of the report's plot images with it",
}


def _declared() -> set[str]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    return {re.split(r"[\[<>=!~ ;]", dep, maxsplit=1)[0].lower() for dep in project["dependencies"]}


def _imported_distributions() -> set[str]:
    top: set[str] = set()
    for package in SHIPPED:
        for path in (ROOT / package).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    top.update(alias.name.split(".")[0] for alias in node.names)
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    top.add(node.module.split(".")[0])
    top -= set(sys.stdlib_module_names) | set(SHIPPED)
    mapping = packages_distributions()
    unknown = sorted(name for name in top if name not in mapping)
    assert not unknown, f"imported but not installed: {unknown}"
    return {dist.lower() for name in top for dist in mapping[name][:1]}


def test_runtime_dependencies_are_what_the_code_imports() -> None:
    declared = _declared()
    imported = _imported_distributions()
    # A distribution imported only because another one pulls it in (starlette through
    # fastapi, pydantic-core through pydantic, ...) counts as covered by that one.
    transitive = {"starlette", "pydantic-core", "pydantic_core", "typing-extensions", "rich"}
    missing = sorted(imported - declared - transitive)
    assert not missing, f"imported at run time but not a runtime dependency: {missing}"
    unused = sorted(declared - imported - set(USED_WITHOUT_IMPORT))
    assert not unused, f"runtime dependencies nothing imports: {unused}"
    test_only = {"pytest", "ruff", "mypy", "playwright", "pytest-timeout"}
    leaked = sorted(imported & test_only)
    assert not leaked, f"test-only libraries imported at run time: {leaked}"



@pytest.fixture(scope="module")
def runtime_venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A clean virtual environment with ``pip install .`` (no extras), as the image does."""
    venv = tmp_path_factory.mktemp("runtime") / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    source = tmp_path_factory.mktemp("source") / "fleethealth"
    # Install from a copy of the tracked tree, as the image's COPY lines do (no .venv, no data).
    shutil.copytree(
        ROOT, source,
        ignore=shutil.ignore_patterns(".venv", ".git", "data", "__pycache__", "*.egg-info",
                                      "build", ".mypy_cache", ".ruff_cache", ".pytest_cache"),
    )
    result = subprocess.run(
        [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", "--no-compile",
         str(source)],
        capture_output=True, text=True, timeout=900,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return venv


def _clean_env(data_dir: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("FLEETHEALTH_", "PYTHON"))}
    env["FLEETHEALTH_DATA_DIR"] = str(data_dir)
    return env


def test_clean_install_runs_the_cli_and_serves(runtime_venv: Path, tmp_path: Path) -> None:
    cli = str(runtime_venv / "bin" / "fleethealth")
    env = _clean_env(tmp_path / "data")
    # Run from an empty folder so nothing of the source tree can be imported by accident.
    work = tmp_path / "elsewhere"
    work.mkdir()

    help_text = subprocess.run([cli, "--help"], capture_output=True, text=True, env=env,
                               cwd=work, timeout=120)
    assert help_text.returncode == 0, help_text.stderr
    assert "serve" in help_text.stdout and "import-cmapss" in help_text.stdout

    trim = subprocess.run(
        [cli, "engine", "trim", "--alt", "0", "--mach", "0", "--power", "100", "--json"],
        capture_output=True, text=True, env=env, cwd=work, timeout=300,
    )
    assert trim.returncode == 0, trim.stderr
    assert json.loads(trim.stdout)

    port = free_port()
    server = subprocess.Popen(
        [cli, "serve", "--host", "127.0.0.1", "--port", str(port), "--no-demo", "--no-jobs"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=work,
    )
    try:
        deadline = time.monotonic() + 120
        health = None
        while time.monotonic() < deadline and server.poll() is None:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2) as r:
                    health = json.loads(r.read())
                    break
            except OSError:
                time.sleep(0.3)
        assert health is not None, "server never answered /health"
        assert health["status"] == "ok" and health["database"] == "ok"
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5) as r:
            assert "text/html" in r.headers["content-type"]
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/vendor/plotly.min.js",
                                    timeout=10) as r:
            assert r.status == 200
    finally:
        server.terminate()
        try:
            out, _ = server.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            server.kill()
            out, _ = server.communicate()
    assert "Traceback" not in out, out[-3000:]


def test_clean_install_renders_report_plots(runtime_venv: Path, tmp_path: Path) -> None:
    """The report's plots render from the wheels alone: kaleido's own browser, no system one."""
    code = (
        "import plotly.graph_objects as go\n"
        "from app.services.reports import plots\n"
        "image = plots.png(go.Figure(go.Scatter(x=[1, 2, 3], y=[3, 1, 2])))\n"
        "print(image[:8] == b'\\x89PNG\\r\\n\\x1a\\n', len(image))\n"
    )
    env = _clean_env(tmp_path / "data")
    env.pop("BROWSER_PATH", None)
    result = subprocess.run([str(runtime_venv / "bin" / "python"), "-c", code],
                            capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.startswith("True "), result.stdout


def _docker_daemon() -> bool:
    if shutil.which("docker") is None:
        return False
    return subprocess.run(["docker", "info"], capture_output=True, timeout=30).returncode == 0


@pytest.mark.skipif(not _docker_daemon(), reason="no Docker daemon answers on this machine")
def test_docker_image_builds_from_the_runtime_install() -> None:
    tag = f"fleethealth-test:{os.getpid()}"
    build = subprocess.run(["docker", "build", "-t", tag, str(ROOT)], capture_output=True,
                           text=True, timeout=1800)
    try:
        assert build.returncode == 0, build.stderr[-3000:]
        run = subprocess.run(["docker", "run", "--rm", tag, "fleethealth", "--help"],
                             capture_output=True, text=True, timeout=300)
        assert run.returncode == 0 and "serve" in run.stdout, run.stderr
    finally:
        subprocess.run(["docker", "rmi", "-f", tag], capture_output=True, timeout=120)
