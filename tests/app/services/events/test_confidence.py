"""Confidence per event, computed when it is read: the posterior over the fault hypotheses
from the stored WSSR and the design's measured confusion (nonlinear engine, else linear Monte
Carlo, else WSSR alone), checked against the formula computed by hand here
(p_i ∝ exp(-WSSR_i / 2) (C_ij + floor) / row sum, estimation/posterior.py); the ambiguity
group when the confusion mixes two faults."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.models.base import utcnow
from app.models.jobs import Job
from tests.app.services.events.test_events import _event
from tests.app.services.trends.test_trends import Fleet, add_engine, make_fleet

FAULTS = ["Fan", "HPC", "HPT", "Wf"]
# Rows true, columns isolated (percent): HPT and Wf mixed, Fan and HPC clean.
ENGINE_CONFUSION = [
    [96.0, 4.0, 0.0, 0.0],
    [2.0, 98.0, 0.0, 0.0],
    [0.0, 0.0, 62.0, 38.0],
    [0.0, 0.0, 30.0, 70.0],
]
FLOOR = 0.5  # fault_posterior's default: percent added to every confusion cell


def _job(session: Session, fleet: Fleet, result: dict[str, Any], minutes: int) -> Job:
    job = Job(
        operator_id=fleet.operator_id, kind="evaluate_design",
        parameters={"design_id": fleet.design.id}, checksum="0" * 64, status="succeeded",
        result=result, finished_at=utcnow() + timedelta(minutes=minutes),
    )
    session.add(job)
    session.flush()
    return job


def _by_hand(wssr: dict[str, float], confusion: list[list[float]] | None) -> np.ndarray:
    w = np.array([wssr[f] for f in FAULTS])
    p = np.exp(-(w - w.min()) / 2)
    if confusion is not None:
        C = np.asarray(confusion) + FLOOR
        C = C / C.sum(axis=1, keepdims=True)
        p = p * C[:, int(np.argmin(w))]
    return p / p.sum()


@pytest.fixture
def fleet(session: Session) -> Fleet:
    fleet = make_fleet(session, "Confidence Air")
    fleet.design.result = {"vstar": [[1.0]] * 5}  # five tuners: dof 4
    session.flush()
    return fleet


def test_posterior_from_wssr_then_linear_then_engine_confusion(
    client: TestClient, session: Session, fleet: Fleet
) -> None:
    engine = add_engine(session, fleet, "CF1")
    clear = {"Fan": 35.0, "HPC": 2.0, "HPT": 28.0, "Wf": 40.0}
    event = _event(session, fleet, engine.id, 1, fault="HPC", wssr=clear)
    session.commit()
    h = {"X-API-Key": fleet.key}
    url = f"/api/v1/events/{event.id}"

    alone = client.get(url, headers=h).json()["confidence"]
    assert alone["source"] == "wssr_only" and alone["confusion_row"] is None
    assert alone["faults"] == FAULTS
    np.testing.assert_allclose(alone["posterior"], _by_hand(clear, None), rtol=1e-9)
    assert sum(alone["posterior"]) == pytest.approx(1.0)
    assert alone["isolated"] == "HPC" and alone["label"] == "HPC"
    assert alone["posterior"][FAULTS.index("HPC")] == max(alone["posterior"])

    linear = [[100.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    _job(session, fleet, {"confusion": {"wssr_q": {"faults": FAULTS, "percent": linear}}}, 1)
    session.commit()
    mc = client.get(url, headers=h).json()["confidence"]
    assert mc["source"] == "linear_monte_carlo"
    np.testing.assert_allclose(mc["posterior"], _by_hand(clear, linear), rtol=1e-9)
    assert mc["confusion_row"] == {"true_fault": "HPC", "faults": FAULTS,
                                   "percent": linear[1]}

    # A newer evaluation with the nonlinear-engine run, fault order differing from the event's.
    order = [3, 2, 1, 0]
    shuffled = np.asarray(ENGINE_CONFUSION)[np.ix_(order, order)].tolist()
    job = _job(session, fleet, {
        "confusion": {"wssr_q": {"faults": FAULTS, "percent": linear}},
        "nonlinear_engine": {"faults": [FAULTS[i] for i in order],
                             "confusion_percent": shuffled,
                             "visibility": {"not_visible": ["VBV"]}},
    }, 2)
    session.commit()
    nl = client.get(url, headers=h).json()["confidence"]
    assert nl["source"] == "nonlinear_engine" and nl["evaluation_job_id"] == job.id
    np.testing.assert_allclose(nl["posterior"], _by_hand(clear, ENGINE_CONFUSION), rtol=1e-9)
    assert nl["confusion_row"]["percent"] == ENGINE_CONFUSION[1]
    assert nl["ambiguity_group"] == ["HPC"] and nl["label"] == "HPC"
    assert nl["not_visible"] == []  # VBV is not in this event's library

    # Close WSSR of HPT and Wf, a design that mixes them: the group is named.
    close = {"Fan": 40.0, "HPC": 30.0, "HPT": 3.0, "Wf": 3.4}
    mixed = _event(session, fleet, engine.id, 2, fault="HPT", wssr=close)
    session.commit()
    listed = client.get("/api/v1/events", headers=h).json()["items"]
    conf = next(e for e in listed if e["id"] == mixed.id)["confidence"]
    expected = _by_hand(close, ENGINE_CONFUSION)
    np.testing.assert_allclose(conf["posterior"], expected, rtol=1e-9)
    assert sum(conf["posterior"]) == pytest.approx(1.0)
    assert conf["ambiguity_group"] == ["HPT", "Wf"]
    assert conf["label"] == "HPT or Wf"
    assert conf["probability"] == pytest.approx(expected[FAULTS.index("HPT")])
    assert conf["probability"] < 0.9  # not reported as certain
    assert conf["confusion_row"]["percent"] == ENGINE_CONFUSION[2]


def test_sensor_space_event_tempered_as_the_engine_run_fitted_it(
    client: TestClient, session: Session, fleet: Fleet
) -> None:
    """With the nonlinear-engine run's tempering stored, an event isolated in sensor space (the
    kind that run measures) takes its WSSR scale and confusion weight, p_i ∝ exp(-WSSR_i / 2 s)
    C_ij^beta; its fit probability keeps the isolation's margin; a tuner-space event is left
    untempered."""
    from scipy import stats

    from estimation.shift_detector import SENSOR_WSSR_MARGIN

    engine = add_engine(session, fleet, "CF3")
    close = {"Fan": 40.0, "HPC": 30.0, "HPT": 6.0, "Wf": 9.0}
    sensor = _event(session, fleet, engine.id, 1, fault="HPT", wssr=close,
                    shift={"health": {"hpt_eff": -2.0}, "wssr_threshold": 60.0,
                           "wssr_dof": 39, "wssr_scale": SENSOR_WSSR_MARGIN})
    tuner = _event(session, fleet, engine.id, 2, fault="HPT", wssr=close)
    tempering = {"wssr_scale": 4.0, "confusion_power": 0.5, "log_score": -0.2,
                 "default_score": -0.3, "events": 600}
    _job(session, fleet, {"nonlinear_engine": {
        "faults": FAULTS, "confusion_percent": ENGINE_CONFUSION,
        "visibility": {"not_visible": []}, "posterior": tempering}}, 1)
    session.commit()
    h = {"X-API-Key": fleet.key}
    got = client.get(f"/api/v1/events/{sensor.id}", headers=h).json()["confidence"]
    w = np.array([close[f] for f in FAULTS])
    C = np.asarray(ENGINE_CONFUSION) + FLOOR
    C = C / C.sum(axis=1, keepdims=True)
    expected = np.exp(-(w - w.min()) / (2 * 4.0)) * C[:, int(np.argmin(w))] ** 0.5
    np.testing.assert_allclose(got["posterior"], expected / expected.sum(), rtol=1e-9)
    assert got["tempering"] == tempering
    assert got["fit_probability"] == pytest.approx(stats.chi2.sf(6.0 / SENSOR_WSSR_MARGIN, 39))
    plain = client.get(f"/api/v1/events/{tuner.id}", headers=h).json()["confidence"]
    assert plain["tempering"] is None
    np.testing.assert_allclose(plain["posterior"], _by_hand(close, ENGINE_CONFUSION), rtol=1e-9)


def test_event_without_wssr_has_no_confidence(
    client: TestClient, session: Session, fleet: Fleet
) -> None:
    engine = add_engine(session, fleet, "CF2")
    event = _event(session, fleet, engine.id, 1, kind="shift", fault=None, magnitude=None,
                   wssr={})
    session.commit()
    shown = client.get(f"/api/v1/events/{event.id}", headers={"X-API-Key": fleet.key}).json()
    assert shown["confidence"] is None


WEAR_LIBRARY = [
    {"name": "Fan", "shifts": {"fan_eff": -2.0, "fan_flow": -2.0}},
    {"name": "HPC", "shifts": {"hpc_eff": -2.0, "hpc_flow": -2.0}},
    {"name": "HPT", "shifts": {"hpt_eff": -2.0, "hpt_flow": 2.0}},
    {"name": "Wf", "shifts": {"wf_bias": -2.0}},
]


def _restricted(wssr: dict[str, float], faults: list[str]) -> np.ndarray:
    """The posterior over ``faults`` alone, with the engine confusion's rows and columns of
    them (each row renormalised over them, the floor added first), by hand."""
    idx = [FAULTS.index(f) for f in faults]
    w = np.array([wssr[f] for f in faults])
    p = np.exp(-(w - w.min()) / 2)
    C = np.asarray(ENGINE_CONFUSION)[np.ix_(idx, idx)] + FLOOR
    C = C / C.sum(axis=1, keepdims=True)
    p = p * C[:, int(np.argmin(w))]
    return p / p.sum()


def test_wear_event_ranks_the_module_faults_its_attribution_chose_from(
    client: TestClient, session: Session, fleet: Fleet
) -> None:
    """A wear event is attributed among module deteriorations fitted with a positive magnitude:
    its confidence ranks those, so the isolated fault is the event's own even where an actuator
    bias (Wf) fits the change better, and the faults left out are named. A wear event stored
    before the hypotheses were (none in its document) ranks the design's module faults."""
    fleet.design.result = {"vstar": [[1.0]] * 5, "health": ["fan_eff", "fan_flow", "hpc_eff",
                                                           "hpc_flow", "hpt_eff", "hpt_flow"],
                           "faults": {"library": WEAR_LIBRARY}}
    _job(session, fleet, {"nonlinear_engine": {"faults": FAULTS,
                                               "confusion_percent": ENGINE_CONFUSION}}, 1)
    engine = add_engine(session, fleet, "CF3")
    wssr = {"Fan": 16.0, "HPC": 15.5, "HPT": 12.0, "Wf": 2.3}  # Wf fits best, HPT of the modules
    wear_doc = {"alert": "directional", "statistic": 8.7, "threshold": 7.4, "baseline_seq": 20}
    health = {"hpt_eff": -3.0, "hpt_flow": 2.0, "fan_eff": 1.0}  # sum of squares 14
    stored = _event(session, fleet, engine.id, 1, kind="wear", fault="HPT", wssr=wssr,
                    shift={"health": health, "wear": {**wear_doc, "hypotheses": ["Fan", "HPT"]}})
    older = _event(session, fleet, engine.id, 2, kind="wear", fault="HPT", wssr=wssr,
                   shift={"wear": wear_doc})
    abrupt = _event(session, fleet, engine.id, 3, fault="Wf", wssr=wssr)
    session.commit()
    h = {"X-API-Key": fleet.key}

    conf = client.get(f"/api/v1/events/{stored.id}", headers=h).json()["confidence"]
    assert conf["faults"] == ["Fan", "HPT"] and conf["left_out"] == ["HPC", "Wf"]
    assert conf["fits_better"] == ["Wf"]  # 2.3 under half of HPT's 12; HPC's 15.5 is not
    assert conf["isolated"] == "HPT" == stored.fault
    np.testing.assert_allclose(conf["posterior"], _restricted(wssr, ["Fan", "HPT"]), rtol=1e-9)
    assert conf["source"] == "nonlinear_engine"
    assert conf["confusion_row"] == {"true_fault": "HPT", "faults": ["Fan", "HPT"],
                                     "percent": [0.0, 62.0]}
    # The fit is judged on the ranked hypotheses: HPT's WSSR of 12 with 4 degrees of freedom.
    assert conf["fit_probability"] == pytest.approx(0.017351, rel=1e-3)
    # HPT's part of the change weighed as its health change: 1 - 12 / 14.
    assert conf["explained"] == pytest.approx(1.0 - 12.0 / 14.0)

    conf = client.get(f"/api/v1/events/{older.id}", headers=h).json()["confidence"]
    assert conf["faults"] == ["Fan", "HPC", "HPT"] and conf["left_out"] == ["Wf"]
    assert conf["isolated"] == "HPT"
    np.testing.assert_allclose(conf["posterior"], _restricted(wssr, ["Fan", "HPC", "HPT"]),
                               rtol=1e-9)

    # An abrupt fault's isolation ranks every fault of the library, actuator biases too.
    conf = client.get(f"/api/v1/events/{abrupt.id}", headers=h).json()["confidence"]
    assert conf["faults"] == FAULTS and conf["left_out"] == [] and conf["isolated"] == "Wf"
    assert conf["explained"] is None


