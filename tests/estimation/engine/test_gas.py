"""Gas properties against independent integration of cp."""

import numpy as np
from scipy.integrate import quad

from estimation.engine import gas


def test_enthalpy_is_integral_of_cp():
    for far in (0.0, 0.025):
        for t1, t2 in ((300.0, 900.0), (1100.0, 1700.0)):
            direct, _ = quad(lambda t, far=far: float(gas.cp(t, far)), t1, t2)
            assert np.isclose(gas.enthalpy(t2, far) - gas.enthalpy(t1, far), direct, rtol=1e-10)


def test_temperature_from_enthalpy_inverts():
    t = np.linspace(200.0, 2200.0, 41)
    for far in (0.0, 0.03):
        assert np.allclose(gas.temperature_from_enthalpy(gas.enthalpy(t, far), far), t, atol=1e-9)


def test_isentropic_temperature_keeps_entropy_constant():
    # ds = integral cp/T dT - R ln(p2/p1) = 0, integrated by quadrature.
    rng = np.random.default_rng(0)
    for _ in range(10):
        t1 = rng.uniform(250.0, 1800.0)
        pr = rng.uniform(0.1, 30.0)
        far = rng.uniform(0.0, 0.03)
        t2 = float(gas.isentropic_temperature(t1, pr, far))
        ds, _ = quad(lambda t, far=far: float(gas.cp(t, far)) / t, t1, t2)
        assert abs(ds - gas.R_GAS * np.log(pr)) < 1e-6


def test_constant_gamma_limit():
    # Over a small pressure ratio cp is nearly constant: T2/T1 = PR^(R/cp).
    t1, pr = 300.0, 1.01
    t2 = gas.isentropic_temperature(t1, pr)
    assert np.isclose(t2 / t1, pr ** (gas.R_GAS / gas.cp(t1)), rtol=1e-6)
