"""Trends per engine and per tail: stored estimates come back as stored, decimation equals a
bucket-by-bucket recomputation, CSV equals JSON, a tail's trend is the union of its
installations cut to their periods."""

from __future__ import annotations

import csv
import io
import uuid
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

import numpy as np
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.models import (
    Aircraft,
    Engine,
    EngineModel,
    EngineType,
    EstimatorDesign,
    Installation,
    Snapshot,
    Upload,
)
from app.models.estimates import Estimate, EstimateLayout, FilterState
from app.services.snapshots import buckets
from app.services.tenancy.service import create_operator, issue_api_key
from app.services.trends import service as trends
from app.signals import PHASES

T0 = datetime(2026, 1, 1, tzinfo=UTC)
LAYOUT = EstimateLayout(
    tuners=("q1", "q2"),
    health=("hpc_eff", "hpc_flow", "fan_eff"),
    aux=("Fn", "SmHPC"),
    sensors=("T30", "Nc", "T48"),
    faults=("Fan", "HPC"),
)


@dataclass
class Fleet:
    operator_id: int
    key: str
    engine_type: EngineType
    design: EstimatorDesign
    upload: Upload


def make_fleet(session: Session, name: str = "Trend Air") -> Fleet:
    """An operator with one engine type, a model and an active design, and an upload row."""
    operator = create_operator(session, name=f"{name} {uuid.uuid4().hex[:8]}")
    _row, key = issue_api_key(session, operator=operator, role="admin", name="test")
    engine_type = EngineType(operator_id=operator.id, name="generic")
    session.add(engine_type)
    session.flush()
    model = EngineModel(
        operator_id=operator.id, engine_type_id=engine_type.id, name="m", version=1,
        source="imported", format="fleethealth.linear-model/1", content={}, checksum="0" * 64,
        dt=0.015, n_states=2, sensor_names=[], health_names=[], aux_names=[],
    )
    session.add(model)
    session.flush()
    design = EstimatorDesign(
        operator_id=operator.id, engine_type_id=engine_type.id, engine_model_id=model.id,
        name="d", spec={}, status="ready", active=True,
    )
    upload = Upload(
        operator_id=operator.id, kind="snapshots", content_format="json", checksum="0" * 64,
        status="stored",
    )
    session.add_all([design, upload])
    session.flush()
    return Fleet(operator.id, key, engine_type, design, upload)


def add_engine(session: Session, fleet: Fleet, esn: str) -> Engine:
    engine = Engine(operator_id=fleet.operator_id, esn=esn, engine_type_id=fleet.engine_type.id)
    session.add(engine)
    session.flush()
    return engine


def add_aircraft(session: Session, fleet: Fleet, tail: str) -> Aircraft:
    aircraft = Aircraft(operator_id=fleet.operator_id, tail=tail)
    session.add(aircraft)
    session.flush()
    return aircraft


def add_estimates(
    session: Session, fleet: Fleet, engine: Engine, aircraft: Aircraft, values: np.ndarray,
    times: list[datetime],
) -> None:
    """Snapshots at ``times`` and an estimate per snapshot with ``values`` (n, width), with
    the engine's deterioration periods."""
    snaps = [
        Snapshot(
            operator_id=fleet.operator_id, engine_id=engine.id, aircraft_id=aircraft.id,
            position=1, upload_id=fleet.upload.id, recorded_at=t,
            phase="cruise" if i % 2 else "takeoff", alt_ft=0.0, mach=0.0, dtamb_k=0.0,
            power_pct=100.0,
        )
        for i, t in enumerate(times)
    ]
    session.add_all(snaps)
    session.flush()
    blobs = LAYOUT.encode(values, np.array([PHASES.index(s.phase) for s in snaps]))
    session.add_all(
        Estimate(
            engine_id=engine.id, design_id=fleet.design.id, seq=i, recorded_at=s.recorded_at,
            packed=blob.tobytes(),
        )
        for i, (s, blob) in enumerate(zip(snaps, blobs, strict=True))
    )
    session.add(
        FilterState(
            operator_id=fleet.operator_id, engine_id=engine.id, design_id=fleet.design.id,
            layout=LAYOUT.to_dict(), state={}, n_records=len(times),
            last_recorded_at=times[-1],
        )
    )
    session.flush()
    # The periods the pipeline keeps beside the estimates it writes.
    buckets.rebuild(session, operator_id=fleet.operator_id, design_id=fleet.design.id,
                    layout=LAYOUT, engine_ids=[engine.id])


