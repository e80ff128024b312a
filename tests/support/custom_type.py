"""A second engine type whose names appear nowhere in fleethealth's code, for the tests that
check the routes and pages show an engine in its own type's names and units.

``model_file`` is a fleethealth.linear-model/1 file of a made-up two-spool engine: spool states
NL and NH, inputs FF [kg/h] and IGV [deg], health parameters fan_loss, core_loss, hpt_loss and
hpt_area, sensors N1 [%], N2 [%], EGT [degC], PS3 [kPa] and FF_meas [kg/h], aux THR [kN] and SMC
[%]. ``setup`` defines it through the API (type, model, design with a fault library of its own,
active), puts one engine on an aircraft and uploads ``records`` snapshots of a known health in
the type's own columns (``samples`` simulates a stream recording of it instead);
``make_operator`` gives an operator of its own with an analyst key, so the type is alone in its
tenant.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from app.services.tenancy import service as tenancy
from estimation.model import LinearModel

T0 = datetime(2026, 4, 1, tzinfo=UTC)
STATES = (("NL", "%"), ("NH", "%"))
INPUTS = (("FF", "kg/h"), ("IGV", "deg"))
HEALTH = ("fan_loss", "core_loss", "hpt_loss", "hpt_area")
SENSORS = (("N1", "%"), ("N2", "%"), ("EGT", "degC"), ("PS3", "kPa"), ("FF_meas", "kg/h"))
AUX = (("THR", "kN"), ("SMC", "%"))
TRIM = {"NL": 92.0, "NH": 96.0, "FF": 3600.0, "IGV": 10.0, "N1": 92.0, "N2": 96.0,
        "EGT": 780.0, "PS3": 2900.0, "FF_meas": 3600.0, "THR": 110.0, "SMC": 20.0}
NOISE_STD = (0.15, 0.15, 0.25, 0.25, 0.3)  # percent of trim
LIBRARY = [
    {"name": "Fan blade erosion", "shifts": {"fan_loss": -2.0}},
    {"name": "Core fouling", "shifts": {"core_loss": -2.0}},
    {"name": "Turbine nozzle burn", "shifts": {"hpt_loss": -1.5, "hpt_area": 2.0}},
]
TRUTH = np.array([-1.0, -0.8, -0.6, 0.4])  # the engine's health, percent
# Every name the custom type declares (what the pages must show for its engine).
NAMES = tuple(n for n, _u in (*INPUTS, *SENSORS, *AUX)) + HEALTH


def model_file(seed: int = 20261125) -> dict[str, Any]:
    """The made-up engine's model file (stable, full-rank steady-state gains)."""
    rng = np.random.default_rng(seed)
    A = np.array([[0.96, 0.01], [0.02, 0.95]])
    B = np.array([[0.02, 0.002], [0.03, -0.003]])
    L = np.array([[0.010, 0.004, 0.006, -0.003], [0.003, 0.012, 0.008, 0.004]])
    C = np.array([[1.0, 0.0], [0.0, 1.0], [0.4, 0.9], [0.6, 0.8], [0.0, 0.0]])
    D = np.vstack([np.zeros((2, 2)), rng.normal(0.0, 0.3, (2, 2)), [[1.0, 0.0]]])
    M = np.vstack([np.zeros((2, 4)), [[-0.3, -0.9, -1.4, 0.7], [0.5, 0.8, -0.4, -0.9]],
                   np.zeros((1, 4))])
    F = rng.normal(0.0, 0.5, (2, 2))
    G = rng.normal(0.0, 0.2, (2, 2))
    N = rng.normal(0.0, 0.6, (2, 4))
    signals = {"states": STATES, "inputs": INPUTS, "health": tuple((h, "%") for h in HEALTH),
               "sensors": SENSORS, "aux": AUX}
    return {
        "format": "fleethealth.linear-model/1", "dt": 0.02,
        "signals": {g: [{"name": n, "unit": u} for n, u in v] for g, v in signals.items()},
        "matrices": {k: np.asarray(v).tolist() for k, v in
                     dict(A=A, B=B, C=C, D=D, L=L, M=M, F=F, G=G, N=N).items()},
        "trim": TRIM, "sensor_noise_std": list(NOISE_STD),
    }


def records(n: int, seed: int = 1) -> tuple[list[str], list[list[Any]]]:
    """CSV header and rows of ``n`` snapshots of the engine at health TRUTH on aircraft N700
    position 1, one a flight, in the type's own columns (EGT uploaded in degF)."""
    model = LinearModel.from_dict(model_file())
    g_y = model.steady_state_gains()[0]
    rng = np.random.default_rng(seed)
    header = ["recorded_at", "tail", "position", "N1[%]", "N2[%]", "EGT[degF]", "PS3[kPa]",
              "FF_meas[kg/h]", "FF[kg/h]", "IGV[deg]"]
    rows = []
    for k in range(n):
        dy = g_y @ TRUTH + rng.normal(size=model.n_sensors) * model.sensor_noise_std
        y = np.array([TRIM[s] for s in model.sensor_names]) * (1.0 + dy / 100.0)
        y[2] = y[2] * 1.8 + 32.0
        at = (T0 + timedelta(hours=12 * k)).strftime("%Y-%m-%dT%H:%M:%SZ")
        rows.append([at, "N700", 1, *(round(float(v), 4) for v in y), TRIM["FF"], TRIM["IGV"]])
    return header, rows


