"""Tenant isolation over EVERY route of the app, including routes added after this test.

The walker lists the app's routes (``app.routes``, following included routers), builds two
operators' worlds, and sends each route a request synthesised from its OpenAPI operation:

1. with operator A's admin key and operator B's ids in the path: 404, and none of B's rows
   change; lists and reads without ids never show B's marker string; a body naming B's
   objects is refused with a 4xx;
2. the same requests with B's own key: not 404 (the control: the ids and requests are real);
3. with A's viewer key and A's own ids, every non-GET route: 403;
4. without a key, every route: 401.

Path parameters are filled by name (``engine_id``, ``aircraft_id``, ...). Objects of tables this
file does not know are found by name (``upload_id`` -> table ``uploads``) and, when the world
has none, synthesised from the table's metadata. Only routes that carry no tenant data are
skipped, listed in ``NO_TENANT_DATA``.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.routing import APIRoute
from fastapi.testclient import TestClient
from sqlalchemy import (
    JSON,
    Boolean,
    Column,
    DateTime,
    Float,
    Integer,
    LargeBinary,
    Numeric,
    String,
    Table,
    Text,
    select,
)
from sqlalchemy.orm import Session
from sqlalchemy.types import TypeDecorator
from starlette.routing import BaseRoute, Mount

from app.models import Base
from app.services.designs import engine_models
from app.services.designs import service as designs
from app.services.fleet import maintenance
from app.services.fleet import service as fleet
from app.services.tenancy.keys import create_key
from tests.estimation.models import reference_model
from tests.support.fleetkit import (
    T0,
    Tenant,
    make_tenant,
)

# Routes that carry no tenant data: the only ones the walker leaves out.
NO_TENANT_DATA = {
    "/health": "liveness and database readiness",
    "/openapi.json": "the API description",
    "/docs": "Swagger UI page",
    "/docs/oauth2-redirect": "Swagger UI helper",
    "/redoc": "ReDoc page",
    "": "static dashboard files (the mount at /)",
    "/vendor/plotly.min.js": "the plotting library the dashboard pages load",
}
READ_METHODS = {"GET", "HEAD", "OPTIONS"}
SPEC = {
    "format": "fleethealth.design-spec/1",
    "method": "subset",
    "tuners": 4,
    "noise": {"Q": [0.01, 0.01], "Qh": [0.1] * 10, "Ph": [2.0] * 10},
}


# ----------------------------------------------------------------------------- routes


def walk_routes(routes: list[BaseRoute], prefix: str = "") -> Iterator[tuple[str, BaseRoute]]:
    """(full path, route) of every route, descending into included routers and mounts."""
    for route in routes:
        included = getattr(route, "original_router", None)  # FastAPI's included-router branch
        if included is not None:
            yield from walk_routes(included.routes, prefix + route.include_context.prefix)  # type: ignore[attr-defined]
        elif isinstance(route, Mount) and route.routes:
            yield from walk_routes(list(route.routes), prefix + route.path)
        else:
            yield prefix + getattr(route, "path", ""), route


@dataclass(frozen=True)
class Operation:
    method: str
    path: str
    route: APIRoute
    spec: dict[str, Any]  # the OpenAPI operation

    @property
    def path_params(self) -> list[str]:
        return re.findall(r"{(\w+)(?::\w+)?}", self.path)

    def __str__(self) -> str:
        return f"{self.method} {self.path}"


def operations(app: FastAPI) -> list[Operation]:
    """Every HTTP operation of the app, each checked to appear in the OpenAPI document."""
    openapi = app.openapi()
    ops, unhandled = [], []
    for path, route in walk_routes(app.routes):
        if path in NO_TENANT_DATA:
            continue
        if not isinstance(route, APIRoute):
            unhandled.append(f"{type(route).__name__} {path}")
            continue
        for method in sorted(route.methods):
            spec = openapi["paths"].get(path, {}).get(method.lower())
            if spec is None:  # hidden from the document: walked all the same, without params
                assert not route.include_in_schema, f"{method} {path} missing from OpenAPI"
                spec = {}
            ops.append(Operation(method, path, route, spec))
    assert not unhandled, (
        f"routes the tenancy walker cannot send requests to: {unhandled}; teach "
        "tests/app/services/tenancy/test_tenancy.py to check them, or list them in "
        "NO_TENANT_DATA if they carry no tenant data"
    )
    walked = {(op.method.lower(), op.path) for op in ops}
    documented = {
        (method, path)
        for path, item in openapi["paths"].items()
        for method in item
        if path not in NO_TENANT_DATA
    }
    assert documented <= walked, f"documented but not walked: {documented - walked}"
    # Reads first and deletions last, so the owner's control requests find every object.
    order = {"GET": 0, "HEAD": 0, "POST": 1, "PUT": 1, "PATCH": 1, "DELETE": 2}
    return sorted(ops, key=lambda op: (order.get(op.method, 1), op.path))


# ------------------------------------------------------------------------------ worlds


def build_world(session: Session, tenant: Tenant, marker: str) -> dict[str, int]:
    """Objects of every kind for one operator, ids by path parameter name."""
    op = tenant.operator_id
    et = fleet.create_engine_type(session, operator_id=op, name=f"{marker} type")
    ac = fleet.create_aircraft(session, operator_id=op, tail=f"{marker}-T")
    en = fleet.create_engine(session, operator_id=op, esn=f"{marker}-E", engine_type_id=et.id)
    inst = fleet.install(
        session, operator_id=op, engine_id=en.id, aircraft_id=ac.id, position=1, installed_at=T0
    )
    action = maintenance.record_action(
        session,
        operator_id=op,
        engine_id=en.id,
        kind="water_wash",
        performed_at=T0,
        notes=marker,
    )
    model, _ = engine_models.import_engine_model(
        session,
        operator_id=op,
        engine_type_id=et.id,
        name=f"{marker} model",
        content=reference_model().to_dict(),
    )
    design = designs.create_design(
        session, operator_id=op, engine_model_id=model.id, name=f"{marker} design", spec=SPEC
    )
    designs.run_design(session, design, designs.design_step)
    designs.activate_design(session, operator_id=op, design_id=design.id)
    key, _plain = create_key(session, operator_id=op, role="viewer", name=f"{marker} key")
    session.commit()
    return {
        "engine_type_id": et.id,
        "aircraft_id": ac.id,
        "engine_id": en.id,
        "installation_id": inst.id,
        "maintenance_action_id": action.id,
        "engine_model_id": model.id,
        "design_id": design.id,
        "key_id": key.id,
    }


def tenant_tables() -> list[Table]:
    return [t for t in Base.metadata.sorted_tables if "operator_id" in t.c]


def table_for(param: str) -> Table | None:
    """The operator table a path parameter names: upload_id -> uploads, schedule_id ->
    job_schedules."""
    stem = param.removesuffix("_id")
    names = (f"{stem}s", f"{stem}es", stem)
    tables = tenant_tables()
    for table in tables:
        if table.name in names:
            return table
    for table in tables:
        if any(table.name.endswith(f"_{n}") for n in names):
            return table
    return None


def _in_values(table: Table, column: Column[Any]) -> list[str]:
    """Values allowed by a CHECK (column IN ('a', 'b')) constraint, if the table has one."""
    for constraint in table.constraints:
        text = str(getattr(constraint, "sqltext", ""))
        match = re.match(rf"\s*{column.name}\s+IN\s*\((.*)\)\s*$", text, re.IGNORECASE)
        if match:
            return re.findall(r"'([^']*)'", match.group(1))
    return []


# Nullable columns that a table's CHECK requires one of (a schedule runs by cron or interval).
CHECKED_ONE_OF: dict[str, dict[str, Any]] = {"job_schedules": {"interval_seconds": 3600}}


def synthesise_row(session: Session, table: Table, operator_id: int, marker: str) -> int:
    """Insert a row of ``table`` for the operator from its metadata; returns its id.

    Foreign keys point at the operator's own rows (made first where missing); required
    columns get a value of their type (the first allowed one under an IN check).
    """
    values: dict[str, Any] = {}
    for column in table.c:
        if column.primary_key:
            continue
        if column.name == "operator_id":
            values[column.name] = operator_id
            continue
        if column.foreign_keys:
            if column.nullable:
                continue
            target = next(iter(column.foreign_keys)).column.table
            values[column.name] = existing_row(session, target, operator_id, marker)
            continue
        if column.nullable or column.default is not None or column.server_default is not None:
            continue
        allowed = _in_values(table, column)
        kind = column.type
        if isinstance(kind, TypeDecorator):
            kind = kind.impl_instance
        if allowed:
            values[column.name] = allowed[0]
        elif isinstance(kind, DateTime):
            values[column.name] = datetime(2026, 1, 1, tzinfo=UTC)
        elif isinstance(kind, Boolean):
            values[column.name] = False
        elif isinstance(kind, Integer):
            values[column.name] = 1
        elif isinstance(kind, Float | Numeric):
            values[column.name] = 1.0
        elif isinstance(kind, JSON):
            values[column.name] = {}
        elif isinstance(kind, LargeBinary):
            values[column.name] = b""
        elif isinstance(kind, String | Text):
            length = getattr(kind, "length", None) or 64
            values[column.name] = f"{marker}-{table.name}-{column.name}"[:length]
        else:
            pytest.fail(f"cannot synthesise {table.name}.{column.name} of type {kind!r}")
    values.update(CHECKED_ONE_OF.get(table.name, {}))
    result = session.execute(table.insert().values(**values).returning(table.c.id))
    return int(result.scalar_one())


def existing_row(session: Session, table: Table, operator_id: int, marker: str) -> int:
    if table.name == "operators":
        return operator_id
    if "operator_id" in table.c:
        found = session.scalar(
            select(table.c.id).where(table.c.operator_id == operator_id).order_by(table.c.id)
        )
        if found is not None:
            return int(found)
    return synthesise_row(session, table, operator_id, marker)


def id_for(session: Session, world: dict[str, int], param: str, tenant: Tenant, marker: str) -> int:
    if param in world:
        return world[param]
    table = table_for(param)
    assert table is not None, (
        f"path parameter {param!r}: no table of operator rows matches it; add it to "
        "build_world() in tests/app/services/tenancy/test_tenancy.py"
    )
    world[param] = existing_row(session, table, tenant.operator_id, marker)
    session.commit()
    return world[param]


def fingerprint(session: Session, operator_id: int) -> dict[str, list[tuple[Any, ...]]]:
    """Every row of the operator, table by table (to prove a request changed nothing)."""
    session.expire_all()
    out = {}
    for table in tenant_tables():
        rows = session.execute(
            select(table).where(table.c.operator_id == operator_id).order_by(*table.primary_key)
        ).all()
        out[table.name] = [tuple(repr(v) for v in row) for row in rows]
    return out


# ---------------------------------------------------------------------- request synthesis


def _resolve(schema: dict[str, Any], components: dict[str, Any]) -> dict[str, Any]:
    while "$ref" in schema:
        # A reference the document does not define (hand-written openapi_extra) is unknown.
        schema = components.get(schema["$ref"].rsplit("/", 1)[-1], {})
    return schema


def example(
    schema: dict[str, Any], name: str, ids: dict[str, int], components: dict[str, Any]
) -> Any:
    """A value valid for ``schema``; fields named like a path parameter get ``ids``' value."""
    schema = _resolve(schema, components)
    if name in ids:
        return ids[name]
    for key in ("anyOf", "oneOf", "allOf"):
        if key in schema:
            options = [o for o in schema[key] if _resolve(o, components).get("type") != "null"]
            return example(options[0], name, ids, components) if options else None
    if "const" in schema:
        return schema["const"]
    if "enum" in schema:
        return schema["enum"][0]
    if "default" in schema:
        return schema["default"]
    kind = schema.get("type")
    if kind == "integer":
        return max(int(schema.get("minimum", 1)), 1)
    if kind == "number":
        return float(schema.get("minimum", 1.0))
    if kind == "boolean":
        return False
    if kind == "array":
        return [example(schema.get("items", {}), name, ids, components)] * schema.get("minItems", 0)
    if kind == "string":
        if schema.get("format") == "date-time":
            return "2026-01-01T00:00:00Z"
        if schema.get("format") == "date":
            return "2026-01-01"
        return "A1" + "x" * max(0, schema.get("minLength", 1) - 2)
    if kind == "object" or "properties" in schema:
        props = schema.get("properties", {})
        return {
            key: example(props[key], key, ids, components) for key in schema.get("required", [])
        }
    return None


