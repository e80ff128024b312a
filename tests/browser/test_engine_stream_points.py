"""The engine page shows the records summarised from a stream recording apart from the
snapshots: a minute of cruise recorded at 20 Hz on an installed engine, two days after its
last snapshot (the engine as its last cruise snapshot saw it, 0.05 % sensor noise), gives two steady
windows; once the estimation job has run they are open diamonds on the health plot, named by
their recording, the engine's recording list counts them, and a click on one opens the
recording page."""

from __future__ import annotations

import io
import time
from datetime import datetime, timedelta
from typing import Any

import httpx
import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pytest

from app.signals import SENSORS, SIGNALS
from tests.browser.conftest import Console, Server, api_get, screenshot, sign_in, traces

pytestmark = pytest.mark.browser

N = 1200  # one minute at 20 Hz: two 30 s windows
DT = 0.05


def _engine(server: Server) -> dict[str, Any]:
    """An installed engine other than the one with the seeded event."""
    status = api_get(server, "/api/v1/fleet/status")
    return next(e for e in status["engines"]
                if e["tail"] and e["engine_id"] != server.seeded.engine_with_event)


def _cruise_minute(snapshot: dict[str, Any]) -> bytes:
    rng = np.random.default_rng(8)
    columns: dict[str, Any] = {"time_s": np.arange(N) * DT}
    for s in SIGNALS:
        value = snapshot.get(s.name)
        if value is None:
            continue
        noise = 5e-4 if s in SENSORS else 0.0  # condition and actuators as commanded
        columns[s.name] = float(value) * (1 + noise * rng.standard_normal(N))
    sink = io.BytesIO()
    pacsv.write_csv(pa.table(columns), sink)
    return sink.getvalue()


def test_stream_points_are_drawn_apart_and_link_to_their_recording(
    page: Any, server: Server, console: Console
) -> None:
    engine = _engine(server)
    eid = engine["engine_id"]
    snaps = api_get(server, f"/api/v1/engines/{eid}/snapshots", limit=100_000)["snapshots"]
    cruise = [s for s in snaps if s["phase"] == "cruise"][-1]
    last = datetime.fromisoformat(snaps[-1]["recorded_at"].replace("Z", "+00:00"))
    started = last + timedelta(days=2)
    response = httpx.post(
        f"{server.base_url}/api/v1/streams", content=_cruise_minute(cruise),
        headers={"X-API-Key": server.seeded.key, "Content-Type": "text/csv"},
        params={"tail": engine["tail"], "position": engine["position"],
                "started_at": started.isoformat(), "flight_id": "STREAM-1"},
    )
    assert response.status_code == 201, response.text[:400]
    rid = response.json()["recording"]["id"]
    assert response.json()["upload"]["affected"][0]["rows"] == 2
    deadline = time.monotonic() + 120
    while True:  # the upload queued the estimation job; the server's runner runs it
        trend = api_get(server, f"/api/v1/engines/{eid}/trend", max_points=1000,
                        health="change")
        if trend["recording"].count(rid) == 2:
            break
        assert time.monotonic() < deadline, "the stream records were not estimated in time"
        time.sleep(0.5)
    assert trend["recording"][-2:] == [rid, rid]
    assert trend["phase"][-2:] == ["cruise", "cruise"]

    sign_in(page, server.seeded.key, f"/engine.html?id={eid}")
    health = traces(page, "#plot-health")
    stream = [t for t in health if t["role"] == "stream"]
    lines = [t for t in health if t["role"] == "line"]
    assert stream and len(stream) == len(lines)  # one marker trace per drawn series
    assert all(t["n"] == 2 for t in stream)
    assert stream[0]["name"] == "stream windows"
    custom = page.evaluate(
        "document.querySelector('#plot-health').data"
        ".filter((t) => t.meta && t.meta.role === 'stream').map((t) => t.customdata)")
    assert all(c == [rid, rid] for c in custom)
    item = page.locator(f"#recordings li[data-recording='{rid}']")
    assert "2 steady windows in the trend" in item.inner_text()
    screenshot(page, "engine-stream-points")
    # A click on a stream point opens its recording.
    page.evaluate(
        """() => { const div = document.querySelector('#plot-health');
           const trace = div.data.find((t) => t.meta && t.meta.role === 'stream');
           const point = { data: trace, customdata: trace.customdata[0] };
           div.emit('plotly_click', { points: [point] }); }""")
    page.wait_for_url(f"**/recording.html?id={rid}")
    page.wait_for_selector("body[data-ready=true]")
    assert console.unexpected() == []