def as_stored(values: np.ndarray) -> np.ndarray:
    """``values`` as the stored estimates give them back (``EstimateLayout.encode``)."""
    return LAYOUT.decode(LAYOUT.encode(values, np.zeros(len(values), dtype=int))).values


def _values(rng: np.random.Generator, n: int) -> np.ndarray:
    """Estimates of ``n`` records: normal values, 1-sigmas 0.1-1.1 and WSSRs 0-5."""
    values = rng.normal(size=(n, LAYOUT.width))
    s = LAYOUT.slices()
    for block in ("q_sigma", "h_sigma", "z_sigma"):
        values[:, s[block]] = 0.1 + rng.random((n, s[block].stop - s[block].start))
    values[:, s["wssr"]] = 5.0 * rng.random((n, s["wssr"].stop - s["wssr"].start))
    return values


def _series(trend: dict, key: str, name: str) -> dict:
    group = next(g for g in trend["groups"] if g["key"] == key)
    return next(s for s in group["series"] if s["name"] == name)


def test_full_resolution_trend_returns_the_stored_numbers(session: Session) -> None:
    rng = np.random.default_rng(1)
    fleet = make_fleet(session)
    engine, aircraft = add_engine(session, fleet, "E1"), add_aircraft(session, fleet, "F-AAAA")
    values = _values(rng, 50)
    times = [T0 + timedelta(hours=6 * i) for i in range(50)]
    add_estimates(session, fleet, engine, aircraft, values, times)

    trend = trends.engine_trend(session, fleet.operator_id, engine.id, max_points=0)
    assert trend["n_records"] == 50 and not trend["decimated"]
    kept = as_stored(values)
    s = LAYOUT.slices()
    for j, name in enumerate(LAYOUT.health):
        series = _series(trend, "health", name)
        np.testing.assert_allclose(series["value"], kept[:, s["h"]][:, j], atol=6e-5)
        np.testing.assert_allclose(series["sigma"], kept[:, s["h_sigma"]][:, j], atol=6e-5)
    np.testing.assert_allclose(
        _series(trend, "wssr", "HPC")["value"], kept[:, s["wssr"]][:, 1], atol=6e-5
    )
    parsed = [datetime.fromisoformat(t.replace("Z", "+00:00")) for t in trend["time"]]
    assert parsed == times
    assert trend["seq"] == list(range(50))


def test_time_range_and_decimation_match_a_direct_recomputation(session: Session) -> None:
    rng = np.random.default_rng(2)
    fleet = make_fleet(session)
    engine, aircraft = add_engine(session, fleet, "E1"), add_aircraft(session, fleet, "F-AAAA")
    n = 1000
    values = _values(rng, n)
    times = [T0 + timedelta(hours=3 * i) for i in range(n)]
    add_estimates(session, fleet, engine, aircraft, values, times)
    kept = as_stored(values)

    start, end = times[100], times[900]
    trend = trends.engine_trend(
        session, fleet.operator_id, engine.id, start=start, end=end, max_points=64
    )
    inside = kept[100:900]
    assert trend["n_records"] == 800 and trend["decimated"] and trend["n_points"] == 64
    col = LAYOUT.slices()["h"].start
    series = _series(trend, "health", "hpc_eff")
    # 800 records in 64 buckets of 12 or 13 consecutive records: recompute bucket by bucket.
    edges = [int(np.floor(k * 800 / 64)) for k in range(64)] + [800]
    for k in range(64):
        chunk = inside[edges[k] : edges[k + 1], col]
        assert abs(series["value"][k] - chunk.mean()) < 1e-4
        assert abs(series["min"][k] - chunk.min()) < 6e-5
        assert abs(series["max"][k] - chunk.max()) < 6e-5
    assert trend["seq"][0] == np.mean(np.arange(100, 100 + edges[1]))


