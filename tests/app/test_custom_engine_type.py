"""A second engine type defined entirely through the API, on both databases.

A made-up two-spool engine whose model file names its sensors N1, N2, EGT and PS3 and its fuel
flow FF (names that appear nowhere in fleethealth's code), with a fault library of its own in
its design. One of its engines and one of the built-in type sit on one aircraft; snapshots are
uploaded in each type's own columns (EGT in degC, converted to the model file's K), generated
from the linear model with a known health drift and sensor noise. The trend's health estimates
track that health within their stated bands, a fault injected from the custom library raises an
event named after it, and the engine's data comes back in its type's names and units. Bad input
is refused with a 4xx and stores nothing. Queued jobs run as a server's job runner runs them.
"""

from __future__ import annotations

import csv
import io
import uuid
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session, sessionmaker

from app.jobs.runner import run_pending
from app.services.tenancy import service as tenancy
from estimation.model import LinearModel

T0 = datetime(2026, 3, 1, tzinfo=UTC)
HEALTH = ("fan_eff", "hpc_eff", "hpt_eff", "hpt_flow")
SENSORS = (("N1", "%"), ("N2", "%"), ("EGT", "K"), ("PS3", "kPa"))
TRIM = {"N1": 92.0, "N2": 96.0, "EGT": 1050.0, "PS3": 2900.0, "FF": 3600.0, "thrust": 110.0}
NOISE_STD = (0.15, 0.15, 0.25, 0.25)  # percent of trim
# The design's fault library: names of this engine's maker, shifts in its health parameters.
LIBRARY: list[dict[str, Any]] = [
    {"name": "Fan blade erosion", "shifts": {"fan_eff": -2.0}},
    {"name": "HPC fouling", "shifts": {"hpc_eff": -2.0}},
    {"name": "HPT nozzle burn-through", "shifts": {"hpt_eff": -1.5, "hpt_flow": 2.0}},
]
DRIFT = np.array([-1.2, -0.6, -0.8, 0.5])  # health change over the drift records, percent
N_DRIFT = 240
N_FAULT = 80
HOURS_APART = 12.0  # one snapshot a flight


def made_up_model(seed: int = 20261125) -> dict[str, Any]:
    """A fleethealth.linear-model/1 file for a made-up engine: two spool states, fuel flow in,
    four health parameters, four sensors, thrust out; random but well-conditioned matrices."""
    rng = np.random.default_rng(seed)
    A = np.diag([0.92, 0.88]) + 0.02 * rng.standard_normal((2, 2))
    B = 0.05 + 0.02 * rng.random((2, 1))
    C = np.array([[1.0, 0.0], [0.0, 1.0], [0.3, 0.5], [0.2, 0.6]])
    D = 0.1 * rng.standard_normal((4, 1))
    L = 0.03 * rng.standard_normal((2, 4))
    # The health directions the sensors see, well apart: M near a scaled orthogonal matrix.
    q, _r = np.linalg.qr(rng.standard_normal((4, 4)))
    M = 0.8 * q + 0.1 * rng.standard_normal((4, 4))
    F = np.array([[0.6, 0.4]])
    G = np.array([[0.2]])
    N = 0.2 * rng.standard_normal((1, 4))
    return {
        "format": "fleethealth.linear-model/1",
        "dt": 0.02,
        "exported_by": "a made-up engine maker's deck",
        "signals": {
            "states": [{"name": "N1", "unit": "%"}, {"name": "N2", "unit": "%"}],
            "inputs": [{"name": "FF", "unit": "kg/h"}],
            "health": [{"name": h, "unit": "%"} for h in HEALTH],
            "sensors": [{"name": n, "unit": u} for n, u in SENSORS],
            "aux": [{"name": "thrust", "unit": "kN"}],
        },
        "matrices": {k: v.tolist() for k, v in
                     dict(A=A, B=B, C=C, D=D, L=L, M=M, F=F, G=G, N=N).items()},
        "trim": TRIM,
        "sensor_noise_std": list(NOISE_STD),
    }


def sensor_values(model: LinearModel, health: np.ndarray, rng: np.random.Generator
                  ) -> np.ndarray:
    """Steady-state sensors [S, 4] in the model's units at health [S, 4] (FF at its trim)."""
    G_y, _G_z = model.steady_state_gains()
    trim = np.array([TRIM[n] for n, _u in SENSORS])
    noise = rng.standard_normal((len(health), 4)) * np.array(NOISE_STD)
    return trim * (1.0 + (health @ G_y.T + noise) / 100.0)


