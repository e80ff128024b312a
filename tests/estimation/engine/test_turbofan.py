"""The nonlinear model's functional API: batches, warm starts, heat soak."""

import numpy as np
import pytest

from estimation.engine.health import health_vector
from estimation.engine.steady import steady_state
from estimation.engine.turbofan import derivatives, evaluate, outputs


@pytest.fixture(scope="module")
def trims():
    env = np.array([[0.0, 0.0, 0.0], [35000.0, 0.8, -5.0], [12000.0, 0.45, 15.0]])
    return steady_state(env, power=np.array([100.0, 85.0, 30.0]))


def test_batch_equals_one_at_a_time(trims):
    rng = np.random.default_rng(3)
    x = trims.x * (1.0 + 0.01 * rng.standard_normal(trims.x.shape))
    u = trims.u * (1.0 + 0.01 * rng.standard_normal(trims.u.shape))
    h = 2.0 * rng.standard_normal((3, 13))
    batch = evaluate(x, u, trims.env, h)
    for i in range(3):
        one = evaluate(x[i], u[i], trims.env[i], h[i])
        assert np.allclose(one.xdot, batch.xdot[i], rtol=1e-7, atol=1e-7)
        assert np.allclose(one.sensors, batch.sensors[i], rtol=1e-9)
        assert np.allclose(one.aux, batch.aux[i], rtol=1e-8, atol=1e-9)


def test_warm_start_does_not_change_the_answer(trims):
    x = trims.x * 1.003
    cold = evaluate(x, trims.u, trims.env, None)
    warm = evaluate(x, trims.u, trims.env, None, guess=trims.inner)
    assert np.allclose(cold.xdot, warm.xdot, rtol=1e-7, atol=1e-7)
    assert np.allclose(cold.inner, warm.inner, atol=1e-8)


def test_wrappers_agree_with_evaluate(trims):
    ev = evaluate(trims.x, trims.u, trims.env, trims.health)
    y, z = outputs(trims.x, trims.u, trims.env, trims.health)
    assert np.array_equal(derivatives(trims.x, trims.u, trims.env, trims.health), ev.xdot)
    assert np.array_equal(y, ev.sensors) and np.array_equal(z, ev.aux)


def test_shape_errors_name_the_argument(trims):
    with pytest.raises(ValueError, match="u must have shape"):
        evaluate(trims.x[0], np.ones(4), trims.env[0])
    with pytest.raises(ValueError, match="rows"):
        evaluate(trims.x, trims.u[:2], trims.env)


def test_cold_metal_lowers_gas_temperatures(trims):
    # Heat soak: HPC and HPT metal colder than the gas draw heat, so T30, T48 and
    # T50 read lower than in the soaked engine at the same spool speeds and fuel.
    x = trims.x.copy()
    x[:, 2:] -= 200.0
    cold = evaluate(x, trims.u, trims.env, None, guess=trims.inner)
    for i in (4, 7, 9):  # T30, T48, T50
        assert np.all(cold.sensors[:, i] < trims.sensors[:, i])
    assert np.all(cold.xdot[:, 2:] > 0)  # and the metal warms up


def test_fuel_and_deterioration_move_spools_the_textbook_way(trims):
    more_fuel = evaluate(trims.x, trims.u * [1.02, 1, 1], trims.env, None, guess=trims.inner)
    assert np.all(more_fuel.xdot[:, :2] > 0)
    worn = evaluate(trims.x, trims.u, trims.env, health_vector({"hpt_eff": -2.0}),
                    guess=trims.inner)
    assert np.all(worn.xdot[:, 1] < 0)  # less HPT work decelerates the core


def test_chord_iteration_with_kept_jacobian_equals_newton(trims):
    first = evaluate(trims.x, trims.u, trims.env, None, guess=trims.inner, with_jacobian=True)
    assert first.jacobian_inv.shape == (3, 5, 5)
    x = trims.x * 1.004
    newton = evaluate(x, trims.u, trims.env, None, guess=trims.inner)
    chord = evaluate(x, trims.u, trims.env, None, guess=trims.inner,
                     jacobian_inv=first.jacobian_inv)
    assert np.allclose(chord.xdot, newton.xdot, rtol=1e-7, atol=1e-7)
    assert np.allclose(chord.sensors, newton.sensors, rtol=1e-9)
    # A useless Jacobian makes the chord iteration fail; Newton takes over.
    junk = np.broadcast_to(1e-6 * np.eye(5), (3, 5, 5))
    rescued = evaluate(x, trims.u, trims.env, None, guess=trims.inner, jacobian_inv=junk)
    assert np.allclose(rescued.sensors, newton.sensors, rtol=1e-9)