def test_csv_carries_the_same_numbers_as_json(client: TestClient, session: Session) -> None:
    rng = np.random.default_rng(3)
    fleet = make_fleet(session)
    engine, aircraft = add_engine(session, fleet, "E9"), add_aircraft(session, fleet, "F-AAAA")
    add_estimates(
        session, fleet, engine, aircraft, _values(rng, 20),
        [T0 + timedelta(days=i) for i in range(20)],
    )
    session.commit()
    headers = {"X-API-Key": fleet.key}
    body = client.get(f"/api/v1/engines/{engine.id}/trend", headers=headers).json()
    text = client.get(
        f"/api/v1/engines/{engine.id}/trend", params={"format": "csv"}, headers=headers
    )
    assert text.status_code == 200 and text.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(text.text)))
    assert len(rows) == body["n_points"] == 20
    column = [float(r["health.hpc_flow[%]"]) for r in rows]
    np.testing.assert_allclose(column, _series(body, "health", "hpc_flow")["value"])
    sigma = [float(r["aux.Fn.sigma[%]"]) for r in rows]
    np.testing.assert_allclose(sigma, _series(body, "aux", "Fn")["sigma"])


def test_tail_trend_is_the_union_of_installations(client: TestClient, session: Session) -> None:
    rng = np.random.default_rng(4)
    fleet = make_fleet(session)
    first, second = add_engine(session, fleet, "E1"), add_engine(session, fleet, "E2")
    tail, other = add_aircraft(session, fleet, "F-AAAA"), add_aircraft(session, fleet, "F-BBBB")
    swap = T0 + timedelta(days=10)
    session.add_all(
        [
            Installation(operator_id=fleet.operator_id, engine_id=first.id, aircraft_id=tail.id,
                         position=1, installed_at=T0, removed_at=swap),
            Installation(operator_id=fleet.operator_id, engine_id=second.id, aircraft_id=tail.id,
                         position=1, installed_at=swap),
            Installation(operator_id=fleet.operator_id, engine_id=first.id,
                         aircraft_id=other.id, position=2, installed_at=swap),
        ]
    )
    days = [T0 + timedelta(days=i, hours=1) for i in range(20)]
    add_estimates(session, fleet, first, tail, _values(rng, 20), days)
    add_estimates(session, fleet, second, tail, _values(rng, 20), days)
    session.commit()

    body = client.get(
        f"/api/v1/aircraft/{tail.id}/trend", headers={"X-API-Key": fleet.key}
    ).json()
    segments = body["segments"]
    assert [s["trend"]["esn"] for s in segments] == ["E1", "E2"]
    assert segments[0]["trend"]["n_records"] == sum(t < swap for t in days)
    assert segments[1]["trend"]["n_records"] == sum(t >= swap for t in days)
    # Each segment equals the engine's own trend over the same period.
    own = trends.engine_trend(session, fleet.operator_id, first.id, end=swap)
    assert _series(own, "tuners", "q1")["value"] == _series(
        segments[0]["trend"], "tuners", "q1"
    )["value"]
    text = client.get(
        f"/api/v1/aircraft/{tail.id}/trend", params={"format": "csv"},
        headers={"X-API-Key": fleet.key},
    ).text
    rows = list(csv.DictReader(io.StringIO(text)))
    assert [r["esn"] for r in rows] == ["E1"] * 10 + ["E2"] * 10