@dataclass(frozen=True)
class Fleet:
    key: dict[str, str]
    builtin_engine: int
    custom_engine: int
    custom_type: str
    model: LinearModel


def api(client: TestClient, key: dict[str, str], method: str, path: str, **kw: Any) -> Any:
    response = client.request(method, f"/api/v1{path}", headers=key, **kw)
    assert response.status_code in (200, 201), f"{method} {path}: {response.text}"
    return response.json()


@pytest.fixture
def fleet(client: TestClient, session: Session) -> Fleet:
    """Everything through the API but the operator and its key: two engine types, their
    models (the built-in engine's linearised, the made-up one's file), the custom type's
    design with its fault library (active), and one engine of each on aircraft N900."""
    operator = tenancy.create_operator(session, name=f"Custom Air {uuid.uuid4().hex[:8]}")
    _r, secret = tenancy.issue_api_key(session, operator=operator, role="analyst", name="k")
    session.commit()
    key = {"X-API-Key": secret}
    builtin = api(client, key, "POST", "/engine-types", json={"name": "Built-in turbofan"})
    custom = api(client, key, "POST", "/engine-types", json={"name": "MadeUp M2"})
    api(client, key, "POST", "/engine-models/builtin", json={
        "engine_type_id": builtin["id"], "name": "SLS", "alt_ft": 0.0, "mach": 0.0,
        "power_pct": 100.0})
    document = made_up_model()
    model = api(client, key, "POST", "/engine-models", json={
        "engine_type_id": custom["id"], "name": "cruise deck", "model": document})
    design = api(client, key, "POST", "/designs", json={
        "engine_model_id": model["id"], "name": "M2 four tuners",
        "spec": {"format": "fleethealth.design-spec/1", "method": "subset", "tuners": 4,
                 "noise": {"Q": [0.01, 0.01], "Qh": [0.05] * 4, "Ph": [2.0] * 4},
                 "faults": LIBRARY}})
    assert design["status"] == "ready", design
    assert design["result"]["faults"]["names"] == [f["name"] for f in LIBRARY]
    api(client, key, "POST", f"/designs/{design['id']}/activate")
    aircraft = api(client, key, "POST", "/aircraft", json={"tail": "N900"})
    engines = {}
    for esn, type_id, position in (("B-900", builtin["id"], 1), ("M-900", custom["id"], 2)):
        engine = api(client, key, "POST", "/engines",
                     json={"esn": esn, "engine_type_id": type_id})
        api(client, key, "POST", "/installations", json={
            "engine_id": engine["id"], "aircraft_id": aircraft["id"], "position": position,
            "installed_at": (T0 - timedelta(days=10)).isoformat()})
        engines[esn] = engine["id"]
    return Fleet(key, engines["B-900"], engines["M-900"], "MadeUp M2",
                 LinearModel.from_dict(document))


HEADER = ["recorded_at", "tail", "position", "flight_id", "phase", "alt_ft", "mach", "dtamb_k",
          "power_pct", "T30", "Nf", "N1[%]", "N2[%]", "EGT[degC]", "PS3", "FF[kg/h]"]


def csv_body(fleet: Fleet, start: int, health: np.ndarray, seed: int) -> bytes:
    """Rows of both engines of N900, one flight each: the built-in engine's in its columns
    (phase, condition, T30, Nf), the made-up engine's in its own (EGT sent in degC)."""
    rng = np.random.default_rng(seed)
    y = sensor_values(fleet.model, health, rng)
    sink = io.StringIO()
    writer = csv.writer(sink)
    writer.writerow(HEADER)
    for i, (n1, n2, egt, ps3) in enumerate(y):
        when = (T0 + timedelta(hours=HOURS_APART * (start + i))).strftime("%Y-%m-%dT%H:%M:%SZ")
        flight = f"MU{start + i:04d}"
        writer.writerow([when, "N900", 1, flight, "cruise", 35000, 0.8, 0, 85,
                         1390 + rng.normal(), 2300 + rng.normal(), "", "", "", "", ""])
        writer.writerow([when, "N900", 2, flight, "", "", "", "", "", "", "",
                         f"{n1:.5f}", f"{n2:.5f}", f"{egt - 273.15:.4f}", f"{ps3:.3f}",
                         f"{TRIM['FF']:.1f}"])
    return sink.getvalue().encode()


def upload(client: TestClient, fleet: Fleet, body: bytes) -> Any:
    return client.post("/api/v1/snapshots/file", content=body,
                       headers={**fleet.key, "Content-Type": "text/csv"})


def run_jobs(session_factory: sessionmaker[Session]) -> None:
    """The queued jobs (the uploads' estimation), as a server's job runner runs them."""
    run_pending(session_factory)


