"""Engine types with their own parameter sets: which columns a snapshot may and must carry,
and the units they convert from, read from the models of the type of the engine each row
resolves to. Uploads are real files (CSV, JSON) through the API, on both databases."""

from __future__ import annotations

import json
import uuid
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models import Snapshot, Upload
from app.services.fleet import service as fleet
from app.services.fleet.parameter_sets import parameter_set_of, parameter_sets
from app.services.tenancy import service as tenancy
from app.signals import CONDITION_COLUMNS, MEASURED
from tests.estimation.models import reference_model

T0 = datetime(2026, 5, 1, tzinfo=UTC)
# The custom engine's signals: names that appear nowhere in fleethealth, units of its own.
CUSTOM_SENSORS = {"Nf": ("N1", "%"), "Nc": ("N2", "%"), "T24": ("T25", "K"),
                  "Ps30": ("PS3", "kPa"), "T30": ("T3", "K"), "T48": ("EGT", "degC")}
CUSTOM_INPUTS = {"Wf": ("FF", "kg/h"), "VSV": ("IGV", "deg"), "VBV": ("BLEED", "%")}


def custom_model_file() -> dict[str, Any]:
    """The reference model with its sensors and inputs renamed (N1, N2, EGT, PS3, FF ...)."""
    doc = reference_model().to_dict()
    signals = doc["signals"]
    for key, names in (("sensors", CUSTOM_SENSORS), ("inputs", CUSTOM_INPUTS)):
        signals[key] = [{"name": names[s["name"]][0], "unit": names[s["name"]][1]}
                        for s in signals[key]]
    states = {s["name"] for s in signals["states"]}
    trim = {k: v for k, v in doc["trim"].items()
            if k in states or k in {a["name"] for a in signals["aux"]}}
    trim.update({"N1": 100.0, "N2": 100.0, "T25": 642.0 / 1.8, "PS3": 3100.0, "T3": 883.0,
                 "EGT": 505.0, "FF": 4500.0, "IGV": 12.0, "BLEED": 20.0})
    doc["trim"] = trim
    doc.pop("operating_condition", None)
    return doc


@dataclass(frozen=True)
class TwoTypes:
    operator_id: int
    key: dict[str, str]
    builtin: int  # engine type ids
    custom: int
    reference: int
    unmodelled: int


@pytest.fixture
def two_types(client: TestClient, session: Session) -> TwoTypes:
    """Four engine types, their engines on aircraft N300 (built-in at 1, custom at 2), N301
    (built-in at 1, reference at 2) and N302 (unmodelled at 1); models through the API."""
    operator = tenancy.create_operator(session, name=f"Types Air {uuid.uuid4().hex[:8]}")
    _r, key = tenancy.issue_api_key(session, operator=operator, role="analyst", name="t")
    ids = {name: fleet.create_engine_type(session, operator_id=operator.id, name=name).id
           for name in ("Built-in turbofan", "Custom 2-spool", "Reference", "Unmodelled")}
    plan = [("B-1", "Built-in turbofan", "N300", 1), ("C-1", "Custom 2-spool", "N300", 2),
            ("B-2", "Built-in turbofan", "N301", 1), ("R-1", "Reference", "N301", 2),
            ("U-1", "Unmodelled", "N302", 1)]
    aircraft = {tail: fleet.create_aircraft(session, operator_id=operator.id, tail=tail).id
                for tail in ("N300", "N301", "N302")}
    for esn, type_name, tail, position in plan:
        engine = fleet.create_engine(session, operator_id=operator.id, esn=esn,
                                     engine_type_id=ids[type_name])
        fleet.install(session, operator_id=operator.id, engine_id=engine.id,
                      aircraft_id=aircraft[tail], position=position,
                      installed_at=T0 - timedelta(days=30))
    session.commit()
    headers = {"X-API-Key": key}
    made = [
        client.post("/api/v1/engine-models/builtin", headers=headers, json={
            "engine_type_id": ids["Built-in turbofan"], "name": "SLS", "alt_ft": 0.0,
            "mach": 0.0, "power_pct": 100.0}),
        client.post("/api/v1/engine-models", headers=headers, json={
            "engine_type_id": ids["Custom 2-spool"], "name": "cruise point",
            "model": custom_model_file()}),
        client.post("/api/v1/engine-models", headers=headers, json={
            "engine_type_id": ids["Reference"], "name": "cruise point",
            "model": reference_model().to_dict()}),
    ]
    for response in made:
        assert response.status_code == 201, response.text
    return TwoTypes(operator.id, headers, ids["Built-in turbofan"], ids["Custom 2-spool"],
                    ids["Reference"], ids["Unmodelled"])