def test_another_operators_engine_is_not_found(client: TestClient, session: Session) -> None:
    mine, theirs = make_fleet(session, "Mine"), make_fleet(session, "Theirs")
    engine = add_engine(session, theirs, "E1")
    aircraft = add_aircraft(session, theirs, "F-CCCC")
    session.commit()
    headers = {"X-API-Key": mine.key}
    assert client.get(f"/api/v1/engines/{engine.id}/trend", headers=headers).status_code == 404
    assert client.get(f"/api/v1/aircraft/{aircraft.id}/trend", headers=headers).status_code == 404
    naive = client.get(
        f"/api/v1/engines/{engine.id}/trend", params={"start": "2026-01-01T00:00:00"},
        headers={"X-API-Key": theirs.key},
    )
    assert naive.status_code == 422


def _reference_trend(values: np.ndarray, phases: list[str], max_points: int) -> dict:
    """The decimated columns computed record by record in plain Python."""
    n = len(values)
    edges = [int(np.floor(k * n / max_points)) for k in range(max_points)] + [n]
    edges = sorted(set(edges))
    out: dict = {"phase": [], "value": [], "min": [], "max": []}
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        bucket = set(phases[a:b])
        out["phase"].append(bucket.pop() if len(bucket) == 1 else None)
        chunk = values[a:b]
        out["value"].append(chunk.mean(axis=0))
        out["min"].append(chunk.min(axis=0))
        out["max"].append(chunk.max(axis=0))
    return {k: (np.array(v) if k != "phase" else v) for k, v in out.items()}


