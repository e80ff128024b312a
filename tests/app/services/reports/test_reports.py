"""Engine and fleet reports, opened with real parsers (openpyxl, pypdf) and compared with what
the API answers for the same engine and fleet, on SQLite and on PostgreSQL.

The fleet is the browser tests' seed (the built-in engine, a simulated fleet with an engine
swap, faults, a water wash), made once per backend in a database of its own.
"""

from __future__ import annotations

import io
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pypdf
import pytest
from fastapi.testclient import TestClient
from openpyxl import load_workbook
from openpyxl.worksheet.worksheet import Worksheet
from sqlalchemy import Engine, func, inspect, select, table

from app.config import Settings
from app.db import make_engine, make_sessionmaker
from app.main import create_app
from app.migrate import upgrade
from app.services.snapshots import estimator
from estimation.engine.schedule import build_schedule
from tests.browser.seed import Seeded, seed
from tests.conftest import BACKENDS, fresh_database_url

pytestmark = pytest.mark.long(seconds=25)

PDF = "application/pdf"
XLSX = "application/vnd.openxmlformats-officedocument.spreadsheetml.sheet"
PNG = b"\x89PNG\r\n\x1a\n"


@dataclass
class Site:
    client: TestClient
    seeded: Seeded
    engine: Engine
    data_dir: Path

    def get(self, path: str, key: str | None = None, **params: Any) -> Any:
        return self.client.get(path, params=params,
                               headers={"X-API-Key": key or self.seeded.key})

    def json(self, path: str, **params: Any) -> Any:
        response = self.get(path, **params)
        assert response.status_code == 200, response.text
        return response.json()


@pytest.fixture(scope="module")
def schedule() -> Iterator[None]:
    built = build_schedule()
    patch = pytest.MonkeyPatch()
    patch.setattr(estimator, "builtin_schedule", lambda: built)
    yield
    patch.undo()


@pytest.fixture(scope="module", params=BACKENDS)
def site(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory,
         schedule: None) -> Iterator[Site]:
    tmp = tmp_path_factory.mktemp(f"reports-{request.param}")
    urls = fresh_database_url(request.param, tmp)
    url = next(urls)
    upgrade(url)
    engine = make_engine(url)
    seeded = seed(make_sessionmaker(engine))
    settings = Settings(data_dir=tmp / "data", database_url=url, log_json=False)
    with TestClient(create_app(settings, engine)) as client:
        yield Site(client, seeded, engine, tmp / "data")
    engine.dispose()
    urls.close()


def _download(site: Site, path: str, fmt: str) -> bytes:
    response = site.get(path, format=fmt)
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == (PDF if fmt == "pdf" else XLSX)
    disposition = response.headers["content-disposition"]
    assert disposition.startswith("attachment;") and disposition.endswith(f'.{fmt}"')
    return response.content


def _rows(sheet: Worksheet) -> list[dict[str, Any]]:
    values = list(sheet.iter_rows(values_only=True))
    return [dict(zip(values[0], row, strict=True)) for row in values[1:]]


def _pairs(sheet: Worksheet) -> dict[str, Any]:
    return {row[0]: row[1] for row in sheet.iter_rows(values_only=True)}


def _utc(iso: str) -> datetime:
    return datetime.fromisoformat(iso.replace("Z", "+00:00")).astimezone(UTC).replace(tzinfo=None)


def _media(body: bytes) -> list[bytes]:
    with zipfile.ZipFile(io.BytesIO(body)) as archive:
        return [archive.read(n) for n in archive.namelist() if n.startswith("xl/media/")]


def _pdf_lines(body: bytes) -> tuple[list[str], int]:
    reader = pypdf.PdfReader(io.BytesIO(body))
    lines = [line.strip() for page in reader.pages for line in page.extract_text().splitlines()]
    images = [image for page in reader.pages for image in page.images]
    assert all(image.data for image in images)
    return lines, len(images)


def _has_run(lines: list[str], run: list[str]) -> bool:
    """``run`` as consecutive lines of the PDF's text (one table cell a line)."""
    return any(lines[i:i + len(run)] == run for i in range(len(lines)))


