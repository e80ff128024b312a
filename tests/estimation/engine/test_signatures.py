"""Gas-path fault signatures have the textbook (and FD001) directions."""


import numpy as np
import pytest

from estimation.engine.health import health_vector
from estimation.engine.sensors import AUX_NAMES, SENSOR_NAMES
from estimation.engine.steady import steady_state
from tests.support.paths import FD001

# Column of each signature quantity in the FD001 rows (SOURCE.md order).
FD001_COLUMN = {"T30": 7, "T50": 8, "P30": 11, "Nc": 13, "BPR": 19}
# The issue's figures (end of life minus first cycles, FD001 training set).
ISSUE_SIGNATURE = {"T50": 24.6, "T30": 14.5, "Nc": 39.0, "P30": -2.3, "BPR": 0.097}
SLS = np.zeros(3)


def _fd001_signature() -> dict[str, float]:
    if not FD001.exists():
        pytest.skip("C-MAPSS FD001 data not present")
    data = np.loadtxt(FD001)
    early = data[data[:, 1] <= 10]
    last = np.concatenate([data[data[:, 0] == u][-10:] for u in np.unique(data[:, 0])])
    return {k: float(last[:, c].mean() - early[:, c].mean()) for k, c in FD001_COLUMN.items()}


def _shift(health: dict[str, float], power: float = 100.0) -> dict[str, float]:
    """Sensor and aux change at fixed fan speed (power sets corrected fan speed)."""
    base = steady_state(SLS, power=power)
    hit = steady_state(SLS, power=power, health=health_vector(health))
    d = dict(zip(SENSOR_NAMES, hit.sensors - base.sensors, strict=True))
    d.update(zip(AUX_NAMES, hit.aux - base.aux, strict=True))
    return d


def test_issue_figures_are_fd001():
    fd = _fd001_signature()
    for k, v in ISSUE_SIGNATURE.items():
        assert abs(fd[k] - v) <= 0.05 * abs(v) + 0.02, k


def test_hpc_deterioration_moves_fd001_sensors_the_same_way():
    fd = _fd001_signature()
    model = _shift({"hpc_eff": -2.0, "hpc_flow": -2.0})
    for k in FD001_COLUMN:
        assert np.sign(model[k]) == np.sign(fd[k]), k


def test_hpc_deterioration_fitted_to_fd001_is_a_loss_and_matches():
    # Least-squares HPC efficiency and flow shifts (linear in small shifts) that
    # best explain the FD001 change: both must come out as losses, and the model
    # then reproduces every FD001 direction and T50 within a third.
    fd = _fd001_signature()
    keys = list(FD001_COLUMN)
    scale = np.array([abs(fd[k]) for k in keys])
    e = _shift({"hpc_eff": -1.0})
    f = _shift({"hpc_flow": -1.0})
    a = np.array([[e[k], f[k]] for k in keys]) / scale[:, None]
    b = np.array([fd[k] for k in keys]) / scale
    loss, *_ = np.linalg.lstsq(a, b, rcond=None)  # amounts of -1 % shifts
    assert np.all(loss > 0)
    model = _shift({"hpc_eff": -loss[0], "hpc_flow": -loss[1]})
    for k in keys:
        assert np.sign(model[k]) == np.sign(fd[k]), k
    assert abs(model["T50"] / fd["T50"] - 1.0) < 1 / 3


def _power_for_thrust(fn: float, health: dict[str, float]) -> float:
    """Power setting [%] at which the engine with ``health`` gives thrust fn (secant)."""
    h = health_vector(health)
    p0, p1 = 95.0, 100.0
    f0 = steady_state(SLS, power=p0, health=h).aux[0] - fn
    f1 = steady_state(SLS, power=p1, health=h).aux[0] - fn
    for _ in range(20):
        p0, p1, f0 = p1, p1 - f1 * (p1 - p0) / (f1 - f0), f1
        f1 = steady_state(SLS, power=p1, health=h).aux[0] - fn
        if abs(f1) < 1e-6 * fn:
            break
    return p1


def test_hpt_efficiency_loss_raises_egt_and_fuel_at_constant_thrust():
    base = steady_state(SLS, power=95.0)
    health = {"hpt_eff": -2.0}
    p = _power_for_thrust(float(base.aux[0]), health)
    hit = steady_state(SLS, power=p, health=health_vector(health))
    assert np.isclose(hit.aux[0], base.aux[0], rtol=1e-5)  # same thrust
    y0 = dict(zip(SENSOR_NAMES, base.sensors, strict=True))
    y1 = dict(zip(SENSOR_NAMES, hit.sensors, strict=True))
    assert y1["T48"] > y0["T48"] + 5.0
    assert y1["T50"] > y0["T50"] + 5.0
    assert y1["Wf"] > y0["Wf"]


def test_turbine_flow_capacity_increase_is_deterioration():
    # Seed 002 Table 3: an HPT fault is -2 % efficiency and +2 % flow; a larger
    # flow capacity lowers P30 and the HPC operating line (more HPC stall margin).
    d = _shift({"hpt_flow": 2.0})
    assert d["P30"] < 0 and d["SM_HPC"] > 0