# A raw body for routes that read files (CSV or Parquet) rather than JSON.
RAW_CSV = b"time_s,alt_ft\n0,0\n"


@dataclass
class Request:
    method: str
    url: str
    params: dict[str, Any]
    json: Any = None
    content: bytes | None = None
    content_type: str | None = None
    files: dict[str, Any] | None = None
    names_foreign: bool = False  # the body names another operator's objects


def synthesise(op: Operation, ids: dict[str, int], components: dict[str, Any]) -> Request:
    url = op.path
    for param in op.path_params:
        url = re.sub(rf"{{{param}(:\w+)?}}", str(ids[param]), url)
    params = {}
    for parameter in op.spec.get("parameters", []):
        if parameter["in"] != "query":
            continue
        name = parameter["name"]
        if parameter.get("required") or name in ids:
            params[name] = example(parameter.get("schema", {}), name, ids, components)
    request = Request(op.method, url, params)
    content = op.spec.get("requestBody", {}).get("content", {})
    if "application/json" in content:
        request.json = example(content["application/json"].get("schema", {}), "", ids, components)
        request.names_foreign = _mentions_ids(request.json, ids)
    elif "multipart/form-data" in content:
        request.files = {"file": ("walker.csv", RAW_CSV, "text/csv")}
    elif content:
        request.content_type = next(iter(content))
        request.content = RAW_CSV if request.content_type == "text/csv" else b""
    elif op.method in {"POST", "PUT", "PATCH"}:
        # An undeclared body: the route reads the raw request, a file upload here.
        request.content, request.content_type = RAW_CSV, "text/csv"
    return request


