"""Installations: no overlaps per engine or tail position, resolution at a time, engine swaps."""

from __future__ import annotations

from datetime import datetime, timedelta

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.errors import Conflict
from app.models import Installation
from app.services.fleet import service as fleet
from tests.support.fleetkit import (
    T0,
    Tenant,
    error_of,
    make_tenant,
    post,
)

API = "/api/v1"
DAY = timedelta(days=1)


@pytest.fixture
def tenant(session: Session) -> Tenant:
    return make_tenant(session, "Swap Air")


def _setup(client: TestClient, tenant: Tenant, tails: int = 2, engines: int = 3) -> None:
    et = post(client, tenant, f"{API}/engine-types", {"name": "TF-2S"})
    for i in range(tails):
        tenant.ids[f"T{i}"] = post(client, tenant, f"{API}/aircraft", {"tail": f"N{i}FH"})["id"]
    for i in range(engines):
        body = {"esn": f"E{i}", "engine_type_id": et["id"]}
        tenant.ids[f"E{i}"] = post(client, tenant, f"{API}/engines", body)["id"]


def _install(
    client: TestClient,
    tenant: Tenant,
    engine: str,
    tail: str,
    position: int,
    start: datetime,
    end: datetime | None = None,
) -> object:
    body = {
        "engine_id": tenant.ids[engine],
        "aircraft_id": tenant.ids[tail],
        "position": position,
        "installed_at": start.isoformat(),
        "removed_at": end.isoformat() if end else None,
    }
    return client.post(f"{API}/installations", json=body, headers=tenant.headers())


def _installations(session: Session, tenant: Tenant) -> int:
    stmt = select(func.count()).where(Installation.operator_id == tenant.operator_id)
    return int(session.scalar(stmt) or 0)


