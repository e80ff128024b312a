"""Steady state: calibration against FD001, balances, envelope errors."""


import numpy as np
import pytest

from estimation.engine.design import CMAPSS_TARGETS, engine_design
from estimation.engine.errors import EngineConvergenceError, EnvelopeError
from estimation.engine.health import health_vector
from estimation.engine.sensors import AUX_NAMES, SENSOR_NAMES
from estimation.engine.steady import steady_state
from estimation.engine.turbofan import derivatives
from tests.support.paths import FD001

COLUMNS = ("unit cycle alt mach tra T2 T24 T30 T50 P2 P15 P30 Nf Nc epr Ps30 phi NRf NRc "
           "BPR farB htBleed Nf_dmd PCNfR_dmd W31 W32").split()


def _fd001_early_means() -> dict[str, float]:
    if not FD001.exists():
        pytest.skip("C-MAPSS FD001 data not present")
    data = np.loadtxt(FD001)
    early = data[data[:, 1] <= 10]
    return {c: float(early[:, i].mean()) for i, c in enumerate(COLUMNS)}


def _sls_takeoff():
    return steady_state(np.zeros(3), power=100.0)


def test_sea_level_take_off_matches_fd001_early_life():
    means = _fd001_early_means()
    # FD001 flies sea-level static (settings near 0 ft, Mach 0) at TRA 100.
    assert abs(means["alt"]) < 0.01 and abs(means["mach"]) < 0.01 and means["tra"] == 100.0
    ss = _sls_takeoff()
    y = dict(zip(SENSOR_NAMES, ss.sensors, strict=True))
    z = dict(zip(AUX_NAMES, ss.aux, strict=True))
    for name in ("T24", "T30", "T50", "P15", "P30", "Nf", "Nc"):
        assert abs(y[name] / means[name] - 1.0) < 1e-3, name
    assert abs(z["BPR"] / means["BPR"] - 1.0) < 1e-3
    assert 85000.0 < z["Fn"] < 95000.0  # the 90,000 lbf class


def test_design_targets_are_fd001_means():
    means = _fd001_early_means()
    for name, value in CMAPSS_TARGETS.items():
        assert abs(value / means[name] - 1.0) < 2e-4, name


def test_steady_state_has_zero_derivatives_with_heat_soak():
    # The steady solver drops heat flows and sets metal = gas temperature; the
    # dynamic model with heat flows must then be at rest too.
    env = np.array([[0.0, 0.0, 0.0], [35000.0, 0.8, 0.0], [10000.0, 0.4, 20.0]])
    ss = steady_state(env, power=np.array([100.0, 85.0, 20.0]))
    xdot = derivatives(ss.x, ss.u, env, ss.health, guess=ss.inner)
    assert np.max(np.abs(xdot[:, :2])) < 1e-4  # rpm/s
    assert np.max(np.abs(xdot[:, 2:])) < 1e-6  # degR/s


def test_batch_equals_single():
    env = np.array([[0.0, 0.0, 0.0], [30000.0, 0.7, -10.0]])
    h = np.stack([np.zeros(13), health_vector({"hpc_eff": -2.0, "hpt_flow": 1.0})])
    batch = steady_state(env, power=np.array([60.0, 90.0]), health=h)
    for i in range(2):
        one = steady_state(env[i], power=[60.0, 90.0][i], health=h[i])
        assert np.allclose(one.sensors, batch.sensors[i], rtol=1e-8)
        assert np.allclose(one.aux, batch.aux[i], rtol=1e-7, atol=1e-8)


def test_fuel_flow_mode_inverts_power_mode():
    env = np.array([25000.0, 0.6, 5.0])
    by_power = steady_state(env, power=70.0)
    by_fuel = steady_state(env, wf=float(by_power.u[0]))
    assert np.allclose(by_fuel.x, by_power.x, rtol=1e-7)
    assert np.allclose(by_fuel.sensors, by_power.sensors, rtol=1e-7)


def test_envelope_corners_converge():
    alts, machs, powers = [0.0, 40000.0], [0.0, 0.85], [0.0, 100.0]
    env, p = [], []
    for a in alts:
        for m in machs:
            for pw in powers:
                for dt in (-40.0, 40.0):
                    env.append([a, m, dt])
                    p.append(pw)
    ss = steady_state(np.array(env), power=np.array(p))
    assert np.all(ss.aux[:, 2:5] > 0.0)  # positive stall margins everywhere
    # Thrust rises with power at every condition.
    fn = ss.aux[:, 0].reshape(-1, 2, 2)  # [cond, power, dt]
    assert np.all(fn[:, 1, :] > fn[:, 0, :])


@pytest.mark.parametrize(
    "env, power",
    [([45000.0, 0.8, 0.0], 80.0), ([0.0, 1.2, 0.0], 80.0), ([0.0, 0.0, 0.0], 130.0),
     ([-5000.0, 0.0, 0.0], 50.0), ([0.0, 0.0, 80.0], 50.0)],
)
def test_outside_envelope_raises(env, power):
    with pytest.raises(EnvelopeError):
        steady_state(np.array(env), power=power)


def test_non_convergence_raises_not_returns():
    # A fuel flow far beyond take-off has no operating point on the maps.
    d = engine_design()
    with pytest.raises(EngineConvergenceError):
        steady_state(np.zeros(3), wf=40.0 * d.wf / 0.45359237)


def test_nan_input_is_refused():
    with pytest.raises(ValueError):
        steady_state(np.array([0.0, np.nan, 0.0]), power=50.0)
