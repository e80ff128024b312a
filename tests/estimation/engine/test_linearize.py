"""Linear models: stable, consistent with the nonlinear model, round-trip as JSON."""

import json

import numpy as np
import pytest

from estimation.engine.health import HEALTH_NAMES, health_vector
from estimation.engine.linearize import linear_model_at, linearize
from estimation.engine.steady import steady_state
from estimation.engine.turbofan import evaluate
from estimation.model import LinearModel

POINTS = [(0.0, 0.0, 100.0), (0.0, 0.0, 0.0), (35000.0, 0.8, 85.0), (40000.0, 0.85, 0.0),
          (15000.0, 0.5, 50.0)]


@pytest.mark.parametrize("alt, mach, power", POINTS)
def test_discrete_model_is_stable(alt, mach, power):
    m = linearize(alt, mach, power)
    assert np.max(np.abs(np.linalg.eigvals(m.A))) < 1.0
    # And the continuous spool modes are those of a few-second engine.
    lam = np.log(np.linalg.eigvals(m.A).astype(complex)) / m.dt
    assert np.all(lam.real < 0) and np.min(lam.real) > -20.0


def _simulate_nonlinear(trim, u, h, seconds, dt=0.015):
    """RK4 on the nonlinear model from the trim state; outputs at each step [k, 12]."""
    x = trim.x.copy()
    guess = trim.inner
    ys = []
    for _ in range(int(round(seconds / dt))):
        ev = evaluate(x, u, trim.env, h, guess=guess)
        guess = ev.inner
        k1 = ev.xdot
        k2 = evaluate(x + 0.5 * dt * k1, u, trim.env, h, guess=guess).xdot
        k3 = evaluate(x + 0.5 * dt * k2, u, trim.env, h, guess=guess).xdot
        k4 = evaluate(x + dt * k3, u, trim.env, h, guess=guess).xdot
        x = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        ys.append(evaluate(x, u, trim.env, h, guess=guess).sensors)
    return np.array(ys)


def _simulate_linear(m, du_pct, dh, steps):
    x = np.zeros(m.n_states)
    ys = []
    for _ in range(steps):
        x = m.A @ x + m.B @ du_pct + m.L @ dh
        ys.append(m.C @ x + m.D @ du_pct + m.M @ dh)
    return np.array(ys)


@pytest.mark.parametrize("case", ["fuel", "hpt_eff"])
def test_small_step_linear_agrees_with_nonlinear(case):
    trim = steady_state(np.array([20000.0, 0.6, 0.0]), power=80.0)
    m = linear_model_at(trim)
    du = np.zeros(3)
    dh = np.zeros(len(HEALTH_NAMES))
    if case == "fuel":
        du[0] = 0.5  # +0.5 % fuel flow
    else:
        dh[HEALTH_NAMES.index("hpt_eff")] = -0.5
    u = trim.u * (1.0 + du / 100.0)
    y_nl = _simulate_nonlinear(trim, u, trim.health + dh, seconds=3.0)
    y_nl_pct = 100.0 * (y_nl - trim.sensors) / trim.sensors
    y_lin = _simulate_linear(m, du, dh, len(y_nl))
    response = np.max(np.abs(y_nl_pct), axis=0)
    significant = response > 0.02 * np.max(response)
    err = np.max(np.abs(y_lin - y_nl_pct), axis=0)
    assert np.all(err[significant] <= 0.02 * response[significant])


def test_steady_state_gains_match_nonlinear_steady_states():
    # Open loop (fuel flow held): linear G_y against the nonlinear re-trim at the
    # same fuel flow, for a small shift of each turbomachinery health parameter.
    env = np.zeros(3)
    trim = steady_state(env, power=100.0)
    m = linear_model_at(trim)
    gy, gz = m.steady_state_gains()
    for j, name in enumerate(HEALTH_NAMES[:10]):
        hit = steady_state(env, wf=float(trim.u[0]), health=health_vector({name: -0.25}))
        dy = 100.0 * (hit.sensors - trim.sensors) / trim.sensors
        lin = -0.25 * gy[:, j]
        scale = max(np.max(np.abs(dy)), 1e-6)
        assert np.max(np.abs(lin - dy)) <= 0.02 * scale + 1e-6, name


def test_wf_sensor_is_the_command_and_biases_are_inputs():
    m = linearize(0.0, 0.0, 100.0)
    iwf = m.sensor_index("Wf")
    assert np.allclose(m.D[iwf], [1.0, 0.0, 0.0], atol=1e-8)
    assert np.allclose(m.C[iwf], 0.0, atol=1e-8) and np.allclose(m.M[iwf], 0.0, atol=1e-8)
    # A percent bias on Wf acts on the states like a percent Wf command.
    assert np.allclose(m.L[:, HEALTH_NAMES.index("wf_bias")], m.B[:, 0], rtol=1e-4, atol=1e-9)


def test_json_round_trip():
    m = linearize(10000.0, 0.4, 60.0)
    back = LinearModel.from_dict(json.loads(json.dumps(m.to_dict())))
    for name in ("A", "B", "C", "D", "L", "M", "F", "G", "N"):
        assert np.array_equal(getattr(back, name), getattr(m, name))
    assert back.trim == m.trim and back.health_names == list(HEALTH_NAMES)


def test_model_at_a_fuel_flow_trim_is_strict_json():
    trim = steady_state(np.array([5000.0, 0.3, 0.0]), wf=3.0)
    m = linear_model_at(trim)
    text = json.dumps(m.to_dict(), allow_nan=False)
    assert json.loads(text)["operating_condition"]["wf_pps"] == 3.0
