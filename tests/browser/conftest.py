"""Browser tests: Playwright driving the system Chromium against a real uvicorn server.

The server runs in a thread of the test process on a free port of 127.0.0.1, on a SQLite file
migrated with Alembic and seeded through the services (``seed.py``). Chromium is the system
package (Playwright's own browser download does not work here): without it the tests skip
with the reason, except under CI (``CI`` set), where a missing Chromium is a failure.
"""

from __future__ import annotations

import os
import shutil
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote

import httpx
import pytest

from tests.support.server import free_port

SCREENSHOTS = Path(__file__).resolve().parents[2] / "test-artifacts" / "screenshots"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
]
LAPTOP = {"width": 1440, "height": 900}


def chromium_path() -> str | None:
    configured = os.environ.get("FLEETHEALTH_CHROMIUM")
    if configured:
        return configured if Path(configured).exists() else None
    if Path("/usr/bin/chromium").exists():
        return "/usr/bin/chromium"
    return shutil.which("chromium") or shutil.which("chromium-browser")


def _unavailable(reason: str) -> None:
    if os.environ.get("CI"):
        pytest.fail(f"browser tests cannot run under CI: {reason}")
    pytest.skip(reason)



@dataclass
class Server:
    base_url: str
    seeded: Any
    factory: Any


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    import uvicorn

    from app.config import Settings
    from app.db import make_engine, make_sessionmaker
    from app.main import create_app
    from app.migrate import upgrade
    from app.services.snapshots import estimator
    from estimation.engine.schedule import build_schedule
    from tests.browser.seed import seed

    data_dir = tmp_path_factory.mktemp("browser-data")
    url = f"sqlite:///{data_dir / 'fleethealth.sqlite3'}"
    upgrade(url)
    schedule = build_schedule()
    patch = pytest.MonkeyPatch()
    patch.setattr(estimator, "builtin_schedule", lambda: schedule)
    engine = make_engine(url)
    factory = make_sessionmaker(engine)
    seeded = seed(factory)
    # Jobs in threads of this process: they see the schedule patched above.
    settings = Settings(data_dir=data_dir, database_url=url, log_json=False, log_level="WARNING",
                        job_host="thread")
    # Jobs the server's runner executes read the settings through get_settings (the stream
    # estimation job its data directory): the server's own.
    patch.setattr("app.config.get_settings", lambda: settings)
    app = create_app(settings, engine, background_jobs=True)
    port = free_port()
    config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on")
    uv = uvicorn.Server(config)
    thread = threading.Thread(target=uv.run, name="uvicorn", daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not uv.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError("uvicorn did not start")
        time.sleep(0.05)
    yield Server(f"http://127.0.0.1:{port}", seeded, factory)
    uv.should_exit = True
    thread.join(timeout=10)
    patch.undo()


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    executable = chromium_path()
    if executable is None:
        _unavailable(
            "Chromium is not installed (apt-get install chromium, or set FLEETHEALTH_CHROMIUM)"
        )
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _unavailable("the playwright python package is not installed")
    with sync_playwright() as pw:
        try:
            chromium = pw.chromium.launch(executable_path=executable, args=CHROMIUM_ARGS)
        except Exception as exc:  # noqa: BLE001 - any launch failure is reported as the reason
            _unavailable(f"Chromium at {executable} did not start: {exc}")
        yield chromium
        chromium.close()


@dataclass
class Console:
    """Console errors and uncaught page errors seen while a test ran."""

    errors: list[str] = field(default_factory=list)

    def unexpected(self, *allowed: str) -> list[str]:
        return [e for e in self.errors if not any(a in e for a in allowed)]


@pytest.fixture
def console() -> Console:
    return Console()


@pytest.fixture(scope="session")
def context(browser: Any, server: Server) -> Iterator[Any]:
    """One browser context for the run: plotly.js is fetched and compiled once (HTTP and code
    cache); each test's page starts signed out (the ``page`` fixture forgets the key)."""
    ctx = browser.new_context(viewport=LAPTOP, base_url=server.base_url)
    yield ctx
    ctx.close()


@pytest.fixture
def page(context: Any, console: Console) -> Iterator[Any]:
    pg = context.new_page()
    pg.on("console", lambda m: console.errors.append(f"console: {m.text} @ {m.location.get('url')}")
          if m.type == "error" else None)
    pg.on("pageerror", lambda e: console.errors.append(f"pageerror: {e}"))
    pg.set_default_timeout(30_000)  # generous: CI shares the machine with other suites
    # The key is kept for the whole browser (localStorage): each test starts signed out.
    pg.goto("/signin.html")
    pg.evaluate("localStorage.clear()")
    yield pg
    pg.close()


def sign_in(page: Any, key: str, then: str = "/") -> None:
    """Sign in through the sign-in form and wait for the page ``then`` to be ready."""
    page.goto(f"/signin.html?next={quote(then, safe='/')}")  # as the pages send it
    page.fill("#key", key)
    page.click("button[type=submit]")
    page.wait_for_url(f"**{then}")
    page.wait_for_selector("body[data-ready=true]")


def screenshot(page: Any, name: str) -> Path:
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    path = SCREENSHOTS / f"{name}.png"
    page.screenshot(path=str(path), full_page=True)
    return path


def traces(page: Any, selector: str) -> list[dict[str, Any]]:
    """Name (the API's code of the series, ``meta.code``, where the trace is named by the
    glossary), shown label, type and point count of every trace of the plotly plot at
    ``selector``."""
    result: list[dict[str, Any]] = page.evaluate(
        """(sel) => (document.querySelector(sel).data || []).map((t) => ({
            name: (t.meta && t.meta.code) || t.name, label: t.name,
            type: t.type || 'scatter', role: t.meta && t.meta.role,
            n: (t.y || t.z || t.x || []).length }))""",
        selector,
    )
    return result


def api_get(server: Server, path: str, **params: Any) -> Any:
    """GET ``path`` (its own query string kept unless ``params`` are given) from the server's
    API with the seeded key; the JSON of a 200."""
    response = httpx.get(
        f"{server.base_url}{path}", params=params or None,
        headers={"X-API-Key": server.seeded.key},
    )
    assert response.status_code == 200, response.text
    return response.json()


def unnamed_controls(page: Any, section: str) -> list[str]:
    """Form controls without a label and buttons without a name in ``section``."""
    result: list[str] = page.evaluate(
        """(sel) => [...document.querySelectorAll(`${sel} input, ${sel} select, ${sel} textarea`)]
            .filter((el) => !el.labels || !el.labels.length).map((el) => el.id || el.name)
            .concat([...document.querySelectorAll(`${sel} button`)]
            .filter((b) => !b.textContent.trim() && !b.getAttribute('aria-label'))
            .map((b) => b.id))""",
        section,
    )
    return result


# WCAG 2.0 and 2.1, levels A and AA: the rules axe-core runs on every page.
WCAG_AA = ["wcag2a", "wcag2aa", "wcag21a", "wcag21aa"]


def axe_violations(page: Any, context: Any = None) -> list[dict[str, Any]]:
    """axe-core's WCAG 2.1 AA violations on the page as it is now (``context``: a selector or
    axe context object to check only part of it). axe-core comes from the ``axe-playwright-python``
    test extra, which ships a pinned ``axe.min.js``; it is injected into the page on each call."""
    from axe_playwright_python.base import AXE_SCRIPT

    if not page.evaluate("typeof window.axe !== 'undefined'"):
        page.add_script_tag(content=AXE_SCRIPT)
    result: list[dict[str, Any]] = page.evaluate(
        """async ([context, tags]) => {
            const r = await axe.run(context || document,
                { runOnly: { type: 'tag', values: tags }, resultTypes: ['violations'] });
            return r.violations.map((v) => ({ id: v.id, impact: v.impact, help: v.help,
                nodes: v.nodes.map((n) => ({ target: n.target.join(' '),
                    html: n.html.slice(0, 200), summary: n.failureSummary })) }));
        }""",
        [context, WCAG_AA],
    )
    return result


def axe_report(violations: list[dict[str, Any]]) -> str:
    """The violations as lines a person reads in a failed assertion."""
    return "\n".join(
        f"{v['id']} ({v['impact']}): {v['help']}: {n['target']} {n['html']} -- {n['summary']}"
        for v in violations for n in v["nodes"]
    )


def cruise_stream_csv(seed: int, n: int, dt: float) -> tuple[bytes, list[str]]:
    """A stream recording of ``n`` samples every ``dt`` s at cruise on the built-in schedule's
    trims with 0.2 % sensor noise, as CSV; and its sensor names. The power setting creeps from
    80 to 83 %: no 30 s window is steady, so the recording (a nominal engine, not the one it is
    filed under) stays out of the engine's history, where it would move the seeded events the
    tests look for (steady windows: test_engine_stream_points)."""
    import io

    import numpy as np
    import pyarrow as pa
    import pyarrow.csv as pacsv

    from app.services.snapshots import estimator
    from app.services.streams import estimator as stream_estimator

    sched = estimator.builtin_schedule()
    t = np.arange(n) * dt
    cond = np.column_stack([np.full(n, 35000.0), np.full(n, 0.8), np.zeros(n),
                            80.0 + 3.0 * t / (n * dt)])
    trims = sched.trims_at(cond[:, [0, 1, 3, 2]])
    rng = np.random.default_rng(seed)
    columns: dict[str, Any] = {"time_s": t, "alt_ft": cond[:, 0], "mach": cond[:, 1],
                               "dtamb_k": cond[:, 2], "power_pct": cond[:, 3]}
    sensors = [s for s in sched.template.sensors if s.name != "Wf"]
    for s in sensors:
        a, b = stream_estimator._stored_affine(s.name, s.unit)
        columns[s.name] = (a * trims[s.name] + b) * (1 + rng.normal(size=n) * 0.002)
    sink = io.BytesIO()
    pacsv.write_csv(pa.table(columns), sink)
    return sink.getvalue(), [s.name for s in sensors]
