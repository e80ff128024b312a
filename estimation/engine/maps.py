"""Generic smooth component maps with stall lines.

Compressor (fan, LPC, HPC): corrected speed n (relative to design corrected
speed) and map coordinate beta (0 choke side, 1 on the stall line, 0.5 design):

    Wc  = Wc_d n^aw (1 + kw (beta_d - beta))            corrected flow [kg/s]
    PR  = 1 + (PR_d - 1) n^ap (1 + kp (beta - beta_d))   total pressure ratio
    eta = eta_d (1 - cn (n - 1)^2 - cb db^2 / (1 + (db / 0.8)^2)),  db = beta - beta_d

so along a speed line flow falls and pressure ratio rises towards stall, and
both rise with speed. The stall line is beta = 1; eliminating n gives the stall
pressure ratio at a corrected flow,

    PR_s(Wc) = 1 + (PR_d - 1)(1 + kp (1 - beta_d)) (Wc / Wc_s)^(ap/aw),
    Wc_s = Wc_d (1 - kw (1 - beta_d)),

and the stall margin at constant corrected flow SM = 100 (PR_s / PR - 1) [%].
Turbine (HPT, LPT): Stodola's ellipse law for flow and a parabola in the
loading parameter for efficiency,

    Wc  = Wc_d sqrt((1 - PR^-2) / (1 - PR_d^-2))
    eta = eta_d (1 - ce (v - 1)^2),   v = n / sqrt(ln PR / ln PR_d).

Health scalars multiply corrected flow and efficiency (seed 002 Table 1:
efficiency and flow capacity per module).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from estimation.engine.xp import NP


class CompressorMap(NamedTuple):
    """Design values and shape constants of one compressor map."""

    wc_design: float  # corrected flow at design [kg/s]
    pr_design: float
    eff_design: float
    flow_exp: float = 1.6  # aw
    pr_exp: float = 2.0  # ap
    flow_slope: float = 0.1  # kw: relative flow change over a whole speed line
    pr_slope: float = 0.35  # kp: relative change of PR - 1 over a speed line
    eff_speed: float = 0.35  # cn
    eff_beta: float = 0.4  # cb
    beta_design: float = 0.5


class TurbineMap(NamedTuple):
    """Design values of one turbine map."""

    wc_design: float
    pr_design: float
    eff_design: float
    eff_loading: float = 0.3  # ce


def compressor(
    m: CompressorMap,
    n_rel: np.ndarray,
    beta: np.ndarray,
    flow_scale: np.ndarray | float = 1.0,
    eff_scale: np.ndarray | float = 1.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corrected flow [kg/s], pressure ratio and isentropic efficiency at (n_rel, beta)."""
    db = beta - m.beta_design
    wc = m.wc_design * n_rel**m.flow_exp * (1.0 - m.flow_slope * db) * flow_scale
    pr = 1.0 + (m.pr_design - 1.0) * n_rel**m.pr_exp * (1.0 + m.pr_slope * db)
    dn = n_rel - 1.0
    # Efficiency falls as a parabola near design and levels off far from it
    # (deep choke or past the stall line), so that the gas path still has a
    # solution when a transient drives a compressor off its working range.
    pen = m.eff_beta * db * db / (1.0 + (db / 0.8) ** 2)
    eff = m.eff_design * (1.0 - m.eff_speed * dn * dn - pen) * eff_scale
    return wc, pr, eff


def stall_pressure_ratio(
    m: CompressorMap, wc: np.ndarray, flow_scale: np.ndarray | float = 1.0, xp: Any = NP
) -> np.ndarray:
    """Pressure ratio on the stall line (beta = 1) at corrected flow wc."""
    wc_s = m.wc_design * (1.0 - m.flow_slope * (1.0 - m.beta_design)) * flow_scale
    ratio = xp.maximum(wc / wc_s, 1e-6)
    k = (m.pr_design - 1.0) * (1.0 + m.pr_slope * (1.0 - m.beta_design))
    return 1.0 + k * ratio ** (m.pr_exp / m.flow_exp)


def stall_margin(
    m: CompressorMap, wc: np.ndarray, pr: np.ndarray, flow_scale: np.ndarray | float = 1.0,
    xp: Any = NP,
) -> np.ndarray:
    """Stall margin at constant corrected flow, SM = 100 (PR_stall(Wc) / PR - 1) [%]."""
    return 100.0 * (stall_pressure_ratio(m, wc, flow_scale, xp) / pr - 1.0)


def turbine(
    m: TurbineMap,
    n_rel: np.ndarray,
    pr: np.ndarray,
    flow_scale: np.ndarray | float = 1.0,
    eff_scale: np.ndarray | float = 1.0,
    xp: Any = NP,
) -> tuple[np.ndarray, np.ndarray]:
    """Corrected flow [kg/s] and isentropic efficiency at (n_rel, PR)."""
    prc = xp.maximum(pr, 1.0 + 1e-6)
    wc = m.wc_design * xp.sqrt((1.0 - prc**-2) / (1.0 - m.pr_design**-2)) * flow_scale
    v = n_rel / xp.sqrt(xp.log(prc) / xp.log(m.pr_design))
    dv = xp.minimum(v - 1.0, 1.0)
    eff = m.eff_design * (1.0 - m.eff_loading * dv * dv) * eff_scale
    return wc, eff
