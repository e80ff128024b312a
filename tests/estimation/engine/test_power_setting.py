"""Aux gains at a power setting against the nonlinear engine's steady states."""

import numpy as np
import pytest

from estimation.engine.health import HEALTH_NAMES
from estimation.engine.linearize import linear_model_at
from estimation.engine.power_setting import held_speed_aux_gains
from estimation.engine.sensors import AUX_NAMES, SENSOR_NAMES
from estimation.engine.steady import steady_state


@pytest.mark.parametrize("alt, mach, power", [(0.0, 0.0, 100.0), (35000.0, 0.8, 85.0)])
def test_held_speed_gains_predict_the_deteriorated_engine_at_the_same_power_setting(
    alt: float, mach: float, power: float
) -> None:
    env = np.array([alt, mach, 0.0])
    nominal = steady_state(env, power=power)
    model = linear_model_at(nominal)
    G_y, G_z = model.steady_state_gains()
    G_uy, G_uz = model.steady_state_input_gains()
    held = SENSOR_NAMES.index("Nf")
    closed_z, closed_uz = held_speed_aux_gains(G_z, G_uz, G_y[held], G_uy[held], loop=0)
    assert np.all(closed_uz[:, 0] == 0.0)
    # HPC and HPT deterioration of half a percent: the engine burns more fuel for the same fan
    # speed and gives nearly the same thrust.
    h = np.zeros(len(HEALTH_NAMES))
    h[HEALTH_NAMES.index("hpc_eff")] = -0.5
    h[HEALTH_NAMES.index("hpt_eff")] = -0.5
    worn = steady_state(env, power=power, health=h)
    true = 100.0 * (worn.aux / nominal.aux - 1.0)
    du = 100.0 * (worn.u / nominal.u - 1.0)
    assert du[0] > 0.3  # more fuel
    closed = closed_z @ h + closed_uz @ du
    opened = G_z @ h  # the same fuel flow: what the aux estimate was before
    fn = AUX_NAMES.index("Fn")
    scale = np.maximum(np.abs(true), 0.05)
    assert np.all(np.abs(closed - true) <= 0.1 * scale + 0.02), (closed, true)
    assert abs(opened[fn] - true[fn]) > 5 * abs(closed[fn] - true[fn])


def test_a_loop_input_that_does_not_move_the_held_sensor_is_refused() -> None:
    with pytest.raises(ValueError, match="zero gain"):
        held_speed_aux_gains(np.ones((2, 3)), np.ones((2, 2)), np.ones(3), np.zeros(2), loop=0)


def test_closed_loop_gains_of_stacked_records_are_the_plain_differences_bit_for_bit() -> None:
    """Each record's gains [S, nz, p] are G - k g, computed into one array per result; the
    inputs are left as they were, and a held row shared by every record broadcasts."""
    rng = np.random.default_rng(0)
    S, nz, p, nu = 5, 4, 6, 3
    G_z, G_uz = rng.standard_normal((S, nz, p)), rng.standard_normal((S, nz, nu))
    G_y, G_u = rng.standard_normal((S, p)), rng.standard_normal((S, nu)) + 3.0
    before = [a.copy() for a in (G_z, G_uz, G_y, G_u)]
    for held_y, held_u in ((G_y, G_u), (G_y[0], G_u[0])):
        closed_z, closed_uz = held_speed_aux_gains(G_z, G_uz, held_y, held_u, loop=1)
        k = G_uz[..., :, 1] / held_u[..., 1, None]
        want_uz = G_uz - k[..., :, None] * held_u[..., None, :]
        want_uz[..., 1] = 0.0
        assert closed_z.tobytes() == (G_z - k[..., :, None] * held_y[..., None, :]).tobytes()
        assert closed_uz.tobytes() == want_uz.tobytes()
    for now, then in zip((G_z, G_uz, G_y, G_u), before, strict=True):
        assert now.tobytes() == then.tobytes()
    # A held row with more records than the gains (broadcast the other way): still right.
    closed_z, _ = held_speed_aux_gains(G_z[0], G_uz[0], G_y, G_u, loop=1)
    k = G_uz[0][:, 1] / G_u[:, 1, None]
    assert closed_z.tobytes() == (G_z[0] - k[..., :, None] * G_y[:, None, :]).tobytes()