def drift(n: int) -> np.ndarray:
    return np.outer(np.linspace(0.0, 1.0, n), DRIFT)


def test_a_custom_engine_type_is_estimated_trended_and_isolated_in_its_own_names(
    client: TestClient, session_factory: sessionmaker[Session], fleet: Fleet, tmp_path: Path
) -> None:
    truth = drift(N_DRIFT)
    response = upload(client, fleet, csv_body(fleet, 0, truth, seed=1))
    assert response.status_code == 201, response.text
    assert response.json()["rows_stored"] == 2 * N_DRIFT
    run_jobs(session_factory)

    # Stored as sent, in the type's names and the model file's units (EGT back in K).
    exported = client.get(f"/api/v1/engines/{fleet.custom_engine}/snapshots",
                          params={"format": "csv"}, headers=fleet.key)
    assert exported.status_code == 200
    rows = list(csv.DictReader(io.StringIO(exported.text)))
    assert len(rows) == N_DRIFT
    assert {"N1[%]", "N2[%]", "EGT[K]", "PS3[kPa]", "FF[kg/h]"} <= set(rows[0])
    assert "T30" not in rows[0] and rows[0]["phase"] == ""
    y0 = sensor_values(fleet.model, truth[:1], np.random.default_rng(1))[0]
    assert float(rows[0]["EGT[K]"]) == pytest.approx(y0[2], abs=1e-3)
    listed = api(client, fleet.key, "GET", f"/engines/{fleet.custom_engine}/snapshots")
    assert listed["units"]["EGT"] == "K" and listed["snapshots"][0]["N1"] == pytest.approx(
        y0[0], abs=1e-4)
    builtin = api(client, fleet.key, "GET", f"/engines/{fleet.builtin_engine}/snapshots")
    assert builtin["count"] == N_DRIFT and builtin["snapshots"][0]["T30"] > 1380

    # The trend: the design's names, and estimates that track the known health.
    trend = api(client, fleet.key, "GET", f"/engines/{fleet.custom_engine}/trend",
                params={"max_points": 0})
    groups = {g["key"]: g for g in trend["groups"]}
    names = {g: [s["name"] for s in groups[g]["series"]] for g in groups}
    assert names["health"] == list(HEALTH)
    assert names["residuals"] == [name for name, _unit in SENSORS]
    assert names["wssr"] == [f["name"] for f in LIBRARY]
    settled = slice(N_DRIFT // 4, None)  # after the start covariance has shrunk
    for j, name in enumerate(HEALTH):
        series = next(s for s in groups["health"]["series"] if s["name"] == name)
        value = np.array(series["value"], float)
        sigma = np.array(series["sigma"], float)
        assert len(value) == N_DRIFT
        error = (value - truth[:, j])[settled]
        inside = np.abs(error) <= 2.0 * sigma[settled]
        assert inside.mean() >= 0.8, (name, inside.mean(), np.abs(error).max())
        assert np.all(np.abs(error) <= 4.0 * sigma[settled]), name
        # It moves with the health: the change over the drift is seen, with its sign.
        assert np.sign(value[-20:].mean() - value[:20].mean()) == np.sign(DRIFT[j])

    # An abrupt fault of the custom library (1.5 times its nominal shift) on top of the drift.
    fault = LIBRARY[2]
    step = np.array([fault["shifts"].get(h, 0.0) for h in HEALTH]) * 1.5
    after = DRIFT + step + np.zeros((N_FAULT, 4))
    response = upload(client, fleet, csv_body(fleet, N_DRIFT, after, seed=2))
    assert response.status_code == 201, response.text
    run_jobs(session_factory)
    events = api(client, fleet.key, "GET", "/events",
                 params={"engine_id": fleet.custom_engine})["items"]
    isolated = [e for e in events if e["kind"] == "isolated_fault"]
    assert [e["fault"] for e in isolated] == [fault["name"]], events
    event = isolated[0]
    assert set(event["wssr"]) == {f["name"] for f in LIBRARY}
    assert event["detected_at"] >= (T0 + timedelta(hours=HOURS_APART * N_DRIFT)).isoformat()
    assert event["magnitude"] == pytest.approx(1.5, abs=0.5)
    # The built-in engine has no design: nothing estimated for it, nothing raised.
    assert api(client, fleet.key, "GET", "/events",
               params={"engine_id": fleet.builtin_engine})["items"] == []


def test_bad_input_for_a_custom_type_is_refused_and_stores_nothing(
    client: TestClient, fleet: Fleet
) -> None:
    good = csv_body(fleet, 0, drift(3), seed=3).decode().splitlines()

    def refused(lines: list[str], *expected: str) -> None:
        response = upload(client, fleet, ("\n".join(lines) + "\n").encode())
        assert response.status_code == 422, response.text
        for text in expected:
            assert text in response.text, (text, response.text)

    # A built-in signal on the custom engine's row: unknown for that type, named with it.
    header = good[0].split(",")
    t30 = header.index("T30")
    row = good[2].split(",")
    row[t30] = "1400"
    refused([good[0], good[1], ",".join(row)], "unknown column 'T30'", "'MadeUp M2'")
    # A unit that is not a temperature's.
    refused([good[0].replace("EGT[degC]", "EGT[psia]"), *good[1:]],
            "unknown unit 'psia' for temperature")
    # A column every row needs, and one the built-in engine's type is scheduled on.
    position = header.index("position")
    refused([",".join(v for k, v in enumerate(line.split(",")) if k != position)
             for line in good], "required column 'position' is missing")
    phase = header.index("phase")
    refused([",".join(v for k, v in enumerate(line.split(",")) if k != phase)
             for line in good], "required column 'phase' is missing",
            "'Built-in turbofan' is scheduled on it")
    for engine_id in (fleet.custom_engine, fleet.builtin_engine):
        assert api(client, fleet.key, "GET", f"/engines/{engine_id}/snapshots")["count"] == 0
    uploads = api(client, fleet.key, "GET", "/uploads")["items"]
    assert [u["status"] for u in uploads] == ["rejected"] * 4


def test_a_custom_types_records_read_the_same_from_memory_and_from_the_database(
    client: TestClient, session: Session, fleet: Fleet
) -> None:
    """The estimation reads the design's signals where they are stored: kept in memory after
    the upload (each other signal a column) or from the database (by name from the JSON
    object; PostgreSQL's binary path or the generic one), the same numbers either way; rows
    without a phase or an operating condition read as "" and NaN."""
    from app.services import fresh_records
    from app.services.snapshots import rows
    from app.signals import stored_at

    response = upload(client, fleet, csv_body(fleet, 0, drift(30), seed=4))
    assert response.status_code == 201, response.text
    places = tuple(stored_at(n) for n, _u in SENSORS)
    inputs = (stored_at("FF"),)
    wants = [(fleet.custom_engine, None)]
    kept = fresh_records.take(session, [fleet.custom_engine, fleet.builtin_engine])
    assert kept is not None and kept.num_rows == 60
    memory = rows.load_records(session, wants, places, inputs, kept=kept)[fleet.custom_engine]
    stored = rows.load_records(session, wants, places, inputs)[fleet.custom_engine]
    assert len(stored.epoch) == 30 and stored.phase == [""] * 30
    assert np.isnan(stored.conditions).all()
    expected = sensor_values(fleet.model, drift(30), np.random.default_rng(4))
    np.testing.assert_allclose(stored.y, expected, rtol=1e-6)  # as written in the CSV
    assert np.all(stored.u == TRIM["FF"])
    for a, b in ((memory.y, stored.y), (memory.u, stored.u), (memory.conditions,
                                                               stored.conditions)):
        assert np.array_equal(a, b, equal_nan=True)
    assert memory.phase == stored.phase and np.array_equal(memory.epoch, stored.epoch)


def test_a_custom_types_rows_sent_again_are_duplicates_and_other_values_a_conflict(
    client: TestClient, fleet: Fleet
) -> None:
    body = csv_body(fleet, 0, drift(4), seed=5)
    assert upload(client, fleet, body).status_code == 201
    # The same rows in another file with two more flights: the stored ones are duplicates.
    more = csv_body(fleet, 4, drift(2), seed=6).decode().splitlines()[1:]
    extra = "\n".join([*body.decode().splitlines(), *more]).encode()
    response = upload(client, fleet, extra)
    assert response.status_code == 201, response.text
    assert (response.json()["rows_stored"], response.json()["rows_duplicate"]) == (4, 8)
    # Another EGT under a stored engine and time: 409, naming the signal; nothing stored.
    lines = body.decode().splitlines()
    header = lines[0].split(",")
    row = lines[2].split(",")
    row[header.index("EGT[degC]")] = str(float(row[header.index("EGT[degC]")]) + 5.0)
    response = upload(client, fleet, "\n".join([lines[0], lines[1], ",".join(row)]).encode())
    assert response.status_code == 409, response.text
    assert "differs in EGT" in response.text
    assert api(client, fleet.key, "GET", f"/engines/{fleet.custom_engine}/snapshots")[
        "count"] == 6
