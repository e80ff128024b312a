"""Gas properties: air and kerosene combustion products with temperature-dependent cp.

cp is linear in temperature, with coefficients that grow with the fuel-air ratio:

    cp(T, far) = a(far) + b(far) T                [J/(kg K)]
    a = 952 + 452 fa,  b = 0.176 + 1.62 fa,  fa = far / (1 + far)

(a least-squares line through air tables 300-1500 K, plus the increment of
stoichiometric products). Then enthalpy and the entropy function are closed form,

    h(T)   = a T + b T^2 / 2                      (reference 0 K)
    phi(T) = a ln T + b T                         (ds = (cp/T) dT - R dp/p)

so an isentropic change of pressure ratio PR is phi(T_s) = phi(T_1) + R ln PR.
T from h is a quadratic; T from phi takes three vectorised Newton steps from the
constant-gamma guess (error below 1e-9 K over 200-2200 K). The gas constant is
taken as the same for air and products (R = 287.05 J/(kg K)).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimation.engine.xp import NP

# Gas-path functions take scalars (the design point) or arrays (a batch of engines).
Real = np.ndarray | float

R_GAS = 287.05  # J/(kg K)
LHV = 43.0e6  # J/kg, lower heating value of Jet-A

_A0, _A1 = 952.0, 452.0
_B0, _B1 = 0.176, 1.62


def _coefficients(far: Real | float) -> tuple[np.ndarray, np.ndarray]:
    """cp = a + b T coefficients; air (far = 0.0, a Python float) skips the arithmetic."""
    if isinstance(far, float) and far == 0.0:
        return _A0, _B0  # type: ignore[return-value]
    fa = far / (1.0 + far)
    return _A0 + _A1 * fa, _B0 + _B1 * fa  # type: ignore[return-value]


def coefficients(far: Real | float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) of cp = a + b T at fuel-air ratio far, for the ``*_ab`` functions below."""
    return _coefficients(far)


def enthalpy_ab(t: Real, a: Real, b: Real, xp: Any = NP) -> np.ndarray:
    """h = a T + b T^2 / 2 with given coefficients (the hot path of the cycle; arrays
    in, arrays out, so no conversion is spent here)."""
    return t * (a + 0.5 * b * t)  # type: ignore[return-value]


def temperature_from_enthalpy_ab(h: Real, a: Real, b: Real, xp: Any = NP) -> np.ndarray:
    """Inverse of ``enthalpy_ab``."""
    return 2.0 * h / (a + xp.sqrt(a * a + 2.0 * b * h))


def isentropic_temperature_ab(
    t1: Real, pressure_ratio: Real, a: Real, b: Real, xp: Any = NP
) -> np.ndarray:
    """``isentropic_temperature`` with given coefficients."""
    log = xp.log
    target = a * log(t1) + b * t1 + R_GAS * log(pressure_ratio)
    t = t1 * pressure_ratio ** (R_GAS / (a + b * t1))
    # Three Newton steps, written out (the cycle calls this five times per evaluation).
    t = t - (a * log(t) + b * t - target) / (a / t + b)
    t = t - (a * log(t) + b * t - target) / (a / t + b)
    return t - (a * log(t) + b * t - target) / (a / t + b)


def cp(t: Real, far: Real | float = 0.0) -> np.ndarray:
    """Specific heat at constant pressure [J/(kg K)] at temperature t [K]."""
    a, b = _coefficients(far)
    return a + b * t


def gamma(t: Real, far: Real | float = 0.0) -> np.ndarray:
    """Ratio of specific heats cp / (cp - R)."""
    c = cp(t, far)
    return c / (c - R_GAS)


def enthalpy(t: Real, far: Real | float = 0.0) -> np.ndarray:
    """Specific enthalpy [J/kg] above 0 K: h = a T + b T^2 / 2."""
    a, b = _coefficients(far)
    return t * (a + 0.5 * b * t)


def temperature_from_enthalpy(h: Real, far: Real | float = 0.0, xp: Any = NP) -> np.ndarray:
    """Invert h(T): the positive root of b/2 T^2 + a T - h = 0."""
    a, b = _coefficients(far)
    # Written as 2h / (a + sqrt(a^2 + 2bh)) to avoid cancellation.
    return 2.0 * h / (a + xp.sqrt(a * a + 2.0 * b * h))


def entropy_function(t: Real, far: Real | float = 0.0) -> np.ndarray:
    """phi(T) = integral of cp/T dT = a ln T + b T [J/(kg K)]."""
    a, b = _coefficients(far)
    return a * np.log(t) + b * t


def isentropic_temperature(
    t1: Real, pressure_ratio: Real, far: Real | float = 0.0
) -> np.ndarray:
    """Temperature after an isentropic change from t1 by p2/p1 = pressure_ratio.

    Solves phi(T) = phi(t1) + R ln(pressure_ratio) by Newton, f' = a/T + b.
    Works for compression (ratio > 1) and expansion (ratio < 1).
    """
    a, b = _coefficients(far)
    return isentropic_temperature_ab(t1, pressure_ratio, a, b)
