"""Every route that shows an engine shows it in its own type's names and units.

An engine type whose model names its signals N1, N2, EGT [degC], PS3, FF_meas, its health
parameters fan_loss ... hpt_area and its aux outputs THR and SMC (``tests.support.custom_type``)
is defined through the API, one of its engines estimated from uploaded snapshots; then the
routes the pages read (trend as JSON and CSV, the aircraft's trend, the type's parameter set, its
models and design, the fleet status, events, the engine's snapshot export, its Excel report) are
read and must carry the type's names, and none of the built-in engine's signal, health or aux
names. The static pages' scripts must not hard-code the built-in names either: what they show
for an engine comes from these routes. On both databases.
"""

from __future__ import annotations

import io
import re
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session, sessionmaker

from app.jobs.runner import run_pending
from app.signals import MEASURED
from estimation.engine.health import HEALTH_NAMES
from estimation.engine.sensors import AUX_NAMES
from tests.support import custom_type as own

ROOT = Path(__file__).resolve().parents[2]
BUILTIN = sorted({s.name for s in MEASURED} | set(HEALTH_NAMES) | set(AUX_NAMES)
                 | {"SmFan", "SmLPC", "SmHPC"})
WORD = re.compile(r"(?<![A-Za-z0-9_])(" + "|".join(map(re.escape, BUILTIN)) + r")(?![A-Za-z0-9_])")


def builtin_names_in(text: str) -> list[str]:
    return sorted(set(WORD.findall(text)))


@pytest.fixture
def custom(client: TestClient, session: Session,
           session_factory: sessionmaker[Session]) -> tuple[own.CustomFleet, dict[str, str]]:
    _operator, key = own.make_operator(session)
    headers = {"X-API-Key": key}

    post = own.poster(client.post, headers)

    def upload(body: bytes) -> None:
        response = client.post("/api/v1/snapshots/file", content=body,
                               headers={**headers, "Content-Type": "text/csv"})
        assert response.status_code in (200, 201, 202), response.text

    fleet = own.setup(post, upload, n=120)
    run_pending(session_factory)
    return fleet, headers


def test_every_route_shows_the_engine_in_its_types_names_and_units(
    client: TestClient, custom: tuple[own.CustomFleet, dict[str, str]],
    session_factory: sessionmaker[Session],
) -> None:
    fleet, headers = custom
    # A water wash half-way: the recovery across it is measured in the type's health names.
    wash = client.post("/api/v1/maintenance-actions", headers=headers, json={
        "engine_id": fleet.engine_id, "kind": "water_wash",
        "performed_at": own.utc(own.T0 + timedelta(days=25, hours=6))})
    assert wash.status_code == 201, wash.text
    run_pending(session_factory)

    def get(path: str, **params: Any) -> Any:
        response = client.get(path, params=params, headers=headers)
        assert response.status_code == 200, (path, response.text)
        return response

    trend = get(f"/api/v1/engines/{fleet.engine_id}/trend").json()
    assert trend["n_records"] == 120
    groups = {g["key"]: g for g in trend["groups"]}
    assert [s["name"] for s in groups["health"]["series"]] == list(own.HEALTH)
    assert [s["name"] for s in groups["aux"]["series"]] == ["THR", "SMC"]
    assert [s["name"] for s in groups["residuals"]["series"]] == ["N1", "N2", "EGT", "PS3"]
    assert [s["name"] for s in groups["wssr"]["series"]] == [f["name"] for f in own.LIBRARY]
    # No engineering-unit figures for another engine than the built-in: said, not left out.
    assert "performance" not in groups and "built-in engine" in trend["performance_note"]
    params = get(f"/api/v1/engine-types/{fleet.type_id}/parameters").json()
    assert [(s["name"], s["unit"]) for s in params["signals"]] == [
        ("FF", "kg/h"), ("IGV", "deg"), ("N1", "%"), ("N2", "%"), ("EGT", "degC"),
        ("PS3", "kPa"), ("FF_meas", "kg/h")]
    assert params["scheduled_on"] == [] and params["from_models"]
    models = get("/api/v1/engine-models", engine_type_id=fleet.type_id).json()["items"]
    assert models[0]["signals"]["sensors"][2] == {"name": "EGT", "unit": "degC"}
    exported = get(f"/api/v1/engines/{fleet.engine_id}/snapshots")
    assert exported.json()["units"]["EGT"] == "degC"
    snapshots = exported.text
    texts = {
        "trend": get(f"/api/v1/engines/{fleet.engine_id}/trend").text,
        "trend, change": get(f"/api/v1/engines/{fleet.engine_id}/trend", health="change").text,
        "trend CSV": get(f"/api/v1/engines/{fleet.engine_id}/trend", format="csv").text,
        "aircraft trend": get(f"/api/v1/aircraft/{fleet.aircraft_id}/trend").text,
        "parameter set": get(f"/api/v1/engine-types/{fleet.type_id}/parameters").text,
        "engine models": get("/api/v1/engine-models", engine_type_id=fleet.type_id).text,
        "model content": get(f"/api/v1/engine-models/{fleet.model_id}/content").text,
        "design": get(f"/api/v1/designs/{fleet.design_id}").text,
        "fleet status": get("/api/v1/fleet/status").text,
        "deterioration": get("/api/v1/fleet/deterioration").text,
        "events": get("/api/v1/events").text,
        "snapshots": snapshots,
        "recovery": get(f"/api/v1/maintenance-actions/{wash.json()['id']}/recovery").text,
    }
    for name, text in texts.items():
        assert builtin_names_in(text) == [], name
    for name in ("N1", "EGT", "fan_loss", "THR"):
        assert name in texts["trend"] and name in texts["trend CSV"], name
    assert "fan_loss" in texts["recovery"]
    # The engine's report (Excel): its sheets name the type's signals only.
    from openpyxl import load_workbook

    report = get(f"/api/v1/engines/{fleet.engine_id}/report", format="xlsx").content
    book = load_workbook(io.BytesIO(report), read_only=True)
    cells = " ".join(str(v) for ws in book.worksheets for row in ws.iter_rows(values_only=True)
                     for v in row if v is not None)
    assert builtin_names_in(cells) == [] and "fan_loss" in cells
    assert "built-in engine's nonlinear model" in cells  # why it has no engineering figures


# Scripts of the pages allowed to name the built-in engine's signals, and why.
ALLOWED = {
    # The glossary is a dictionary of the built-in engine's codes: a code it does not know
    # (any other type's) is shown as it is.
    "glossary.js": set(BUILTIN),
    # Colours keyed by the built-in health parameters, so each keeps its colour on every plot;
    # any other name takes the palette in order.
    "plots.js": set(HEALTH_NAMES),
    # The performance group's series (engineering units, the built-in engine's only: the API
    # sends the group for a design of the built-in engine and a note otherwise).
    "engine.js": {"Fn", "SM_fan", "SM_LPC", "SM_HPC"},
}


def test_the_pages_do_not_hard_code_the_builtin_names() -> None:
    found = {}
    for path in sorted((ROOT / "static").rglob("*")):
        if path.suffix not in (".js", ".html") or "vendor" in path.parts:
            continue
        literals = re.findall(r"""["'`]([^"'`\n]{1,40})["'`]""", path.read_text())
        names = {n for lit in literals for n in builtin_names_in(lit)}
        extra = sorted(names - ALLOWED.get(path.name, set()))
        if extra:
            found[path.name] = extra
    assert found == {}