def test_an_isolated_faults_fit_is_judged_with_its_own_degrees_of_freedom(
    client: TestClient, session: Session, fleet: Fleet
) -> None:
    """An abrupt fault isolated in sensor space (20 records of 11 sensors: 219 degrees of
    freedom, the WSSR held to a margin of 1.5 for model error) has a WSSR in the hundreds: its
    fit is judged as chi-squared with those degrees of freedom, not the tuner space's m - 1
    (which called every isolated fault of the demo "none fits", tail probabilities near
    1e-50). Stored with the event, or read back from its threshold for one stored before."""
    from scipy import stats

    from estimation.shift_detector import SENSOR_ISOLATION_LEVEL, SENSOR_WSSR_MARGIN

    engine = add_engine(session, fleet, "CF4")
    wssr = {"Fan": 900.0, "HPC": 255.7, "HPT": 700.0, "Wf": 820.0}
    threshold = SENSOR_WSSR_MARGIN * float(stats.chi2.ppf(SENSOR_ISOLATION_LEVEL, 219))
    base = {"tuners": {"q1": -1.0}, "health": {"hpc_eff": -2.2}, "fault": {"hpc_eff": -2.2},
            "wssr_threshold": threshold}
    stored = _event(session, fleet, engine.id, 1, fault="HPC", wssr=wssr,
                    shift={**base, "wssr_dof": 219, "wssr_scale": SENSOR_WSSR_MARGIN})
    older = _event(session, fleet, engine.id, 2, fault="HPC", wssr=wssr, shift=base)
    session.commit()
    expected_fit = float(stats.chi2.sf(255.7 / SENSOR_WSSR_MARGIN, 219))
    w = np.array([wssr[f] for f in FAULTS]) / SENSOR_WSSR_MARGIN
    p = np.exp(-(w - w.min()) / 2)
    for event in (stored, older):
        conf = client.get(f"/api/v1/events/{event.id}",
                          headers={"X-API-Key": fleet.key}).json()["confidence"]
        assert conf["fit_probability"] == pytest.approx(expected_fit, rel=1e-9)
        assert conf["fit_probability"] > 0.5  # a good fit, as the isolation found it
        np.testing.assert_allclose(conf["posterior"], p / p.sum(), rtol=1e-9)
        assert conf["isolated"] == "HPC"