def _fmt(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f}"


def _counts(engine: Engine) -> dict[str, int]:
    """Rows of every table: a report stores nothing."""
    names = inspect(engine).get_table_names()
    with engine.connect() as connection:
        return {n: connection.execute(select(func.count()).select_from(table(n))).scalar_one()
                for n in names}


def _engine_api(site: Site, engine_id: int) -> dict[str, Any]:
    trend = site.json(f"/api/v1/engines/{engine_id}/trend", health="change", max_points=0)
    status = site.json("/api/v1/fleet/status")
    row = next(e for e in status["engines"] if e["engine_id"] == engine_id)
    events = site.json("/api/v1/events", status="active", engine_id=engine_id, limit=1000)
    groups = {g["key"]: g for g in trend["groups"]}
    figures = {}
    hidden = set(groups["health"].get("unobservable") or ())
    for s in groups["health"]["series"]:
        if s["name"] not in hidden:
            figures[("health change", s["name"])] = (s["value"][-1], s["sigma"][-1])
    for s in groups["performance"]["series"]:
        if s["name"] in {"dEGT", "egt_margin", "thrust_deficit", "Fn_rated"} \
                or s["name"].startswith("SM_"):
            figures[("engineering", s["name"])] = (
                s["value"][-1], None if s["sigma"] is None else s["sigma"][-1])
    return {"trend": trend, "row": row, "events": events["items"], "figures": figures,
            "groups": groups}


def _panels(api: dict[str, Any]) -> int:
    """The plots of the engine page the report draws: health, then each performance panel
    with a series."""
    names = {s["name"] for s in api["groups"]["performance"]["series"]}
    return 1 + sum(1 for panel in (("egt_margin",), ("dEGT",), ("thrust_deficit",),
                                   ("SM_fan", "SM_LPC", "SM_HPC"),
                                   ("SM_fan_change", "SM_LPC_change", "SM_HPC_change"))
                   if names & set(panel))


def _washed_engine(site: Site) -> int:
    actions = site.json("/api/v1/maintenance-actions", limit=100)["items"]
    engine_id: int = actions[-1]["engine_id"]
    return engine_id


