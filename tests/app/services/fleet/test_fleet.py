"""Engine types, aircraft and engines over the API: CRUD, pagination, bad input stores nothing."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models import Aircraft, Engine, EngineType
from tests.support.fleetkit import (
    T0,
    Tenant,
    error_of,
    make_tenant,
    post,
)

API = "/api/v1"


@pytest.fixture
def tenant(session: Session) -> Tenant:
    return make_tenant(session, "North Air")


def _count(session: Session, model: type, tenant: Tenant) -> int:
    stmt = select(func.count()).select_from(model).where(model.operator_id == tenant.operator_id)  # type: ignore[attr-defined]
    return int(session.scalar(stmt) or 0)


def test_engine_type_aircraft_engine_round_trip(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    et = post(client, tenant, f"{API}/engine-types", {"name": "TF-2S", "description": "two-spool"})
    ac = post(client, tenant, f"{API}/aircraft", {"tail": "N101FH", "engine_positions": 2})
    en = post(client, tenant, f"{API}/engines", {"esn": "ESN-001", "engine_type_id": et["id"]})

    stored = session.get(Engine, en["id"])
    assert stored is not None
    assert (stored.esn, stored.engine_type_id, stored.operator_id) == (
        "ESN-001",
        et["id"],
        tenant.operator_id,
    )
    viewer = tenant.headers("viewer")
    assert client.get(f"{API}/engines/{en['id']}", headers=viewer).json() == en
    assert client.get(f"{API}/aircraft/{ac['id']}", headers=viewer).json() == ac
    assert client.get(f"{API}/engine-types/{et['id']}", headers=viewer).json() == et

    patched = client.patch(
        f"{API}/aircraft/{ac['id']}",
        json={"aircraft_type": "A320"},
        headers=tenant.headers(),
    )
    assert patched.status_code == 200
    assert patched.json() == {**ac, "aircraft_type": "A320"}
    session.expire_all()
    assert session.get(Aircraft, ac["id"]).aircraft_type == "A320"  # type: ignore[union-attr]


def test_lists_are_paginated_in_a_stable_order(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    tails = [f"N{n:03d}XY" for n in (7, 3, 11, 5, 1, 9, 2)]
    for tail in tails:
        post(client, tenant, f"{API}/aircraft", {"tail": tail})
    expected = sorted(tails)
    seen: list[str] = []
    for offset in range(0, len(tails), 3):
        page = client.get(
            f"{API}/aircraft",
            params={"limit": 3, "offset": offset},
            headers=tenant.headers("viewer"),
        ).json()
        assert (page["total"], page["limit"], page["offset"]) == (len(tails), 3, offset)
        seen += [item["tail"] for item in page["items"]]
    assert seen == expected
    one = client.get(f"{API}/aircraft", params={"tail": "N005XY"}, headers=tenant.headers())
    assert [a["tail"] for a in one.json()["items"]] == ["N005XY"]

    for bad in ({"limit": 0}, {"limit": 100_000}, {"offset": -1}, {"limit": "many"}):
        response = client.get(f"{API}/aircraft", params=bad, headers=tenant.headers())
        assert response.status_code == 422, bad
        assert error_of(response)["details"][0]["location"][-1] == next(iter(bad))


@pytest.mark.parametrize(
    ("path", "body", "field"),
    [
        ("aircraft", {}, "tail"),
        ("aircraft", {"tail": ""}, "tail"),
        ("aircraft", {"tail": 123}, "tail"),
        ("aircraft", {"tail": "N1", "engine_positions": 5}, "engine_positions"),
        ("aircraft", {"tail": "N1", "engine_positions": "two"}, "engine_positions"),
        ("aircraft", {"tail": "N1", "colour": "blue"}, "colour"),
        ("engines", {"esn": "E1"}, "engine_type_id"),
        ("engines", {"esn": "E1", "engine_type_id": "x"}, "engine_type_id"),
        ("engines", {"esn": ["E1"], "engine_type_id": 1}, "esn"),
        ("engine-types", {"description": "no name"}, "name"),
    ],
)
def test_bad_bodies_name_the_field_and_store_nothing(
    client: TestClient,
    session: Session,
    tenant: Tenant,
    path: str,
    body: dict[str, object],
    field: str,
) -> None:
    before = {m: _count(session, m, tenant) for m in (Aircraft, Engine, EngineType)}
    response = client.post(f"{API}/{path}", json=body, headers=tenant.headers())
    assert response.status_code == 422
    error = error_of(response)
    assert error["details"][0]["location"][-1] == field
    assert field in error["message"]
    assert {m: _count(session, m, tenant) for m in before} == before


def test_unknown_engine_type_is_refused_naming_the_field(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    other = make_tenant(session, "South Air")
    foreign_type = post(client, other, f"{API}/engine-types", {"name": "TF-2S"})
    for engine_type_id in (987654, foreign_type["id"]):
        response = client.post(
            f"{API}/engines",
            json={"esn": "E1", "engine_type_id": engine_type_id},
            headers=tenant.headers(),
        )
        assert response.status_code == 422
        assert error_of(response)["details"][0]["location"] == ["body", "engine_type_id"]
    assert _count(session, Engine, tenant) == 0


def test_duplicates_are_conflicts_per_operator(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    et = post(client, tenant, f"{API}/engine-types", {"name": "TF-2S"})
    post(client, tenant, f"{API}/engines", {"esn": "ESN-9", "engine_type_id": et["id"]})
    again = client.post(
        f"{API}/engines",
        json={"esn": "ESN-9", "engine_type_id": et["id"]},
        headers=tenant.headers(),
    )
    assert again.status_code == 409 and "ESN-9" in error_of(again)["message"]
    post(client, tenant, f"{API}/aircraft", {"tail": "N1"})
    assert (
        client.post(f"{API}/aircraft", json={"tail": "N1"}, headers=tenant.headers()).status_code
        == 409
    )

    # Tails, ESNs and type names are unique per operator only.
    other = make_tenant(session, "South Air")
    other_type = post(client, other, f"{API}/engine-types", {"name": "TF-2S"})
    post(client, other, f"{API}/engines", {"esn": "ESN-9", "engine_type_id": other_type["id"]})
    post(client, other, f"{API}/aircraft", {"tail": "N1"})
    assert [_count(session, m, t) for m in (Engine, Aircraft) for t in (tenant, other)] == [1] * 4


def test_delete_refuses_what_is_still_used(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    et = post(client, tenant, f"{API}/engine-types", {"name": "TF-2S"})
    en = post(client, tenant, f"{API}/engines", {"esn": "E1", "engine_type_id": et["id"]})
    ac = post(client, tenant, f"{API}/aircraft", {"tail": "N1"})
    post(
        client,
        tenant,
        f"{API}/installations",
        {
            "engine_id": en["id"],
            "aircraft_id": ac["id"],
            "position": 1,
            "installed_at": T0.isoformat(),
        },
    )
    for path in (f"engine-types/{et['id']}", f"engines/{en['id']}", f"aircraft/{ac['id']}"):
        response = client.delete(f"{API}/{path}", headers=tenant.headers())
        assert response.status_code == 409, path
    assert [_count(session, m, tenant) for m in (EngineType, Engine, Aircraft)] == [1, 1, 1]

    spare = post(client, tenant, f"{API}/engines", {"esn": "E2", "engine_type_id": et["id"]})
    assert client.delete(f"{API}/engines/{spare['id']}", headers=tenant.headers()).json() == {
        "id": spare["id"],
        "deleted": True,
    }
    assert client.get(f"{API}/engines/{spare['id']}", headers=tenant.headers()).status_code == 404


def test_engine_positions_cannot_drop_below_an_installed_position(
    client: TestClient, tenant: Tenant
) -> None:
    et = post(client, tenant, f"{API}/engine-types", {"name": "TF-2S"})
    en = post(client, tenant, f"{API}/engines", {"esn": "E1", "engine_type_id": et["id"]})
    ac = post(client, tenant, f"{API}/aircraft", {"tail": "N1", "engine_positions": 4})
    post(
        client,
        tenant,
        f"{API}/installations",
        {
            "engine_id": en["id"],
            "aircraft_id": ac["id"],
            "position": 3,
            "installed_at": T0.isoformat(),
        },
    )
    response = client.patch(
        f"{API}/aircraft/{ac['id']}", json={"engine_positions": 2}, headers=tenant.headers()
    )
    assert response.status_code == 409
    ok = client.patch(
        f"{API}/aircraft/{ac['id']}", json={"engine_positions": 3}, headers=tenant.headers()
    )
    assert ok.json()["engine_positions"] == 3


def test_update_refuses_null_for_required_fields(client: TestClient, tenant: Tenant) -> None:
    ac = post(client, tenant, f"{API}/aircraft", {"tail": "N1"})
    response = client.patch(
        f"{API}/aircraft/{ac['id']}", json={"tail": None}, headers=tenant.headers()
    )
    assert response.status_code == 422
    assert error_of(response)["details"][0]["location"] == ["body", "tail"]
    assert client.get(f"{API}/aircraft/{ac['id']}", headers=tenant.headers()).json()["tail"] == "N1"


def test_engine_updates_check_references_and_uniqueness(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    et = post(client, tenant, f"{API}/engine-types", {"name": "TF-2S"})
    e1 = post(client, tenant, f"{API}/engines", {"esn": "E1", "engine_type_id": et["id"]})
    post(client, tenant, f"{API}/engines", {"esn": "E2", "engine_type_id": et["id"]})
    other = make_tenant(session, "South Air")
    foreign_type = post(client, other, f"{API}/engine-types", {"name": "TF-3S"})
    url = f"{API}/engines/{e1['id']}"
    bad_type = client.patch(
        url, json={"engine_type_id": foreign_type["id"]}, headers=tenant.headers()
    )
    assert bad_type.status_code == 422
    assert error_of(bad_type)["details"][0]["location"] == ["body", "engine_type_id"]
    taken = client.patch(url, json={"esn": "E2"}, headers=tenant.headers())
    assert taken.status_code == 409
    session.expire_all()
    stored = session.get(Engine, e1["id"])
    assert stored is not None and (stored.esn, stored.engine_type_id) == ("E1", et["id"])
    renamed = client.patch(url, json={"esn": "E1-R"}, headers=tenant.headers())
    assert renamed.json() == {**e1, "esn": "E1-R"}
