"""International Standard Atmosphere and the inlet: altitude, Mach, dTamb to T2, P2.

Troposphere lapse -6.5 K/km to 11 km, isothermal above (ISA, ICAO Doc 7488).
A temperature offset dTamb shifts the temperature, not the pressure (standard
practice for hot/cold days). The inlet is adiabatic with a total-pressure
recovery of 0.9948, which puts sea-level static P2 at C-MAPSS's 14.62 psia.
Corrected parameters (seed 004): theta = T2 / 288.15 K, delta = P2 / 101325 Pa.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from estimation.engine.gas import R_GAS
from estimation.engine.xp import NP

T_SL = 288.15  # K
P_SL = 101325.0  # Pa
FT = 0.3048  # m per ft
PSI = 6894.757293168  # Pa per psi
LBF = 4.4482216152605  # N per lbf
LBM = 0.45359237  # kg per lbm
RANKINE = 1.8  # degR per K
INLET_RECOVERY = 14.62 * PSI / P_SL  # C-MAPSS FD001: P2 = 14.62 psia at sea-level static

_H_TROPOPAUSE = 11000.0  # m
_LAPSE = 0.0065  # K/m
_G0 = 9.80665


class FlightCondition(NamedTuple):
    """Ambient and inlet conditions, each an array over the batch of engines.

    t_amb, p_amb: ambient static temperature [K] and pressure [Pa];
    v0: flight speed [m/s]; t2, p2: fan-face total temperature [K] and
    pressure [Pa]; theta = t2 / 288.15, delta = p2 / 101325.
    """

    t_amb: np.ndarray
    p_amb: np.ndarray
    v0: np.ndarray
    t2: np.ndarray
    p2: np.ndarray
    theta: np.ndarray
    delta: np.ndarray


def isa(
    alt_ft: np.ndarray | float, dtamb: np.ndarray | float = 0.0, xp: Any = NP
) -> tuple[np.ndarray, np.ndarray]:
    """Ambient static temperature [K] and pressure [Pa] at geopotential altitude [ft]."""
    h = xp.asarray(alt_ft, dtype=float) * FT
    t_std = xp.where(h < _H_TROPOPAUSE, T_SL - _LAPSE * h, T_SL - _LAPSE * _H_TROPOPAUSE)
    expo = _G0 / (_LAPSE * R_GAS)
    p_trop = P_SL * (1.0 - _LAPSE * xp.minimum(h, _H_TROPOPAUSE) / T_SL) ** expo
    t_tp = T_SL - _LAPSE * _H_TROPOPAUSE
    p = p_trop * xp.exp(-_G0 * xp.maximum(h - _H_TROPOPAUSE, 0.0) / (R_GAS * t_tp))
    return t_std + xp.asarray(dtamb, dtype=float), p


def flight_condition(
    alt_ft: np.ndarray | float, mach: np.ndarray | float, dtamb: np.ndarray | float = 0.0,
    xp: Any = NP,
) -> FlightCondition:
    """Ambient and fan-face conditions for altitude [ft], Mach number, dTamb [K].

    Ram rise with gamma = 1.4 (the inlet sees ambient air at most 330 K, where
    cp varies by under 1 %): T2 = T (1 + 0.2 M^2), P2 = eta_r P (1 + 0.2 M^2)^3.5.
    """
    t, p = isa(alt_ft, dtamb, xp)
    m = xp.asarray(mach, dtype=float)
    ram = 1.0 + 0.2 * m * m
    t2 = t * ram
    p2 = INLET_RECOVERY * p * ram**3.5
    v0 = m * xp.sqrt(1.4 * R_GAS * t)
    return FlightCondition(t, p, v0, t2, p2, t2 / T_SL, p2 / P_SL)


def correction_factors(
    exponents: np.ndarray, alt_ft: np.ndarray, mach: np.ndarray, dtamb: np.ndarray
) -> np.ndarray:
    """theta^a delta^b [K, n] at K conditions for n signals with exponents [n, 2] (a, b): a
    value divided by its factor is the corrected parameter (seed 004: temperatures (1, 0),
    pressures and thrust (0, 1), speeds (0.5, 0), fuel flow (0.5, 1))."""
    fc = flight_condition(alt_ft, mach, dtamb)
    ab = np.asarray(exponents, dtype=float).reshape(-1, 2)
    return fc.theta[:, None] ** ab[:, 0] * fc.delta[:, None] ** ab[:, 1]