def write_csv(path: Path, header: list[str], rows: list[list[Any]]) -> bytes:
    path.write_text("\n".join(",".join(str(v) for v in line) for line in [header, *rows]) + "\n")
    return path.read_bytes()


def post_csv(client: TestClient, types: TwoTypes, body: bytes) -> Any:
    return client.post("/api/v1/snapshots/file", content=body,
                       headers={**types.key, "Content-Type": "text/csv"})


def stored(session: Session, types: TwoTypes) -> int:
    return int(session.scalar(select(func.count()).select_from(Snapshot).where(
        Snapshot.operator_id == types.operator_id)) or 0)


def at(hours: float) -> str:
    return (T0 + timedelta(hours=hours)).strftime("%Y-%m-%dT%H:%M:%SZ")


def test_a_types_parameter_set_comes_from_its_models(
    two_types: TwoTypes, session: Session
) -> None:
    sets = parameter_sets(session, [two_types.builtin, two_types.custom, two_types.reference,
                                    two_types.unmodelled])
    builtin = sets[two_types.builtin]
    # The built-in engine is one such type: its model file declares the catalogue's signals.
    assert set(builtin.names) == {s.name for s in MEASURED} and builtin.from_models
    assert builtin.scheduled_on == CONDITION_COLUMNS and builtin.phase_required
    custom = sets[two_types.custom]
    assert custom.names == ("FF", "IGV", "BLEED", "N1", "N2", "T25", "PS3", "T3", "EGT")
    assert [(s.name, s.unit) for s in custom.signals][-1] == ("EGT", "degC")
    assert custom.signal("EGT") is not None and custom.signal("EGT").quantity == "temperature"
    assert custom.scheduled_on == () and not custom.phase_required
    assert not custom.knows("T30") and custom.knows("alt_ft")
    unmodelled = sets[two_types.unmodelled]
    assert not unmodelled.from_models and unmodelled.names == tuple(s.name for s in MEASURED)
    # A model without signals (content not a model file) adds nothing.
    assert not parameter_set_of(1, "x", [("imported", {})]).from_models


def test_a_column_unknown_for_the_rows_type_refuses_the_upload_naming_both(
    client: TestClient, session: Session, two_types: TwoTypes, tmp_path: Path
) -> None:
    header = ["recorded_at", "tail", "position", "phase", "alt_ft", "mach", "dtamb_k",
              "power_pct", "T30", "EGT[degC]"]
    # EGT on the built-in engine's row (position 1): EGT is the custom type's, not its.
    body = write_csv(tmp_path / "egt_on_builtin.csv", header, [
        [at(0), "N300", 2, "cruise", "", "", "", "", "", 505.0],
        [at(0), "N300", 1, "cruise", 35000, 0.8, 0, 85, 1400.0, 510.0],
    ])
    response = post_csv(client, two_types, body)
    assert response.status_code == 422, response.text
    detail = response.json()["error"]["details"][0]
    assert detail["column"] == "EGT[degC]"
    assert "'EGT'" in detail["reason"] and "'Built-in turbofan'" in detail["reason"]
    assert "row 2 and 0 more" in detail["reason"]
    # T30 on the custom type's row: a built-in name is no name of that type.
    body = write_csv(tmp_path / "t30_on_custom.csv", header[:-1], [
        [at(1), "N300", 2, "cruise", "", "", "", "", 1400.0],
    ])
    response = post_csv(client, two_types, body)
    assert response.status_code == 422, response.text
    reason = response.json()["error"]["details"][0]["reason"]
    assert "'T30'" in reason and "'Custom 2-spool'" in reason and "EGT" in reason
    # A name no type has, in JSON, names the row's type as well.
    doc = {"snapshots": [{"recorded_at": at(2), "tail": "N302", "position": 1,
                          "phase": "cruise", "alt_ft": 0, "mach": 0, "dtamb_k": 0,
                          "power_pct": 90, "ZZ9": 1.0}]}
    path = tmp_path / "unknown.json"
    path.write_text(json.dumps(doc))
    response = client.post("/api/v1/snapshots", content=path.read_bytes(),
                           headers={**two_types.key, "Content-Type": "application/json"})
    assert response.status_code == 422, response.text
    assert "'ZZ9'" in response.text and "'Unmodelled'" in response.text
    assert stored(session, two_types) == 0
    rejected = session.scalars(select(Upload.status).where(
        Upload.operator_id == two_types.operator_id)).all()
    assert rejected == ["rejected"] * 3


