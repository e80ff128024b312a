"""Thermodynamics of the gas-path components, vectorised over engines.

Each function maps inlet total conditions (and a pressure ratio or a fuel flow)
to exit conditions and a specific work or heat, with the enthalpies of
``gas.py``; mass is carried by the caller. Energy balances: compressor
h_out = h_in + dh_is / eta; turbine h_out = h_in - eta dh_is; burner
(1 + far) h(T4, far) = h(T3, 0) + far eta_b LHV; nozzle total enthalpy is
kept and the exit velocity follows from the static pressure it reaches.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimation.engine.atmosphere import P_SL, T_SL
from estimation.engine.gas import (
    LHV,
    R_GAS,
    Real,
    coefficients,
    enthalpy_ab,
    isentropic_temperature_ab,
    temperature_from_enthalpy_ab,
)
from estimation.engine.xp import NP

_A_AIR, _B_AIR = coefficients(0.0)


def corrected_flow(w: Real, t: Real, p: Real, xp: Any = NP) -> np.ndarray:
    """Wc = W sqrt(T / 288.15) / (P / 101325)."""
    return w * xp.sqrt(t / T_SL) / (p / P_SL)


def physical_flow(wc: Real, t: Real, p: Real, xp: Any = NP) -> np.ndarray:
    """W from corrected flow: W = Wc (P / 101325) / sqrt(T / 288.15)."""
    return wc * (p / P_SL) / xp.sqrt(t / T_SL)


def compression(
    t_in: Real, pr: Real, eff: Real, xp: Any = NP
) -> tuple[np.ndarray, np.ndarray]:
    """Exit temperature [K] and specific work [J/kg] of a compression by pr at efficiency eff."""
    a, b = _A_AIR, _B_AIR
    h_in = enthalpy_ab(t_in, a, b, xp)
    dh = (enthalpy_ab(isentropic_temperature_ab(t_in, pr, a, b, xp), a, b, xp) - h_in) / eff
    return temperature_from_enthalpy_ab(h_in + dh, a, b, xp), dh


def expansion(
    t_in: Real, pr: Real, eff: Real, far: Real, xp: Any = NP
) -> tuple[np.ndarray, np.ndarray]:
    """Exit temperature [K] and specific work [J/kg] of an expansion by pr (= p_in/p_out > 1)."""
    a, b = coefficients(far)
    h_in = enthalpy_ab(t_in, a, b, xp)
    dh = eff * (h_in - enthalpy_ab(isentropic_temperature_ab(t_in, 1.0 / pr, a, b, xp), a, b, xp))
    return temperature_from_enthalpy_ab(h_in - dh, a, b, xp), dh


def burner(
    t3: Real, w3: Real, wf: Real, eff: float, xp: Any = NP
) -> tuple[np.ndarray, np.ndarray]:
    """Burner exit temperature [K] and fuel-air ratio: (1+far) h4 = h3 + far eff LHV."""
    far = wf / w3
    h4 = (enthalpy_ab(t3, _A_AIR, _B_AIR, xp) + far * eff * LHV) / (1.0 + far)
    a, b = coefficients(far)
    return temperature_from_enthalpy_ab(h4, a, b, xp), xp.asarray(far)


def nozzle(
    pt: Real, tt: Real, p_amb: Real, area: float, far: Real | float, xp: Any = NP
) -> tuple[np.ndarray, np.ndarray]:
    """Flow [kg/s] and gross thrust [N] of a convergent nozzle of throat ``area`` [m^2].

    Subsonic: exit static pressure = ambient; choked (Pt/Pamb above critical): exit
    Mach 1 and pressure thrust A (Ps - Pamb). gamma is taken at the inlet total
    temperature. Pt/Pamb below one is clipped (no reverse flow), which only
    Newton iterates far from a solution can see.
    """
    a, b = coefficients(far)
    c = a + b * tt
    g = c / (c - R_GAS)
    gm1 = g - 1.0
    pr = xp.maximum(pt / p_amb, 1.0 + 1e-9)
    pr_crit = (0.5 * (g + 1.0)) ** (g / gm1)
    pr_exit = xp.minimum(pr, pr_crit)
    m2 = 2.0 / gm1 * (pr_exit ** (gm1 / g) - 1.0)
    ts = tt / (1.0 + 0.5 * gm1 * m2)
    ps = pt / pr_exit
    v = xp.sqrt(m2 * g * R_GAS * ts)
    rho = ps / (R_GAS * ts)
    w = rho * v * area
    return w, w * v + area * (ps - p_amb)


def static_pressure(pt: Real, tt: Real, w: Real, area: float, xp: Any = NP) -> np.ndarray:
    """Static pressure of a low-Mach duct flow: Ps = Pt - W^2 R T / (2 A^2 Pt)."""
    return xp.asarray(pt - w * w * R_GAS * tt / (2.0 * area * area * pt))


def bleed_valve(
    position: Real, pt: Real, tt: Real, p_amb: Real, k: float, xp: Any = NP
) -> np.ndarray:
    """Overboard bleed flow [kg/s] of a valve open ``position`` percent.

    W = k (position / 100) Pt / sqrt(Tt) sqrt(1 - (Pamb/Pt)^2) (ellipse law).
    """
    r = xp.clip(p_amb / pt, 0.0, 1.0)
    return k * (position / 100.0) * pt / xp.sqrt(tt) * xp.sqrt(1.0 - r * r)