STREAM_HEADER = ["time_s", "alt_ft", "mach", "dtamb_k", "power_pct", "N1[%]", "N2[%]",
                 "EGT[degF]", "PS3[kPa]", "FF_meas[kg/h]", "FF[kg/h]", "IGV[deg]"]


def samples(n: int, health: np.ndarray, seed: int = 2) -> tuple[list[str], np.ndarray]:
    """CSV header and [n, 12] values of a stream recording of the engine at the model's own
    sample interval, in cruise, inputs at trim: the model file's dynamics run from the steady
    state of ``health[0]`` through ``health`` [n, 4] (percent) with its sensor noise, the
    sensors in the model's units (EGT sent in degF: column 7)."""
    model = LinearModel.from_dict(model_file())
    rng = np.random.default_rng(seed)
    x = np.linalg.solve(np.eye(model.n_states) - model.A, model.L @ health[0])
    dy = np.empty((n, model.n_sensors))
    for k in range(n):
        dy[k] = model.C @ x + model.M @ health[k]
        x = model.A @ x + model.L @ health[k]
    dy += rng.standard_normal(dy.shape) * model.sensor_noise_std
    y = np.array([TRIM[s] for s in model.sensor_names]) * (1.0 + dy / 100.0)
    y[:, 2] = y[:, 2] * 1.8 + 32.0
    t = np.arange(n) * model.dt
    values = np.column_stack([t, np.full(n, 35000.0), np.full(n, 0.8), np.zeros(n),
                              np.full(n, 85.0), y, np.full(n, TRIM["FF"]),
                              np.full(n, TRIM["IGV"])])
    return STREAM_HEADER, values


def make_operator(session: Session) -> tuple[int, str]:
    """An operator of its own and its analyst key (committed)."""
    operator = tenancy.create_operator(session, name=f"Own Types {uuid.uuid4().hex[:8]}")
    _row, key = tenancy.issue_api_key(session, operator=operator, role="analyst", name="a")
    session.commit()
    return operator.id, key


@dataclass(frozen=True)
class CustomFleet:
    type_id: int
    model_id: int
    design_id: int
    engine_id: int
    aircraft_id: int


Post = Callable[[str, dict[str, Any]], dict[str, Any]]


def poster(send: Callable[..., Any], headers: dict[str, str], base_url: str = "") -> Post:
    """A ``Post`` through ``send`` (a TestClient's or httpx's ``post``) that requires a 200
    or 201 and returns the JSON body."""

    def post(path: str, body: dict[str, Any]) -> dict[str, Any]:
        response = send(f"{base_url}{path}", json=body, headers=headers)
        assert response.status_code in (200, 201), (path, response.text)
        result: dict[str, Any] = response.json()
        return result

    return post


def setup(post: Post, upload_csv: Callable[[bytes], Any], n: int = 60) -> CustomFleet:
    """The type, its model, an active design, an engine on an aircraft and ``n`` snapshots (none
    for 0), all through the API (``post(path, body)`` answering the JSON of a success, and
    ``upload_csv(body)``)."""
    type_id = post("/api/v1/engine-types", {"name": "Made-up 2-spool"})["id"]
    model_id = post("/api/v1/engine-models", {"engine_type_id": type_id, "name": "cruise",
                                              "model": model_file()})["id"]
    spec = {"format": "fleethealth.design-spec/1", "method": "subset", "tuners": 4,
            "sensors": ["N1", "N2", "EGT", "PS3"], "faults": LIBRARY,
            "noise": {"Q": [0.01, 0.01], "Qh": [0.05] * 4, "Ph": [1.5] * 4}}
    design_id = post("/api/v1/designs", {"engine_model_id": model_id, "name": "own names",
                                         "spec": spec})["id"]
    post(f"/api/v1/designs/{design_id}/activate", {})
    aircraft_id = post("/api/v1/aircraft", {"tail": "N700"})["id"]
    engine_id = post("/api/v1/engines", {"esn": "MU-1", "engine_type_id": type_id})["id"]
    post("/api/v1/installations",
         {"engine_id": engine_id, "aircraft_id": aircraft_id, "position": 1,
          "installed_at": utc(T0 - timedelta(days=1))})
    if n:
        header, rows = records(n)
        text = "\n".join(",".join(str(v) for v in line) for line in [header, *rows]) + "\n"
        upload_csv(text.encode())
    return CustomFleet(type_id, model_id, design_id, engine_id, aircraft_id)


def utc(dt: datetime) -> str:
    return dt.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