@pytest.mark.parametrize("which", ["with events", "washed"])
def test_engine_workbook_holds_the_figures_the_api_answers(site: Site, which: str) -> None:
    engine_id = site.seeded.engine_with_event if which == "with events" else _washed_engine(site)
    assert engine_id is not None
    before = _counts(site.engine)
    body = _download(site, f"/api/v1/engines/{engine_id}/report", "xlsx")
    api = _engine_api(site, engine_id)
    book = load_workbook(io.BytesIO(body))

    summary = _pairs(book["Engine"])
    row, trend = api["row"], api["trend"]
    assert (summary["ESN"], summary["Engine type"], summary["Tail"], summary["Position"]) == (
        row["esn"], row["engine_type"], row["tail"], row["position"])
    assert (summary["State"], summary["Severity"], summary["Records"]) == (
        row["state"], row["severity"], trend["n_records"])
    assert summary["Design"] == trend["design_name"]
    checks = _rows(book["Limit checks"])
    assert [(c["limit"], c["value"], c["level"]) for c in checks] == [
        (c["limit"], c["value"], c["level"]) for c in row["checks"]]

    # The current figures: the latest record's value and 1-sigma, exactly as the API gives.
    figures = {(f["group"], f["name"]): (f["value"], f["sigma"])
               for f in _rows(book["Figures"])}
    assert figures == api["figures"]
    assert {("engineering", n) for n in ("dEGT", "egt_margin", "thrust_deficit", "SM_HPC")} \
        <= set(figures)
    units = {f["name"]: f["unit"] for f in _rows(book["Figures"])}
    assert (units["egt_margin"], units["dEGT"], units["SM_HPC"]) == (
        "°C", "°C", "margin points")

    # The plotted data: every record, every series and its sigma.
    points = _rows(book["Trend"])
    # Excel keeps times to the millisecond.
    assert len(points) == len(trend["time"]) == trend["n_records"]
    assert all(abs((p["time (UTC)"] - _utc(t)).total_seconds()) < 1e-3
               for p, t in zip(points, trend["time"], strict=True))
    compared = []
    for key in ("health", "performance"):
        for s in api["groups"][key]["series"]:
            column = f"{s['name']} [{units.get(s['name'], s['unit'])}]"
            if column in points[0]:
                assert [p[column] for p in points] == s["value"], column
                compared.append(s["name"])
    assert {"fan_eff", "dEGT", "egt_margin", "thrust_deficit", "SM_HPC_change"} <= set(compared)
    assert "thrust_deficit sigma [%]" in points[0]

    # Active events with their isolation, and the maintenance actions.
    events = _rows(book["Active events"])
    assert [e["event"] for e in events] == [e["id"] for e in api["events"]]
    assert events or which == "washed"
    for got, want in zip(events, api["events"], strict=True):
        assert (got["fault"], got["isolated"], got["probability"], got["status"]) == (
            want["fault"], want["confidence"]["isolated"], want["confidence"]["probability"],
            want["status"])
        assert got["ambiguity_group"] == ", ".join(want["confidence"]["ambiguity_group"])
    maintenance = _rows(book["Maintenance"])
    assert [m["kind"] for m in maintenance] == [m["kind"] for m in trend["maintenance"]]
    assert maintenance or which == "with events"
    assert all(abs((got["performed_at (UTC)"] - _utc(want["performed_at"])).total_seconds())
               < 1e-3 for got, want in zip(maintenance, trend["maintenance"], strict=True))

    # One image per plotted panel, each a PNG.
    panels = _panels(api)
    assert len(book["Plots"]._images) == panels
    media = _media(body)
    assert len(media) == panels and all(m.startswith(PNG) and len(m) > 10_000 for m in media)
    assert _counts(site.engine) == before


def test_engine_pdf_prints_the_figures_the_api_answers(site: Site) -> None:
    engine_id = site.seeded.engine_with_event
    assert engine_id is not None
    body = _download(site, f"/api/v1/engines/{engine_id}/report", "pdf")
    assert body.startswith(b"%PDF-")
    api = _engine_api(site, engine_id)
    lines, images = _pdf_lines(body)
    row = api["row"]
    assert f"Engine report · {row['esn']}" in lines
    assert f"State: {row['state']} (severity {row['severity']})" in lines
    assert row["esn"] in lines and f"{row['tail']} position {row['position']}" in lines
    for (_group, name), (value, sigma) in api["figures"].items():
        assert _has_run(lines, [name, _fmt(value), _fmt(sigma)]), name
    for event in api["events"]:
        confidence = event["confidence"]
        assert _has_run(lines, [event["kind"], event["status"], event["fault"],
                                _fmt(event["magnitude"])]), event["id"]
        assert f"{confidence['isolated']} ({_fmt(confidence['probability'])})" in lines
    assert images == _panels(api)


