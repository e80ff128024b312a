"""The design evaluation's run on the built-in nonlinear engine: stored under its own key and
served by the API, equal to the estimation core's run with the same seed; a design of an
imported model gets none and the result says why."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session, sessionmaker

from app.jobs.runner import run_pending
from app.services.demo import fleet
from app.services.snapshots import estimator
from estimation import evaluate_engine as ee
from estimation.engine.health import HEALTH_NAMES
from estimation.engine.schedule import EngineSchedule, build_schedule
from estimation.posterior import fit_tempering
from estimation.shift_detector import SENSOR_WSSR_MARGIN
from tests.estimation.models import reference_model
from tests.support.fleetkit import Tenant, make_tenant, post

API = "/api/v1"
SMALL_MC = {"n_cases": 4, "duration_s": 2.0, "window_s": 1.0, "fault_duration_s": 2.0}
ENGINE = {"engine_per_fault": 4, "engine_records_before": 8, "engine_records_after": 5}
SEED = 3


@pytest.fixture(scope="module")
def coarse_schedule() -> EngineSchedule:
    # Two nodes per axis keep the test fast; the service uses the full default grid.
    return build_schedule({"alt": (0.0, 40000.0), "mach": (0.0, 0.85), "power": (40.0, 100.0)})


def _design(client: TestClient, tenant: Tenant, type_id: int, model_id: int) -> dict[str, Any]:
    model = client.get(f"{API}/engine-models/{model_id}", headers=tenant.headers()).json()
    sensors = [s for s in model["sensor_names"] if s != "Wf"]
    spec = fleet.design_spec("subset", 9, sensors)
    return post(client, tenant, f"{API}/designs",
                {"engine_model_id": model_id, "name": "subset m=9", "spec": spec})


def _evaluate(
    client: TestClient, tenant: Tenant, factory: sessionmaker[Session], design_id: int
) -> dict[str, Any]:
    params = {"design_id": design_id, "seed": SEED, **SMALL_MC, **ENGINE}
    job = client.post(f"{API}/jobs", json={"kind": "evaluate_design", "parameters": params},
                      headers=tenant.headers())
    assert job.status_code == 202, job.text
    assert run_pending(factory) == [job.json()["id"]]
    out = client.get(f"{API}/designs/{design_id}/evaluation", headers=tenant.headers("viewer"))
    assert out.status_code == 200
    return out.json()["result"]


def test_builtin_design_evaluation_has_the_nonlinear_engine_run(
    client: TestClient, session: Session, session_factory: sessionmaker[Session],
    coarse_schedule: EngineSchedule, monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: coarse_schedule)
    tenant = make_tenant(session, "Engine Run Air")
    type_id = post(client, tenant, f"{API}/engine-types", {"name": "built-in"})["id"]
    model_id = post(client, tenant, f"{API}/engine-models/builtin", {
        "engine_type_id": type_id, "name": "cruise", "alt_ft": 35000.0, "mach": 0.8,
        "power_pct": 80.0,
    })["id"]
    design = _design(client, tenant, type_id, model_id)
    result = _evaluate(client, tenant, session_factory, design["id"])
    run = result["nonlinear_engine"]
    assert run is not None, result.get("nonlinear_engine_note")
    # The same run by the estimation core, same seed and schedule.
    rng = np.random.default_rng(SEED)
    rec = ee.simulate_records(4, rng=rng, n_before=8, n_after=5)
    stored = design["result"] if "result" in design else client.get(
        f"{API}/designs/{design['id']}", headers=tenant.headers()).json()["result"]
    vstar = np.zeros((len(stored["vstar"]), len(HEALTH_NAMES)))
    vstar[:, [HEALTH_NAMES.index(h) for h in stored["health"]]] = stored["vstar"]
    direct = ee.evaluate_design(
        ee.EngineDesign("d", tuple(stored["sensors"]), vstar), rec, coarse_schedule
    )
    np.testing.assert_allclose(run["confusion_percent"], np.round(direct.confusion, 2))
    assert run["percent_correct"] == pytest.approx(float(np.mean(np.diag(direct.confusion))))
    assert run["faults"] == list(direct.faults)
    # The events' confidence tempered on a second fleet of the same run, three times the size.
    second = ee.evaluate_design(
        ee.EngineDesign("d", tuple(stored["sensors"]), vstar),
        ee.simulate_records(12, rng=rng, n_before=8, n_after=5), coarse_schedule)
    tempering = fit_tempering(second.wssr, second.dof, second.true_fault, direct.faults,
                              np.nan_to_num(direct.confusion), SENSOR_WSSR_MARGIN)
    assert run["posterior"] == tempering.to_dict() and tempering.events == 12 * 8
    assert tempering.log_score >= tempering.default_score
    assert run["settings"]["wf"] == "input"  # the demo's designs have no Wf sensor
    names = run["health"]["names"]
    idx = [HEALTH_NAMES.index(h) for h in names]
    np.testing.assert_allclose(run["health"]["rms"], direct.health_rms[idx], rtol=1e-9)
    np.testing.assert_allclose(run["health"]["coverage_95"], direct.coverage[idx], rtol=1e-9)
    # The least 1-sigma the sensors allow: as the estimation core computes it; hpc_flow's
    # stays near its 0.4 % scatter (the VSV rigging mixes with it), hpc_eff's falls far below.
    # From the baseline's own 8 records, 4 of each phase.
    floors = ee.information_floors(coarse_schedule, stored["sensors"], 4)
    np.testing.assert_allclose(run["health"]["floor"], np.round(floors[idx], 4))
    assert run["health"]["floor_records"] == 8
    floor = dict(zip(names, run["health"]["floor"], strict=True))
    assert floor["hpc_flow"] > floor["hpc_eff"]
    # No design beats the bound: the simulated engines' RMS error is above it everywhere.
    assert np.all(np.asarray(run["health"]["rms"]) >= np.asarray(run["health"]["floor"]))
    # The VBV bias moves nothing the sensors see (module docstring of evaluate_engine).
    vis = run["visibility"]
    assert "VBV" in vis["not_visible"] and "HPT" in vis["visible"]
    diag = np.diag(np.asarray(run["confusion_percent"]))
    shown = [run["faults"].index(f) for f in vis["visible"]]
    assert vis["percent_correct_visible"] == pytest.approx(float(np.mean(diag[shown])), abs=0.01)
    # The ceiling the faults' evidence allows (VBV at chance); named on evidence, as the
    # product names faults, no isolation passes it (VBV is named by elimination only).
    assert vis["ceiling_percent_correct"] == pytest.approx(
        ee.chance_ceiling(np.asarray(vis["event_sigmas"])), abs=1e-9)
    assert vis["ceiling_percent_correct"] < 90.0
    assert run["percent_correct_on_evidence"] == pytest.approx(direct.percent_on_evidence)
    assert run["percent_correct_on_evidence"] <= vis["ceiling_percent_correct"]
    np.testing.assert_allclose(np.sum(run["confusion_percent"], axis=1), 100.0, atol=0.05)
    # Ambiguity groups among the visible faults only, each pair linked by > 10 % confusion.
    assert not {f for g in run["ambiguity_groups"] for f in g} & set(vis["not_visible"])


def test_imported_design_evaluation_says_why_there_is_no_engine_run(
    client: TestClient, session: Session, session_factory: sessionmaker[Session],
) -> None:
    tenant = make_tenant(session, "Imported Air")
    type_id = post(client, tenant, f"{API}/engine-types", {"name": "TF-2S"})["id"]
    body = {"engine_type_id": type_id, "name": "cruise", "model": reference_model().to_dict()}
    model_id = post(client, tenant, f"{API}/engine-models", body)["id"]
    spec = {"format": "fleethealth.design-spec/1", "method": "subset", "tuners": 4,
            "noise": {"Q": [0.01, 0.01], "Qh": [0.1] * 10, "Ph": [2.0] * 10}}
    design = post(client, tenant, f"{API}/designs",
                  {"engine_model_id": model_id, "name": "d", "spec": spec})
    result = _evaluate(client, tenant, session_factory, design["id"])
    assert result["nonlinear_engine"] is None
    assert "built-in engine" in result["nonlinear_engine_note"]
    assert "imported" in result["nonlinear_engine_note"]