def _mentions_ids(body: Any, ids: dict[str, int]) -> bool:
    if isinstance(body, dict):
        return any(k in ids or _mentions_ids(v, ids) for k, v in body.items())
    if isinstance(body, list):
        return any(_mentions_ids(v, ids) for v in body)
    return False


def send(client: TestClient, request: Request, key: str | None) -> Any:
    headers = {"X-API-Key": key} if key else {}
    if request.content_type:
        headers["content-type"] = request.content_type
    return client.request(
        request.method,
        request.url,
        params=request.params,
        json=request.json,
        content=request.content,
        files=request.files,
        headers=headers,
    )


# -------------------------------------------------------------------------------- tests


@pytest.fixture
def worlds(session: Session) -> tuple[Tenant, Tenant]:
    a, b = make_tenant(session, "Tenant A"), make_tenant(session, "Tenant B")
    a.ids = build_world(session, a, "zzowna")
    b.ids = build_world(session, b, "zzforeign")
    return a, b


def test_the_walker_sees_every_route(app: FastAPI) -> None:
    ops = operations(app)
    paths = {op.path for op in ops}
    # A few routes of each kind, so a broken walker (finding nothing) fails here.
    for expected in (
        "/api/v1/engines/{engine_id}",
        "/api/v1/installations",
        "/api/v1/designs/{design_id}/activate",
        "/api/v1/keys/{key_id}",
        "/api/v1/me",
    ):
        assert expected in paths
    assert len(ops) >= 40


