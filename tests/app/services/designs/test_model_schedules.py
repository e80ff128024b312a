"""A type's model schedule through the API: imported as one schedule file or as several model
files, refused naming the fault (nothing stored), its parameter set scheduled on its
variables, and an engine of the type estimated under a design of it: records at several
operating points, of a known health, give that health back. On both databases."""

from __future__ import annotations

import itertools
import json
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models import EngineModel
from app.services.designs import service as designs
from app.services.fleet import service as fleet
from app.services.fleet.parameter_sets import parameter_sets
from app.services.snapshots import estimator
from estimation.model import LinearModel
from estimation.schedule import SCHEDULE_FORMAT
from tests.estimation.models import scheduled_models
from tests.support.fleetkit import Tenant, error_of, make_tenant, post

API = "/api/v1"
T0 = datetime(2026, 3, 1, tzinfo=UTC)
ALTS = (0.0, 20000.0, 35000.0)
POWERS = (60.0, 85.0, 100.0)
POINTS = [{"alt_ft": a, "mach": 0.2 + 0.5 * a / 35000.0, "power_pct": p}
          for a, p in itertools.product(ALTS, POWERS)]
HEALTH = ["fan_eff", "hpc_eff", "hpt_eff", "lpt_eff"]
TRUTH = np.array([-1.5, -2.5, -2.0, 1.0])  # percent, the engine's health throughout
SPEC: dict[str, Any] = {
    "format": "fleethealth.design-spec/1", "method": "subset", "tuners": 4, "health": HEALTH,
    "noise": {"Q": [0.01, 0.01], "Qh": [0.1] * 4, "Ph": [2.0] * 4},
}


# The engine type's own signals: names that appear nowhere in fleethealth, units of its own
# (the reference model's signals renamed: name, unit, value in that unit of a reference trim).
OWN = {"Nf": ("N1", "rpm", 1.0, 0.0), "Nc": ("N2", "rpm", 1.0, 0.0), "T24": ("T25", "K", 1.0, 0.0),
       "Ps30": ("PS3", "kPa", 1.0, 0.0), "T30": ("T3", "K", 1.0, 0.0),
       "T48": ("EGT", "degC", 1.0, -273.15), "Wf": ("FF", "kg/h", 3600.0, 0.0),
       "VSV": ("IGV", "deg", 1.0, 0.0), "VBV": ("BLEED", "%", 1.0, 0.0)}


def own_models() -> list[LinearModel]:
    """The scheduled test models with the type's own signal names and units."""
    out = []
    for model in scheduled_models(POINTS):
        doc = model.to_dict()
        for group in ("sensors", "inputs"):
            doc["signals"][group] = [{"name": OWN[s["name"]][0], "unit": OWN[s["name"]][1]}
                                     for s in doc["signals"][group]]
        doc["trim"] = {(OWN[k][0] if k in OWN else k): (v * OWN[k][2] + OWN[k][3] if k in OWN
                                                          else v)
                       for k, v in doc["trim"].items()}
        out.append(LinearModel.from_dict(doc))
    return out


def schedule_document() -> dict[str, Any]:
    return {"format": SCHEDULE_FORMAT, "variables": ["alt_ft", "power_pct"],
            "design_point": 7, "models": [m.to_dict() for m in own_models()]}


@pytest.fixture
def tenant(client: TestClient, session: Session) -> Tenant:
    tenant = make_tenant(session, "Schedule Air")
    tenant.ids["type"] = post(client, tenant, f"{API}/engine-types", {"name": "TF-S"})["id"]
    return tenant


def stored_models(session: Session, tenant: Tenant) -> int:
    return int(session.scalar(select(func.count()).select_from(EngineModel).where(
        EngineModel.operator_id == tenant.operator_id)) or 0)