def test_fleet_reports_hold_the_status_alerts_and_deterioration(site: Site) -> None:
    before = _counts(site.engine)
    xlsx = _download(site, "/api/v1/fleet/report", "xlsx")
    pdf = _download(site, "/api/v1/fleet/report", "pdf")
    status = site.json("/api/v1/fleet/status")
    alerts = site.json("/api/v1/events", status="active", limit=1000)["items"]
    deterioration = site.json("/api/v1/fleet/deterioration", bucket="month")
    book = load_workbook(io.BytesIO(xlsx))

    summary = _pairs(book["Fleet"])
    assert (summary["Engines"], summary["Active events"]) == (
        status["n_engines"], status["n_open_events"])
    assert {k.removeprefix("State "): v for k, v in summary.items()
            if k.startswith("State ")} == status["states"]
    ranked = _rows(book["Status"])
    assert [(e["rank"], e["esn"], e["state"], e["severity"], e["tail"]) for e in ranked] == [
        (e["rank"], e["esn"], e["state"], e["severity"], e["tail"]) for e in status["engines"]]
    for got, want in zip(ranked, status["engines"], strict=True):
        health = want["health"] or {}
        assert (got["worst_health"], got["worst_health_value [%]"],
                got["worst_health_sigma [%]"], got["thrust_deficit [%]"]) == (
            health.get("worst_health"), health.get("worst_health_value"),
            health.get("worst_health_sigma"), health.get("thrust_deficit"))
    assert [a["event"] for a in _rows(book["Active alerts"])] == [a["id"] for a in alerts] != []
    means = [(r["series"], r["month (UTC)"], r["mean"], r["spread (1 sd)"])
             for r in _rows(book["Deterioration"])]
    want = [(s["name"], _utc(t), s["mean"][i], s["sigma"][i])
            for g in deterioration["groups"] for s in (*g["health"], *g["aux"])
            for i, t in enumerate(g["time"])]
    assert means == want != []
    assert len(book["Plots"]._images) == 2
    assert len(_media(xlsx)) == 2 and all(m.startswith(PNG) for m in _media(xlsx))

    lines, images = _pdf_lines(pdf)
    assert _has_run(lines, [str(status["n_engines"]), str(status["n_open_events"]),
                            *(str(status["states"][s])
                              for s in ("alert", "watch", "normal", "no_data"))])
    # Ranked worst first: the ESNs appear in the API's order.
    positions = [lines.index(e["esn"]) for e in status["engines"]]
    assert positions == sorted(positions)
    for e in status["engines"]:
        if e["health"] and e["health"]["worst_health"]:
            h = e["health"]
            assert (f"{h['worst_health']} {_fmt(h['worst_health_value'])} ± "
                    f"{_fmt(h['worst_health_sigma'])}") in lines
    for alert in alerts:
        assert _has_run(lines, [str(alert["id"]), alert["esn"]]), alert["id"]
    assert images == 2
    assert _counts(site.engine) == before


def test_bad_requests_get_a_4xx_and_store_nothing(site: Site) -> None:
    seeded = site.seeded
    engine_id = seeded.engine_with_event
    before = _counts(site.engine)
    files_before = sorted(site.data_dir.rglob("*")) if site.data_dir.exists() else []
    cases = [
        # Another operator's engine is not found, as an unknown one.
        (f"/api/v1/engines/{seeded.other_engine_id}/report", {"format": "pdf"}, 404, "engine"),
        (f"/api/v1/engines/{10**9}/report", {"format": "xlsx"}, 404, "engine"),
        (f"/api/v1/engines/{engine_id}/report", {"format": "docx"}, 422, "format"),
        (f"/api/v1/engines/{engine_id}/report", {}, 422, "format"),
        ("/api/v1/fleet/report", {"format": "csv"}, 422, "format"),
        (f"/api/v1/engines/{engine_id}x/report", {"format": "pdf"}, 422, "engine_id"),
    ]
    for path, params, code, field in cases:
        response = site.get(path, **params)
        assert response.status_code == code, (path, params, response.text)
        assert response.headers["content-type"] == "application/json"
        assert field in response.json()["error"]["message"], response.text
    # The other operator sees its own engine (never estimated: a report without plots), and
    # the seeded one not.
    for fmt in ("pdf", "xlsx"):
        response = site.get(f"/api/v1/engines/{seeded.other_engine_id}/report",
                            seeded.other_key, format=fmt)
        assert response.status_code == 200, response.text
    assert _media(response.content) == []
    assert _pairs(load_workbook(io.BytesIO(response.content))["Engine"])["ESN"] == "OTHER-1"
    assert site.get(f"/api/v1/engines/{engine_id}/report", seeded.other_key,
                    format="xlsx").status_code == 404
    assert site.get("/api/v1/fleet/report", "fh_wrong", format="pdf").status_code == 401
    # A viewer may read reports.
    assert site.get("/api/v1/fleet/report", seeded.viewer_key, format="xlsx").status_code == 200
    assert _counts(site.engine) == before
    after = sorted(site.data_dir.rglob("*")) if site.data_dir.exists() else []
    assert after == files_before