def test_required_columns_and_units_follow_the_type(
    client: TestClient, session: Session, two_types: TwoTypes, tmp_path: Path
) -> None:
    # The built-in type is scheduled on the operating condition: a row without it is refused.
    body = write_csv(tmp_path / "no_condition.csv",
                     ["recorded_at", "tail", "position", "phase", "T30"],
                     [[at(0), "N301", 1, "cruise", 1400.0]])
    response = post_csv(client, two_types, body)
    assert response.status_code == 422
    detail = response.json()["error"]["details"][0]
    assert detail["column"] == "alt_ft"
    assert detail["reason"] == ("required column 'alt_ft' is missing (engine type "
                                "'Built-in turbofan' is scheduled on it)")
    # The custom type's own columns with their declared units are stored by name, in the
    # units of its model file (EGT in degC, FF in kg/h), without a condition or a phase.
    header = ["recorded_at", "tail", "position", "N1[%]", "N2[%]", "EGT[degF]", "PS3[kPa]",
              "FF[kg/h]"]
    body = write_csv(tmp_path / "custom.csv", header,
                     [[at(3), "N300", 2, 98.0, 99.0, 941.0, 3100.0, 4500.0]])
    response = post_csv(client, two_types, body)
    assert response.status_code == 201, response.text
    row = session.execute(select(Snapshot.phase, Snapshot.alt_ft, Snapshot.t48,
                                 Snapshot.other_signals).where(
        Snapshot.operator_id == two_types.operator_id)).one()
    assert row.phase is None and row.alt_ft is None and row.t48 is None
    assert set(row.other_signals) == {"N1", "N2", "EGT", "PS3", "FF"}
    assert row.other_signals["EGT"] == pytest.approx(505.0)
    assert row.other_signals["FF"] == 4500.0 and row.other_signals["N1"] == 98.0
    # A unit that is not one of the signal's quantity is refused by name.
    body = write_csv(tmp_path / "bad_unit.csv", ["recorded_at", "tail", "position",
                                                  "EGT[psia]"], [[at(4), "N300", 2, 7.0]])
    response = post_csv(client, two_types, body)
    assert response.status_code == 422
    detail = response.json()["error"]["details"][0]
    assert detail["column"] == "EGT[psia]" and "unknown unit 'psia' for temperature" in \
        detail["reason"]
    assert stored(session, two_types) == 1


def test_one_upload_holds_engines_of_two_types_on_one_tail(
    client: TestClient, session: Session, two_types: TwoTypes, tmp_path: Path
) -> None:
    """N301: the built-in type at position 1 (all catalogue signals), the reference type at 2
    (a single-point model: Nf, Nc, T24, Ps30, T30, T48; no P30). Declared units convert."""
    header = ["recorded_at", "tail", "position", "phase", "flight_id", "alt_ft", "mach",
              "dtamb_k", "power_pct", "T30[degC]", "P30", "Ps30[kPa]"]
    body = write_csv(tmp_path / "mixed.csv", header, [
        [at(0), "N301", 1, "cruise", "F1", 35000, 0.8, 0, 85, 500.0, 150.0, ""],
        [at(0), "N301", 2, "cruise", "F1", 35000, 0.8, 0, 85, 600.0, "", 3100.0],
    ])
    response = post_csv(client, two_types, body)
    assert response.status_code == 201, response.text
    assert response.json()["rows_stored"] == 2
    rows = session.execute(select(Snapshot.position, Snapshot.t30, Snapshot.p30,
                                  Snapshot.ps30).where(
        Snapshot.operator_id == two_types.operator_id).order_by(Snapshot.position)).all()
    assert [r.position for r in rows] == [1, 2]
    assert rows[0].t30 == pytest.approx((500.0 + 273.15) * 1.8)
    assert rows[1].t30 == pytest.approx((600.0 + 273.15) * 1.8)
    assert rows[0].p30 == 150.0 and rows[1].p30 is None
    assert rows[1].ps30 == pytest.approx(3100.0 / 6.894757293168)
    # P30 on the reference engine's row: not one of its sensors.
    body = write_csv(tmp_path / "p30_on_reference.csv", header, [
        [at(1), "N301", 2, "cruise", "F2", 35000, 0.8, 0, 85, 600.0, 150.0, 3100.0],
    ])
    response = post_csv(client, two_types, body)
    assert response.status_code == 422
    assert "'P30'" in response.text and "'Reference'" in response.text
    # Its rows need no operating condition and no phase: they are stored without them.
    body = write_csv(tmp_path / "reference_only.csv", ["recorded_at", "tail", "position",
                                                       "T30"], [[at(2), "N301", 2, 1590.0]])
    response = post_csv(client, two_types, body)
    assert response.status_code == 201, response.text
    assert stored(session, two_types) == 3