def test_a_schedule_is_imported_as_one_file_or_as_several_model_files(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    body = {"engine_type_id": tenant.ids["type"], "name": "envelope",
            "model": schedule_document()}
    one = client.post(f"{API}/engine-models", json=body, headers=tenant.headers())
    assert one.status_code == 201, one.text
    row = one.json()
    assert row["format"] == SCHEDULE_FORMAT and row["version"] == 1
    assert row["sensor_names"] == ["N1", "N2", "T25", "PS3", "T3", "EGT"]
    # The same models as nine files, in another order: the same schedule, the same version.
    files = {"engine_type_id": tenant.ids["type"], "name": "envelope",
             "models": [m.to_dict() for m in own_models()][::-1],
             "variables": ["alt_ft", "power_pct"], "design_point": 1}
    again = client.post(f"{API}/engine-models", json=files, headers=tenant.headers())
    assert again.status_code == 200, again.text
    assert again.json()["id"] == row["id"]
    content = client.get(f"{API}/engine-models/{row['id']}/content",
                         headers=tenant.headers()).json()["model"]
    assert content["format"] == SCHEDULE_FORMAT and len(content["models"]) == 9
    # Designs are made on the design point: alt 20000 ft, 85 %.
    design = post(client, tenant, f"{API}/designs",
                  {"engine_model_id": row["id"], "name": "d", "spec": SPEC})
    assert design["status"] == "ready"
    # The type's records must carry its scheduling variables and what corrects its trims.
    params = parameter_sets(session, [tenant.ids["type"]])[tenant.ids["type"]]
    assert params.scheduled_on == ("alt_ft", "mach", "dtamb_k", "power_pct")
    assert not params.phase_required
    plain = {**schedule_document(), "corrections": {
        n: "none" for n in own_models()[0].trim}}
    post(client, tenant, f"{API}/engine-types", {"name": "TF-P"})
    other = post(client, tenant, f"{API}/engine-types", {"name": "TF-Q"})["id"]
    post(client, tenant, f"{API}/engine-models",
         {"engine_type_id": other, "name": "power only", "model": plain})
    assert parameter_sets(session, [other])[other].scheduled_on == ("alt_ft", "power_pct")


@pytest.mark.parametrize(("change", "location", "message"), [
    (lambda b: b["model"]["models"].pop(4), "model", "do not fill the grid 3 x 3"),
    (lambda b: b["model"].update(variables=["alt_ft", "altitude"]), "model",
     "variables must be"),
    (lambda b: b["model"]["models"][3]["matrices"].update(M=[[1.0]]), "model",
     "models[3]: Incompatible dimensions of M matrix"),
    (lambda b: b.update(models=b.pop("model")["models"], variables=["alt_ft", "mach"]),
     "models", "models[0] and models[1] are both at"),
    (lambda b: b.update(models=[{"format": "x"}], variables=["mach"]) or b.pop("model"),
     "models[0]", "format must be"),
])
def test_a_file_that_makes_no_schedule_is_a_422_naming_why_and_stores_nothing(
    client: TestClient, session: Session, tenant: Tenant, change: Any, location: str,
    message: str,
) -> None:
    body = {"engine_type_id": tenant.ids["type"], "name": "bad",
            "model": json.loads(json.dumps(schedule_document()))}
    change(body)
    response = client.post(f"{API}/engine-models", json=body, headers=tenant.headers())
    assert response.status_code == 422, response.text
    detail = error_of(response)["details"][0]
    assert detail["location"] == ["body", location] and message in detail["reason"]
    # Both forms, or the files without their variables: named by the request's validation.
    for wrong in ({**body, "model": schedule_document(), "models": [{}],
                   "variables": ["mach"]},
                  {"engine_type_id": tenant.ids["type"], "name": "x", "models": [{}]}):
        assert client.post(f"{API}/engine-models", json=wrong,
                           headers=tenant.headers()).status_code == 422
    assert stored_models(session, tenant) == 0


def _scheduled_engine(
    client: TestClient, session: Session, tenant: Tenant, *, esn: str, tail: str
) -> tuple[Any, dict[str, Any]]:
    """The schedule imported as the type's model, a design on it made active, and one engine
    of the type installed on a new aircraft: (engine, design)."""
    model_id = post(client, tenant, f"{API}/engine-models", {
        "engine_type_id": tenant.ids["type"], "name": "envelope",
        "model": schedule_document()})["id"]
    design = post(client, tenant, f"{API}/designs",
                  {"engine_model_id": model_id, "name": "d", "spec": SPEC})
    post(client, tenant, f"{API}/designs/{design['id']}/activate", {})
    engine = fleet.create_engine(session, operator_id=tenant.operator_id, esn=esn,
                                 engine_type_id=tenant.ids["type"])
    aircraft = fleet.create_aircraft(session, operator_id=tenant.operator_id, tail=tail)
    fleet.install(session, operator_id=tenant.operator_id, engine_id=engine.id,
                  aircraft_id=aircraft.id, position=1, installed_at=T0 - timedelta(days=1))
    session.commit()
    return engine, design


def test_an_engine_of_a_scheduled_type_is_estimated_to_its_known_health(
    client: TestClient, session: Session, session_factory: Any, tenant: Tenant, tmp_path: Path
) -> None:
    from app.jobs.runner import run_pending

    engine, design = _scheduled_engine(client, session, tenant, esn="S-1", tail="N500")

    # Records at the nine operating points in turn, each from that point's own model, with the
    # sensors' noise; EGT in degF and fuel flow in kg/s (the upload converts them).
    rng = np.random.default_rng(12)
    models = own_models()
    header = ["recorded_at", "tail", "position", "alt_ft", "mach", "dtamb_k", "power_pct",
              "N1[rpm]", "N2[rpm]", "T25[K]", "PS3[kPa]", "T3[K]", "EGT[degF]", "FF[kg/s]",
              "BLEED[%]"]
    lines = [",".join(header)]
    n = 270
    for k in range(n):
        i = k % len(POINTS)
        point, model = POINTS[i], models[i]
        g_y = model.select_health(HEALTH).steady_state_gains()[0]
        dy = g_y @ TRUTH + rng.normal(size=model.n_sensors) * model.sensor_noise_std
        y = np.array([model.trim[s] for s in model.sensor_names]) * (1.0 + dy / 100.0)
        y[5] = y[5] * 1.8 + 32.0  # degC -> degF
        at = (T0 + timedelta(hours=6 * k)).strftime("%Y-%m-%dT%H:%M:%SZ")
        lines.append(",".join(str(v) for v in [
            at, "N500", 1, point["alt_ft"], point["mach"], 0.0, point["power_pct"], *y,
            model.trim["FF"] / 3600.0, model.trim["BLEED"]]))
    path = tmp_path / "scheduled.csv"
    path.write_text("\n".join(lines) + "\n")
    response = client.post(f"{API}/snapshots/file", content=path.read_bytes(),
                           headers={**tenant.headers(), "Content-Type": "text/csv"})
    assert response.status_code in (200, 201, 202), response.text
    run_pending(session_factory)

    trend = client.get(f"{API}/engines/{engine.id}/trend", headers=tenant.headers(),
                       params={"max_points": 5000}).json()
    group = next(g for g in trend["groups"] if g["key"] == "health")
    health = {s["name"]: s for s in group["series"]}
    assert set(health) == set(HEALTH)
    for name, truth in zip(HEALTH, TRUTH, strict=True):
        last = np.array(health[name]["value"][-90:], dtype=float)
        std = np.array(health[name]["sigma"][-90:], dtype=float)
        assert abs(float(np.mean(last)) - truth) < 3 * float(np.mean(std)) + 0.1, (name, last)
        assert float(np.mean(std)) < 0.5, name
    # The design's evaluation runs on its design-point model; the nonlinear-engine run says why
    # it is absent.
    job = client.post(f"{API}/jobs", headers=tenant.headers(), json={
        "kind": "evaluate_design", "parameters": {
            "design_id": design["id"], "n_cases": 8, "duration_s": 3.0, "window_s": 1.0,
            "fault_duration_s": 3.0, "seed": 5}})
    assert job.status_code in (200, 201, 202), job.text
    run_pending(session_factory)
    evaluation = client.get(f"{API}/designs/{design['id']}/evaluation",
                            headers=tenant.headers()).json()["result"]
    assert evaluation["monte_carlo"]["health"]["names"] == HEALTH
    assert evaluation["nonlinear_engine"] is None
    assert "built-in engine" in evaluation["nonlinear_engine_note"]
    # The estimator's schedule gives each node's own trims, in the stored units.
    stored = estimator.estimator_for_design(session, designs.get_design(
        session, operator_id=tenant.operator_id, design_id=design["id"]))
    conditions = np.array([[p["alt_ft"], p["mach"], 0.0, p["power_pct"]] for p in POINTS])
    gains = stored.schedule(conditions)
    for j, name in enumerate(models[0].sensor_names):
        assert np.allclose(gains.y_trim[:, j], [m.trim[name] for m in models], rtol=1e-9), name
    assert not gains.constant


def test_a_stream_of_a_scheduled_type_is_scheduled_on_each_samples_condition(
    client: TestClient, session: Session, tenant: Tenant, settings: Any,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A recording flying two of the schedule's nodes in turn (the sensors steady at the
    engine's health, each from its node's model, in its own units and EGT in degF): the
    stream filter takes each sample's trims and each segment's gain from the schedule, so the
    health comes back at both nodes (on the design point's trims alone the second is far off)."""
    from app.services.streams import estimator as stream_estimator
    from app.services.streams import store as stream_store

    monkeypatch.setattr("app.config.get_settings", lambda: settings)
    _, design = _scheduled_engine(client, session, tenant, esn="S-2", tail="N501")

    models = own_models()
    nodes = (7, 5)  # 35,000 ft at 85 % (the design point), then 20,000 ft at 100 %
    per = 800
    dt = models[0].dt
    rng = np.random.default_rng(21)
    header = ["time_s", "alt_ft", "mach", "dtamb_k", "power_pct", "N1[rpm]", "N2[rpm]",
              "T25[K]", "PS3[kPa]", "T3[K]", "EGT[degF]", "FF[kg/s]", "BLEED[%]"]
    lines = [",".join(header)]
    for s, i in enumerate(nodes):
        point, model = POINTS[i], models[i]
        g_y = model.select_health(HEALTH).steady_state_gains()[0]
        dy = g_y @ TRUTH + rng.standard_normal((per, model.n_sensors)) * model.sensor_noise_std
        y = np.array([model.trim[n] for n in model.sensor_names]) * (1.0 + dy / 100.0)
        y[:, 5] = y[:, 5] * 1.8 + 32.0  # degC -> degF
        for k in range(per):
            lines.append(",".join(f"{v:.8g}" for v in [
                (s * per + k) * dt, point["alt_ft"], point["mach"], 0.0, point["power_pct"],
                *y[k], model.trim["FF"] / 3600.0, model.trim["BLEED"]]))
    response = client.post(f"{API}/streams", content=("\n".join(lines) + "\n").encode(),
                           params={"tail": "N501", "position": 1,
                                   "started_at": (T0 + timedelta(days=1)).isoformat()},
                           headers={**tenant.headers(), "Content-Type": "text/csv"})
    assert response.status_code == 201, response.text
    recording_id = response.json()["recording"]["id"]
    summary = stream_store.estimate_recording(
        session, operator_id=tenant.operator_id, recording_id=recording_id,
        data_dir=settings.data_dir)
    assert summary["samples"] == 2 * per and summary["segments"] == 2
    body = client.get(f"{API}/streams/{recording_id}/estimates", headers=tenant.headers(),
                      params={"max_points": 100_000}).json()
    assert body["names"]["health"] == HEALTH
    t = np.array(body["t_s"])
    for s in range(len(nodes)):
        settled = (t >= (s * per + per // 2) * dt) & (t < (s + 1) * per * dt - 1.0)
        assert settled.sum() >= 3
        for name, truth in zip(HEALTH, TRUTH, strict=True):
            h = np.array(body["h_hat"][name], float)[settled]
            sigma = np.array(body["h_sigma"][name], float)[settled]
            assert abs(float(h.mean()) - truth) < float(sigma.mean()), (s, name, h, sigma)
    # Its trims are the snapshot pipeline's at each condition, in the stored units.
    row = designs.get_design(session, operator_id=tenant.operator_id, design_id=design["id"])
    est = stream_estimator.estimator_for(session, row, models[0].sensor_names)
    snap = estimator.estimator_for_design(session, row)
    conditions = np.array([[p["alt_ft"], p["mach"], 0.0, p["power_pct"]] for p in POINTS])
    np.testing.assert_allclose(est.trims(conditions)[0], snap.schedule(conditions).y_trim,
                               rtol=1e-12)


def test_a_stream_of_a_scheduled_type_without_its_condition_is_a_422_naming_both(
    client: TestClient, session: Session, tenant: Tenant, settings: Any,
) -> None:
    """The type is scheduled on the operating condition: a recording (file or live chunk)
    without one of its columns, or with a sample missing a value, is refused naming the column
    and the type, and nothing is stored."""
    _scheduled_engine(client, session, tenant, esn="S-3", tail="N502")
    model = own_models()[7]  # the design point
    header = ["time_s", "alt_ft", "mach", "dtamb_k", "power_pct", "N1[rpm]", "N2[rpm]",
              "T25[K]", "PS3[kPa]", "T3[K]", "EGT", "FF[kg/h]", "BLEED[%]"]
    point = [POINTS[7]["alt_ft"], POINTS[7]["mach"], 0.0, POINTS[7]["power_pct"]]
    rows = [[k * model.dt, *point, *(model.trim[n] for n in model.sensor_names),
             model.trim["FF"], model.trim["BLEED"]] for k in range(50)]

    def body(drop: str | None = None, blank: tuple[int, str] | None = None) -> bytes:
        keep = [j for j, name in enumerate(header) if name != drop]
        lines = [",".join(header[j] for j in keep)]
        for k, row in enumerate(rows):
            cells = [f"{row[j]:.8g}" for j in keep]
            if blank is not None and blank[0] == k:
                cells[[header[j] for j in keep].index(blank[1])] = ""
            lines.append(",".join(cells))
        return ("\n".join(lines) + "\n").encode()

    csv_headers = {**tenant.headers(), "Content-Type": "text/csv"}
    meta = {"tail": "N502", "position": 1, "started_at": (T0 + timedelta(days=1)).isoformat()}
    for name in ("mach", "power_pct"):
        response = client.post(f"{API}/streams", params=meta, content=body(drop=name),
                               headers=csv_headers)
        assert response.status_code == 422, response.text
        assert error_of(response)["details"] == [{
            "row": None, "column": name,
            "reason": f"required column {name!r} is missing (engine type 'TF-S' is scheduled "
                      "on it)"}]
    blank = client.post(f"{API}/streams", params=meta, content=body(blank=(2, "alt_ft")),
                        headers=csv_headers)
    assert blank.status_code == 422, blank.text
    assert error_of(blank)["details"] == [
        {"row": 3, "column": "alt_ft", "reason": "value is missing"}]
    assert client.get(f"{API}/streams", headers=tenant.headers()).json()["total"] == 0

    live = client.post(f"{API}/streams/live", json={**meta, "dt_s": model.dt},
                       headers=tenant.headers("analyst"))
    assert live.status_code == 201, live.text
    rid = live.json()["id"]
    chunk = client.post(f"{API}/streams/{rid}/chunks", params={"index": 0},
                        content=body(drop="dtamb_k"), headers=csv_headers)
    assert chunk.status_code == 422, chunk.text
    assert "'dtamb_k' is missing (engine type 'TF-S'" in error_of(chunk)["message"]
    assert client.get(f"{API}/streams/{rid}", headers=tenant.headers()).json()["n_samples"] == 0
    assert not list((Path(settings.data_dir) / "recordings").rglob("*.parquet"))
    # The same samples with the condition are stored.
    good = client.post(f"{API}/streams/{rid}/chunks", params={"index": 0}, content=body(),
                       headers=csv_headers)
    assert good.status_code == 201, good.text