def test_json_fast_path_equals_the_dict_and_a_direct_recomputation(
    client: TestClient, session: Session
) -> None:
    """Records stored out of seq order, missing sensors (NaN) and mixed phases: the route's
    bytes equal the dict encoded by json, and the numbers equal a bucket-by-bucket loop."""
    rng = np.random.default_rng(8)
    fleet = make_fleet(session)
    engine, aircraft = add_engine(session, fleet, "E7"), add_aircraft(session, fleet, "F-FAST")
    n = 701
    values = _values(rng, n)
    values[rng.random(n) < 0.05, LAYOUT.slices()["residual"].start] = np.nan
    times = [T0 + timedelta(hours=5 * i) for i in range(n)]
    # Insert in a shuffled order so the rows do not come back in seq order by accident.
    order = rng.permutation(n)
    snaps = [
        Snapshot(
            operator_id=fleet.operator_id, engine_id=engine.id, aircraft_id=aircraft.id,
            position=1, upload_id=fleet.upload.id, recorded_at=times[i],
            phase="cruise" if (i // 7) % 3 else "takeoff", alt_ft=0.0, mach=0.0, dtamb_k=0.0,
            power_pct=100.0,
        )
        for i in order
    ]
    session.add_all(snaps)
    session.flush()
    blobs = LAYOUT.encode(values, np.array([PHASES.index("cruise" if (i // 7) % 3 else "takeoff")
                                             for i in range(n)]))
    session.add_all(
        Estimate(
            engine_id=engine.id, design_id=fleet.design.id, seq=int(i),
            recorded_at=s.recorded_at, packed=blobs[i].tobytes(),
        )
        for i, s in zip(order, snaps, strict=True)
    )
    session.add(
        FilterState(
            operator_id=fleet.operator_id, engine_id=engine.id, design_id=fleet.design.id,
            layout=LAYOUT.to_dict(), state={}, n_records=n, last_recorded_at=times[-1],
        )
    )
    session.commit()
    headers = {"X-API-Key": fleet.key}
    phases = ["cruise" if (i // 7) % 3 else "takeoff" for i in range(n)]
    kept = as_stored(values)
    for max_points in (0, 50, 333):
        body = client.get(
            f"/api/v1/engines/{engine.id}/trend", params={"max_points": max_points},
            headers=headers,
        ).content
        trend = trends.engine_trend(session, fleet.operator_id, engine.id, max_points=max_points)
        assert body == trends.to_json(trend)
        if max_points == 0:
            assert trend["phase"] == phases and trend["seq"] == list(range(n))
            continue
        ref = _reference_trend(kept, phases, max_points)
        assert trend["phase"] == ref["phase"]
        s = LAYOUT.slices()
        for key, block in (("health", "h"), ("residuals", "residual")):
            group = next(g for g in trend["groups"] if g["key"] == key)
            for j, series in enumerate(group["series"]):
                col = s[block].start + j
                for field in ("value", "min", "max"):
                    got = np.array([np.nan if v is None else v for v in series[field]])
                    np.testing.assert_allclose(got, np.round(ref[field][:, col], 4), atol=1e-12)


def test_markers_are_the_engines_installations_maintenance_and_events_in_time_order(
    session: Session,
) -> None:
    from app.models import MaintenanceAction
    from app.models.estimates import Event

    rng = np.random.default_rng(10)
    fleet = make_fleet(session, "Marker Air")
    engine, other = add_engine(session, fleet, "M1"), add_engine(session, fleet, "M2")
    first, second = add_aircraft(session, fleet, "F-MRKA"), add_aircraft(session, fleet, "F-MRKB")
    swap = T0 + timedelta(days=3)
    installs = [
        Installation(operator_id=fleet.operator_id, engine_id=engine.id, aircraft_id=second.id,
                     position=2, installed_at=swap),
        Installation(operator_id=fleet.operator_id, engine_id=engine.id, aircraft_id=first.id,
                     position=1, installed_at=T0, removed_at=swap),
    ]
    actions = [
        MaintenanceAction(operator_id=fleet.operator_id, engine_id=engine.id, kind=kind,
                          performed_at=T0 + timedelta(days=d, microseconds=250), notes=notes)
        for kind, d, notes in (("shop_visit", 5, 'said "ok"'), ("water_wash", 1, ""))
    ]
    session.add_all(installs + actions)
    add_estimates(session, fleet, engine, first, _values(rng, 8),
                  [T0 + timedelta(days=i) for i in range(8)])
    events = [
        Event(operator_id=fleet.operator_id, engine_id=e.id, design_id=fleet.design.id, seq=s,
              detected_at=T0 + timedelta(days=s), kind=kind, fault=fault, statistic=9.0,
              wssr={}, shift={}, status=status)
        for e, s, kind, fault, status in (
            (engine, 6, "isolated_fault", "HPC", "open"),
            (engine, 2, "shift", None, "acknowledged"),
            (other, 2, "shift", None, "open"),
        )
    ]
    session.add_all(events)
    session.flush()

    trend = trends.engine_trend(session, fleet.operator_id, engine.id)
    assert trend["installations"] == [
        {"aircraft_id": i.aircraft_id, "tail": {first.id: "F-MRKA", second.id: "F-MRKB"}[
            i.aircraft_id], "position": i.position, "installed_at": i.installed_at,
         "removed_at": i.removed_at}
        for i in sorted(installs, key=lambda i: i.installed_at)
    ]
    assert trend["maintenance"] == [
        {"id": a.id, "kind": a.kind, "performed_at": a.performed_at, "notes": a.notes}
        for a in sorted(actions, key=lambda a: a.performed_at)
    ]
    assert trend["events"] == [
        {"id": e.id, "detected_at": e.detected_at, "kind": e.kind, "fault": e.fault,
         "status": e.status, "seq": e.seq}
        for e in sorted(events[:2], key=lambda e: e.detected_at)
    ]


def test_a_read_asking_for_more_buckets_than_a_plot_shows_is_refused(
    client: TestClient, session: Session
) -> None:
    """Bounded cost: at most 20,000 buckets per read (0 keeps every record)."""
    fleet = make_fleet(session)
    engine, aircraft = add_engine(session, fleet, "E10"), add_aircraft(session, fleet, "F-AAAB")
    add_estimates(session, fleet, engine, aircraft, _values(np.random.default_rng(4), 5),
                  [T0 + timedelta(days=i) for i in range(5)])
    session.commit()
    headers = {"X-API-Key": fleet.key}
    path = f"/api/v1/engines/{engine.id}/trend"
    too_many = client.get(path, params={"max_points": 100_000}, headers=headers)
    assert too_many.status_code == 422
    assert "max_points" in too_many.json()["error"]["message"]
    assert client.get(path, params={"max_points": 20_000}, headers=headers).status_code == 200