def test_other_operators_objects_answer_404_and_never_leak(
    client: TestClient, app: FastAPI, session: Session, worlds: tuple[Tenant, Tenant]
) -> None:
    a, b = worlds
    components = app.openapi().get("components", {}).get("schemas", {})
    ops = operations(app)
    for op in ops:
        for param in op.path_params:
            id_for(session, b.ids, param, b, "zzforeign")
    before = fingerprint(session, b.operator_id)

    requests: dict[str, Request] = {}
    for op in ops:
        request = synthesise(op, b.ids, components)
        requests[str(op)] = request
        response = send(client, request, a.keys["admin"])
        status, text = response.status_code, response.text
        assert status < 500, f"{op}: {status} {text}"
        if op.path_params:
            assert status == 404, f"{op} with another operator's ids: {status} {text}"
        elif request.names_foreign and op.method not in READ_METHODS:
            assert 400 <= status < 500, f"{op} naming another operator's objects: {status}"
        assert "zzforeign" not in text, f"{op} shows another operator's data: {text[:300]}"
    assert fingerprint(session, b.operator_id) == before, "a refused request changed B's rows"

    # Control: the owner gets past the lookup with the very same requests, and the owner's
    # lists do show the marker that A's never did.
    own_lists = set()
    for op in ops:
        if not op.path_params:
            if op.method == "GET":
                response = send(client, requests[str(op)], b.keys["admin"])
                if "zzforeign" in response.text:
                    own_lists.add(op.path)
            continue
        response = send(client, requests[str(op)], b.keys["admin"])
        assert response.status_code != 404, f"{op}: the owner gets 404: {response.text}"
    assert {"/api/v1/engines", "/api/v1/aircraft", "/api/v1/installations"} <= own_lists


def test_viewer_cannot_write_and_every_route_needs_a_key(
    client: TestClient, app: FastAPI, session: Session, worlds: tuple[Tenant, Tenant]
) -> None:
    a, _b = worlds
    components = app.openapi().get("components", {}).get("schemas", {})
    ops = operations(app)
    for op in ops:
        for param in op.path_params:
            id_for(session, a.ids, param, a, "zzowna")
    before = fingerprint(session, a.operator_id)
    writes = 0
    for op in ops:
        request = synthesise(op, a.ids, components)
        anonymous = send(client, request, None)
        assert anonymous.status_code == 401, f"{op} without a key: {anonymous.status_code}"
        if op.method in READ_METHODS:
            continue
        writes += 1
        response = send(client, request, a.keys["viewer"])
        assert response.status_code == 403, f"{op} as viewer: {response.status_code}"
    assert writes >= 15
    assert fingerprint(session, a.operator_id) == before