def test_overlaps_are_refused_for_an_engine_and_for_a_position(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    _setup(client, tenant)
    first = _install(client, tenant, "E0", "T0", 1, T0, T0 + 10 * DAY)
    assert first.status_code == 201  # type: ignore[attr-defined]

    # E0 elsewhere while it sits on T0/1; another engine at T0/1 meanwhile; both open-ended too.
    refused = [
        ("E0", "T1", 2, T0 + 5 * DAY, T0 + 20 * DAY, "E0"),
        ("E0", "T1", 1, T0 - DAY, None, "E0"),
        ("E1", "T0", 1, T0 + 9 * DAY, T0 + 11 * DAY, "T0"),
        ("E1", "T0", 1, T0 - 3 * DAY, T0 + DAY, "T0"),
        ("E2", "T0", 1, T0 - 100 * DAY, None, "T0"),
    ]
    for engine, tail, position, start, end, _why in refused:
        response = _install(client, tenant, engine, tail, position, start, end)
        assert response.status_code == 409, (engine, tail, start)  # type: ignore[attr-defined]
        error = error_of(response)
        assert error["details"][0]["esn"] == "E0" and error["details"][0]["tail"] == "N0FH"
    assert _installations(session, tenant) == 1

    # Touching periods are fine: [t0, t10) then [t10, ...).
    assert _install(client, tenant, "E1", "T0", 1, T0 + 10 * DAY).status_code == 201  # type: ignore[attr-defined]
    assert _install(client, tenant, "E0", "T1", 2, T0 + 10 * DAY).status_code == 201  # type: ignore[attr-defined]
    # The open-ended installation blocks anything later at that position.
    late = _install(client, tenant, "E2", "T0", 1, T0 + 400 * DAY)
    assert late.status_code == 409  # type: ignore[attr-defined]
    assert _installations(session, tenant) == 3


@pytest.mark.parametrize(
    ("change", "field", "status"),
    [
        ({"installed_at": "2026-01-01T00:00:00"}, "installed_at", 422),
        ({"removed_at": "2026-01-05T00:00:00"}, "removed_at", 422),
        ({"installed_at": "yesterday"}, "installed_at", 422),
        ({"removed_at": "2025-12-31T00:00:00Z"}, "removed_at", 422),
        ({"removed_at": "2026-01-01T00:00:00Z"}, "removed_at", 422),
        ({"position": 5}, "position", 422),
        ({"position": 3}, "position", 422),
        ({"position": "left"}, "position", 422),
        ({"engine_id": None}, "engine_id", 422),
        ({"aircraft_id": 10**9}, "aircraft_id", 422),
    ],
)
def test_bad_installations_name_the_field_and_store_nothing(
    client: TestClient,
    session: Session,
    tenant: Tenant,
    change: dict[str, object],
    field: str,
    status: int,
) -> None:
    _setup(client, tenant)
    body: dict[str, object] = {
        "engine_id": tenant.ids["E0"],
        "aircraft_id": tenant.ids["T0"],
        "position": 1,
        "installed_at": T0.isoformat(),
        **change,
    }
    response = client.post(f"{API}/installations", json=body, headers=tenant.headers())
    assert response.status_code == status
    assert error_of(response)["details"][0]["location"][-1] == field
    assert _installations(session, tenant) == 0


def test_engine_swap_keeps_history_and_resolves_by_time(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    _setup(client, tenant)
    on_t0 = _install(client, tenant, "E0", "T0", 1, T0).json()  # type: ignore[attr-defined]
    # The swap: E0 comes off N0FH at day 30, E1 goes on; E0 goes to N1FH position 2 at day 45.
    removed = client.patch(
        f"{API}/installations/{on_t0['id']}",
        json={"removed_at": (T0 + 30 * DAY).isoformat()},
        headers=tenant.headers(),
    )
    assert removed.status_code == 200
    assert _install(client, tenant, "E1", "T0", 1, T0 + 30 * DAY).status_code == 201  # type: ignore[attr-defined]
    assert _install(client, tenant, "E0", "T1", 2, T0 + 45 * DAY).status_code == 201  # type: ignore[attr-defined]

    history = client.get(
        f"{API}/engines/{tenant.ids['E0']}/installations", headers=tenant.headers("viewer")
    ).json()
    assert [(i["tail"], i["position"]) for i in history["items"]] == [("N1FH", 2), ("N0FH", 1)]
    assert history["items"][1]["removed_at"] == (T0 + 30 * DAY).isoformat().replace("+00:00", "Z")

    expected = {  # (tail, position, time) -> ESN, read off the swap above
        ("N0FH", 1, T0 + 29 * DAY): "E0",
        ("N0FH", 1, T0 + 30 * DAY): "E1",
        ("N1FH", 2, T0 + 40 * DAY): None,
        ("N1FH", 2, T0 + 45 * DAY): "E0",
        ("N0FH", 1, T0 - DAY): None,
    }
    for (tail, position, at), esn in expected.items():
        engine = fleet.resolve_engine(session, tenant.operator_id, tail, position, at)
        assert (engine.esn if engine else None) == esn, (tail, position, at)
        aircraft_id = tenant.ids["T0" if tail == "N0FH" else "T1"]
        slots = client.get(
            f"{API}/aircraft/{aircraft_id}/engines",
            params={"at": at.isoformat()},
            headers=tenant.headers("viewer"),
        ).json()
        slot = next(s for s in slots if s["position"] == position)
        assert (slot["engine"]["esn"] if slot["engine"] else None) == esn

    # The engines list and each engine say where it is now: after the swap, E0 on N1FH #2,
    # E1 on N0FH #1 and E2 (never installed) nowhere; the list is by ESN, a page at a time.
    placed = [client.get(f"{API}/engines", params={"limit": 2, "offset": offset},
                         headers=tenant.headers("viewer")).json() for offset in (0, 2)]
    assert [p["total"] for p in placed] == [3, 3]
    assert [(e["esn"], e["tail"], e["position"]) for p in placed for e in p["items"]] == [
        ("E0", "N1FH", 2), ("E1", "N0FH", 1), ("E2", None, None)]
    one = client.get(f"{API}/engines/{tenant.ids['E1']}", headers=tenant.headers("viewer"))
    assert (one.json()["tail"], one.json()["position"]) == ("N0FH", 1)

    # Re-opening E0's first installation would overlap both E1 at N0FH/1 and E0 at N1FH/2.
    reopen = client.patch(
        f"{API}/installations/{on_t0['id']}", json={"removed_at": None}, headers=tenant.headers()
    )
    assert reopen.status_code == 409
    session.expire_all()
    row = session.get(Installation, on_t0["id"])
    assert row is not None and row.removed_at == T0 + 30 * DAY


def test_installations_list_filters_agree_with_resolution(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    _setup(client, tenant)
    _install(client, tenant, "E0", "T0", 1, T0, T0 + 10 * DAY)
    _install(client, tenant, "E1", "T0", 2, T0 + 5 * DAY)
    _install(client, tenant, "E2", "T0", 1, T0 + 10 * DAY)
    at = T0 + 7 * DAY
    listed = client.get(
        f"{API}/installations",
        params={"aircraft_id": tenant.ids["T0"], "at": at.isoformat()},
        headers=tenant.headers("viewer"),
    ).json()
    by_position = {i["position"]: i["esn"] for i in listed["items"]}
    for position in (1, 2):
        engine = fleet.resolve_engine(session, tenant.operator_id, "N0FH", position, at)
        assert engine is not None and by_position[position] == engine.esn
    naive = client.get(
        f"{API}/installations", params={"at": "2026-01-01T00:00:00"}, headers=tenant.headers()
    )
    assert naive.status_code == 422 and error_of(naive)["details"][0]["location"][-1] == "at"


def _random_history(
    session: Session, tenant: Tenant, rng: np.random.Generator, n_tails: int, n_engines: int
) -> list[Installation]:
    """Random installation attempts through the service; it keeps the ones that fit."""
    et = fleet.create_engine_type(session, operator_id=tenant.operator_id, name="TF")
    aircraft = [
        fleet.create_aircraft(
            session, operator_id=tenant.operator_id, tail=f"R{i}", engine_positions=2
        )
        for i in range(n_tails)
    ]
    engines = [
        fleet.create_engine(
            session, operator_id=tenant.operator_id, esn=f"RE{i}", engine_type_id=et.id
        )
        for i in range(n_engines)
    ]
    kept = []
    for _ in range(120):
        start = T0 + timedelta(hours=int(rng.integers(0, 24 * 200)))
        end = (
            None if rng.random() < 0.15 else start + timedelta(hours=int(rng.integers(1, 24 * 40)))
        )
        try:
            kept.append(
                fleet.install(
                    session,
                    operator_id=tenant.operator_id,
                    engine_id=engines[int(rng.integers(n_engines))].id,
                    aircraft_id=aircraft[int(rng.integers(n_tails))].id,
                    position=int(rng.integers(1, 3)),
                    installed_at=start,
                    removed_at=end,
                )
            )
        except Conflict:
            pass
    return kept


def _covers(row: Installation, t: datetime) -> bool:
    return row.installed_at <= t and (row.removed_at is None or t < row.removed_at)


def test_vectorised_resolution_equals_brute_force_and_the_scalar_query(
    session: Session, tenant: Tenant
) -> None:
    rng = np.random.default_rng(5)
    kept = _random_history(session, tenant, rng, n_tails=4, n_engines=6)
    assert len(kept) > 20

    # What the service kept never overlaps, by a pairwise check.
    end = T0 + 10_000 * DAY
    for i, a in enumerate(kept):
        for b in kept[i + 1 :]:
            meet = a.installed_at < (b.removed_at or end) and b.installed_at < (a.removed_at or end)
            same_slot = (a.aircraft_id, a.position) == (b.aircraft_id, b.position)
            assert not (meet and (a.engine_id == b.engine_id or same_slot))

    # Records at random times, at every boundary, for unknown tails and bad positions.
    tails, positions, times = [], [], []
    for _ in range(400):
        tails.append(f"R{int(rng.integers(0, 5))}")  # R4 has no aircraft
        positions.append(int(rng.integers(0, 4)))  # 0 and 3 never resolve
        times.append(T0 + timedelta(minutes=int(rng.integers(-60 * 24 * 10, 60 * 24 * 260))))
    for row in kept:
        for t in (row.installed_at, row.removed_at):
            if t is not None:
                for dt in (-timedelta(microseconds=1), timedelta(0)):
                    tails.append(row.aircraft.tail)
                    positions.append(row.position)
                    times.append(t + dt)

    got = fleet.resolve_engines(session, tenant.operator_id, tails, positions, times)
    assert 100 < int(np.sum(got != fleet.NO_ENGINE)) < len(got)  # both outcomes exercised
    as_datetime64 = np.array([t.replace(tzinfo=None) for t in times], dtype="datetime64[us]")
    assert np.array_equal(
        fleet.resolve_engines(session, tenant.operator_id, tails, positions, as_datetime64), got
    )
    names = sorted(set(tails))
    coded = fleet.resolve_engines_coded(
        session,
        tenant.operator_id,
        names + ["unused"],
        np.array([names.index(tail) for tail in tails]),
        positions,
        times,
    )
    assert np.array_equal(coded, got)
    for k, (tail, position, t) in enumerate(zip(tails, positions, times, strict=True)):
        covering = [
            r.engine_id
            for r in kept
            if r.aircraft.tail == tail and r.position == position and _covers(r, t)
        ]
        assert len(covering) <= 1
        assert got[k] == (covering[0] if covering else fleet.NO_ENGINE), (tail, position, t)
    for k in range(0, len(tails), 37):
        engine = fleet.resolve_engine(session, tenant.operator_id, tails[k], positions[k], times[k])
        assert (engine.id if engine else fleet.NO_ENGINE) == got[k]


def test_resolution_over_millennia_uses_time_ranks(session: Session, tenant: Tenant) -> None:
    """Records spanning thousands of years overflow the time key; ranks must give the same."""
    et = fleet.create_engine_type(session, operator_id=tenant.operator_id, name="TF")
    ac = fleet.create_aircraft(session, operator_id=tenant.operator_id, tail="OLD")
    engines = [
        fleet.create_engine(
            session, operator_id=tenant.operator_id, esn=f"O{i}", engine_type_id=et.id
        )
        for i in range(3)
    ]
    starts = [T0.replace(year=y) for y in (5, 2000, 9000)]
    for engine, start, end in zip(engines, starts, [*starts[1:], None], strict=True):
        fleet.install(
            session,
            operator_id=tenant.operator_id,
            engine_id=engine.id,
            aircraft_id=ac.id,
            position=1,
            installed_at=start,
            removed_at=end,
        )
    times = [T0.replace(year=y) for y in (1, 5, 1999, 2000, 8999, 9000, 9999)]
    expected = [fleet.NO_ENGINE] + [e.id for e in engines for _ in (0, 1)]
    got = fleet.resolve_engines(session, tenant.operator_id, ["OLD"] * 7, [1] * 7, times)
    assert got.tolist() == expected
    # With 20 tail names (19 unknown) the time key would pass 2^62: the ranks path runs.
    names = ["OLD"] + [f"NONE{i}" for i in range(19)]
    span_us = (times[-1] - times[0]).total_seconds() * 1e6
    assert len(names) * 5 * span_us > 2**62
    ranked = fleet.resolve_engines_coded(
        session, tenant.operator_id, names, np.zeros(7, dtype=np.int64), [1] * 7, times
    )
    assert ranked.tolist() == expected


def test_resolution_is_per_operator(session: Session, tenant: Tenant) -> None:
    other = make_tenant(session, "Other Air")
    for who in (tenant, other):
        et = fleet.create_engine_type(session, operator_id=who.operator_id, name="TF")
        ac = fleet.create_aircraft(session, operator_id=who.operator_id, tail="SAME")
        en = fleet.create_engine(
            session, operator_id=who.operator_id, esn="E", engine_type_id=et.id
        )
        fleet.install(
            session,
            operator_id=who.operator_id,
            engine_id=en.id,
            aircraft_id=ac.id,
            position=1,
            installed_at=T0,
        )
        who.ids["engine"] = en.id
    for who in (tenant, other):
        got = fleet.resolve_engines(session, who.operator_id, ["SAME"], [1], [T0 + DAY])
        assert got.tolist() == [who.ids["engine"]]


def test_database_refuses_overlaps_on_postgresql(session: Session, tenant: Tenant) -> None:
    """Behind the service check, an exclusion constraint holds for any writer."""
    if session.get_bind().dialect.name != "postgresql":
        pytest.skip("exclusion constraints are PostgreSQL's; SQLite relies on the service check")
    et = fleet.create_engine_type(session, operator_id=tenant.operator_id, name="TF")
    ac = fleet.create_aircraft(session, operator_id=tenant.operator_id, tail="X1")
    e1, e2 = (
        fleet.create_engine(
            session, operator_id=tenant.operator_id, esn=f"X{i}", engine_type_id=et.id
        )
        for i in (1, 2)
    )
    fleet.install(
        session,
        operator_id=tenant.operator_id,
        engine_id=e1.id,
        aircraft_id=ac.id,
        position=1,
        installed_at=T0,
        removed_at=T0 + 10 * DAY,
    )
    for engine, position in ((e1, 2), (e2, 1)):  # same engine elsewhere; same position
        with pytest.raises(IntegrityError, match="ex_installations"), session.begin_nested():
            session.add(
                Installation(
                    operator_id=tenant.operator_id,
                    engine_id=engine.id,
                    aircraft_id=ac.id,
                    position=position,
                    installed_at=T0 + 5 * DAY,
                )
            )
            session.flush()


def test_moving_an_installation_to_a_taken_position_is_refused(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    _setup(client, tenant)
    first = _install(client, tenant, "E0", "T0", 1, T0, T0 + 10 * DAY).json()  # type: ignore[attr-defined]
    _install(client, tenant, "E1", "T0", 2, T0 + 5 * DAY)
    url = f"{API}/installations/{first['id']}"
    taken = client.patch(url, json={"position": 2}, headers=tenant.headers())
    assert taken.status_code == 409 and error_of(taken)["details"][0]["esn"] == "E1"
    beyond = client.patch(url, json={"position": 3}, headers=tenant.headers())
    assert (
        beyond.status_code == 422 and error_of(beyond)["details"][0]["location"][-1] == "position"
    )
    # Ending before E1 arrived frees position 2 for the whole period.
    moved = client.patch(
        url,
        json={"position": 2, "removed_at": (T0 + 5 * DAY).isoformat()},
        headers=tenant.headers(),
    )
    assert moved.status_code == 200
    engine = fleet.resolve_engine(session, tenant.operator_id, "N0FH", 2, T0 + DAY)
    assert engine is not None and engine.id == tenant.ids["E0"]
    assert fleet.resolve_engine(session, tenant.operator_id, "N0FH", 1, T0 + DAY) is None
