"""The engine controller: fan-speed governor on fuel flow with ratio-unit limits.

Seed 001's engine is controlled on corrected low-pressure spool speed: "the
power level angle (PLA) is converted to desired corrected low-pressure spool
speed ... The control system adjusts three actuation values to cause the
corrected measured low-pressure spool speed to match the desired value." Here
the power setting p [%] is that demand (``actuators.demanded_corrected_fan_speed``)
and the three actuators are:

- Wf: a PI loop on the corrected fan speed error whose output is a fuel flow
  in ratio units, RU = Wf / Ps30 [pps/psia]. Ratio units make the loop gain
  nearly independent of altitude (fuel flow and Ps30 both scale with delta),
  and bounding RU between a deceleration and an acceleration schedule on
  corrected core speed is the classical acceleration/deceleration limiter
  (flameout below, surge and over-temperature above). The integrator is
  back-calculated when a limit holds (no wind-up).
- VSV and VBV: the nominal schedules of ``actuators.py`` on measured corrected
  core speed NRc = Nc / sqrt(T24 / T24_design), relative to take-off.

Discrete time, one sample of the sensors per step, low-passed (50 ms) before
use, everything vectorised over a batch of B engines (arrays [B]). The power
setting is the demand; a power lever angle maps onto it linearly between the
idle and take-off stops (``power_from_pla``; the flight profiles give power
directly). Internally the controller works in
normalised units: speeds over the design (take-off) speeds, RU over the design
point's RU.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from estimation.engine.actuators import (
    FLIGHT_IDLE_SLOPE,
    IDLE_FRACTION,
    VBV_OPEN,
    VBV_SHUT,
    VSV_CLOSED,
    VSV_OPEN,
    demanded_corrected_fan_speed,
    vbv_schedule,
    vsv_schedule,
)
from estimation.engine.atmosphere import PSI, RANKINE
from estimation.engine.design import EngineDesign, engine_design
from estimation.engine.steady import steady_state
from estimation.engine.xp import NP, SCALAR

DELTA_EXP = 1.5
PLA_IDLE_DEG, PLA_TAKEOFF_DEG = 20.0, 80.0  # throttle stops [deg]


class ControllerGains(NamedTuple):
    """Gains and limits, normalised: error in NRf / NRf_design, output in RU / RU_design.

    kp [-], ki [1/s]: PI gains. The loop from RU to corrected fan speed has a
    static gain of 0.3-0.55 over the envelope and a spool time constant that
    grows from 0.27 s at take-off to 1.2 s at idle and roughly as 1/delta2 with
    altitude; near idle the bleed and stator schedules add a slow oscillatory
    mode. So the integral gain is scheduled: ki at idle corrected fan speed,
    rising linearly to ki_takeoff * min(delta2, 1)^1.5 at take-off corrected
    speed (never below ki). The defaults, chosen on 6 % power steps at sea
    level and 35,000 ft, settle within 1 % in 2-7 s with at most 18 %
    overshoot, a slam from idle to take-off in about 4.5 s. accel_ratio, decel_ratio: the
    acceleration and deceleration schedules as multiples of the sea-level
    steady RU line at the same corrected core speed. sensor_tau [s]: time
    constant of the first-order filter on the sensed signals (sensor noise
    would otherwise reach the fuel command multiplied by kp; 0 disables it).
    """

    kp: float = 3.0
    ki: float = 1.2
    ki_takeoff: float = 5.0
    accel_ratio: float = 1.45
    decel_ratio: float = 0.55
    sensor_tau: float = 0.05


DEFAULT_GAINS = ControllerGains()


class ControllerState(NamedTuple):
    """integrator [B]: the PI integrator in RU / RU_design (equals RU at rest);
    sensed [B, 4]: the low-passed Nf, Nc [rpm], T24 [degR], Ps30 [psia] the laws use.
    """

    integrator: np.ndarray
    sensed: np.ndarray


class ControlOutput(NamedTuple):
    """Commands [B, 3] (Wf pps, VSV % open, VBV % open) and what limited them.

    ru: commanded ratio units Wf/Ps30 [pps/psia]; ru_min, ru_max: the limits;
    limited: -1 on the deceleration limit, +1 on the acceleration limit, 0 free;
    error: corrected fan speed error over design NRf; nrc_rel: corrected core
    speed over take-off.
    """

    u: np.ndarray
    ru: np.ndarray
    ru_min: np.ndarray
    ru_max: np.ndarray
    limited: np.ndarray
    error: np.ndarray
    nrc_rel: np.ndarray


def power_from_pla(pla_deg: np.ndarray | float) -> np.ndarray:
    """Power setting [%] of a power lever angle [deg]: 0 at the idle stop, 100 at take-off."""
    pla = np.asarray(pla_deg, dtype=float)
    return np.clip(100.0 * (pla - PLA_IDLE_DEG) / (PLA_TAKEOFF_DEG - PLA_IDLE_DEG), 0.0, 100.0)


def design_ratio_units(design: EngineDesign | None = None) -> float:
    """RU = Wf / Ps30 [pps/psia] at the design point (sea-level static take-off)."""
    return float(_steady_ru_line(design)[1][-1])


# Keyed by the design object's identity (the design is kept in the value, so
# the id is not reused): hashing the frozen design field by field on every
# controller sample would cost more than the control law itself. The line is
# kept as arrays (numpy path) and as lists of floats (scalar path).
_RU_LINES: dict[int, tuple[EngineDesign, np.ndarray, np.ndarray, list[float], list[float]]] = {}


def _steady_ru_line(
    design: EngineDesign | None, xp: Any = NP
) -> tuple[Any, Any]:
    """Sea-level static steady line: corrected core speed [-] and RU [pps/psia], sorted."""
    d = design or engine_design()
    hit = _RU_LINES.get(id(d))
    if hit is None:
        power = np.linspace(0.0, 100.0, 26)
        ss = steady_state(np.zeros((power.size, 3)), power=power, design=d)
        nrc = ss.stations["n_hpc"]
        ru = ss.u[:, 0] / (ss.stations["ps30"] / PSI)
        order = np.argsort(nrc)
        nrc, ru = nrc[order], ru[order]
        hit = _RU_LINES[id(d)] = (d, nrc, ru, nrc.tolist(), ru.tolist())
    return (hit[3], hit[4]) if xp is SCALAR else (hit[1], hit[2])


def ratio_unit_limits(
    nrc_rel: np.ndarray, gains: ControllerGains = DEFAULT_GAINS,
    design: EngineDesign | None = None, xp: Any = NP,
) -> tuple[np.ndarray, np.ndarray]:
    """Deceleration and acceleration limits (RU_min, RU_max) [pps/psia] at NRc/NRc_takeoff.

    Multiples of the sea-level steady RU line, held flat beyond its ends.
    """
    grid, ru = _steady_ru_line(design, xp)
    ru_ss = xp.interp(nrc_rel, grid, ru)
    return gains.decel_ratio * ru_ss, gains.accel_ratio * ru_ss


def corrected_core_speed(
    nc: np.ndarray, t24_degr: np.ndarray, design: EngineDesign | None = None, xp: Any = NP
) -> np.ndarray:
    """NRc over take-off: Nc / sqrt(T24 / T24_design) / Nc_design (as the schedules use it)."""
    d = design or engine_design()
    return nc / xp.sqrt(t24_degr / RANKINE / d.t24) / d.nc


def initial_state(
    wf: np.ndarray, nf: np.ndarray, nc: np.ndarray, t24: np.ndarray, ps30: np.ndarray,
    design: EngineDesign | None = None,
) -> ControllerState:
    """State that holds a steady operating point: RU = Wf / Ps30 (pps, psia), filters at rest."""
    ru_d = design_ratio_units(design)
    sensed = np.stack([np.asarray(v, dtype=float) for v in (nf, nc, t24, ps30)], axis=-1)
    return ControllerState(np.asarray(wf, dtype=float) / sensed[..., 3] / ru_d, sensed)


def control_step(
    state: ControllerState,
    power_pct: np.ndarray,
    mach: np.ndarray,
    theta2: np.ndarray,
    delta2: np.ndarray,
    nf: np.ndarray,
    nc: np.ndarray,
    t24: np.ndarray,
    ps30: np.ndarray,
    dt: float,
    gains: ControllerGains = DEFAULT_GAINS,
    design: EngineDesign | None = None,
    xp: Any = NP,
) -> tuple[ControllerState, ControlOutput]:
    """One controller sample for a batch of engines (all arrays [B]; with
    ``xp = SCALAR`` one engine: floats, ``state.sensed`` a list of 4, ``u`` a list).

    power_pct: power setting [%]; mach, theta2 = T2 / 288.15 K and
    delta2 = P2 / 101325 Pa: flight condition (from the aircraft); nf, nc
    [rpm], t24 [degR], ps30 [psia]: measured sensors, low-passed with
    time constant ``gains.sensor_tau`` before use. Returns the next state and
    the commands.

        e   = (NRf_dem(p, M) - Nf / sqrt(theta2)) / NRf_design
        RU  = clip(I + kp e, RU_min(NRc), RU_max(NRc))
        I  <- I + ki(NRf, delta2) e dt, then back-calculated to RU - kp e when clipped
        Wf  = RU Ps30,  VSV = vsv_schedule(NRc),  VBV = vbv_schedule(NRc)
    """
    d = design or engine_design()
    ru_d = design_ratio_units(d)
    # First-order sensor filters: s <- s + dt / (tau + dt) (m - s).
    alpha = dt / (gains.sensor_tau + dt)
    col = xp.col
    sensed = xp.stack([col(state.sensed, i) + alpha * (m - col(state.sensed, i))
                       for i, m in enumerate((nf, nc, t24, ps30))])
    nf, nc, t24, ps30 = col(sensed, 0), col(sensed, 1), col(sensed, 2), col(sensed, 3)
    demand = demanded_corrected_fan_speed(power_pct, d.nf, mach, xp)
    error = (demand - nf / xp.sqrt(theta2)) / d.nf
    nrc = corrected_core_speed(nc, t24, d, xp)
    ru_min, ru_max = ratio_unit_limits(nrc, gains, d, xp)
    nrf_rel = nf / xp.sqrt(theta2) / d.nf
    s = xp.clip((nrf_rel - 0.42) / 0.58, 0.0, 1.0)
    ki = gains.ki + (gains.ki_takeoff * xp.minimum(delta2, 1.0) ** DELTA_EXP - gains.ki) * s
    integ = state.integrator + ki * error * dt
    ru_free = (integ + gains.kp * error) * ru_d
    ru = xp.clip(ru_free, ru_min, ru_max)
    limited = xp.where(ru_free > ru_max, 1, xp.where(ru_free < ru_min, -1, 0))
    # Back-calculation: on a limit the integrator follows the limited output.
    integ = xp.where(limited != 0, ru / ru_d - gains.kp * error, integ)
    u = xp.stack([ru * ps30, vsv_schedule(nrc, xp), vbv_schedule(nrc, xp)])
    return ControllerState(integ, sensed), ControlOutput(u, ru, ru_min, ru_max, limited, error, nrc)


ScalarControlLaw = Callable[
    [float, list[float], float, float, float, float, float, float, float, float],
    tuple[float, list[float], list[float], int],
]


def scalar_control_law(
    dt: float, gains: ControllerGains = DEFAULT_GAINS, design: EngineDesign | None = None,
) -> ScalarControlLaw:
    """``control_step`` with ``xp = SCALAR`` for one engine, with the per-sample lookups
    (design, RU line, gains, filter coefficient) done once.

    The returned ``law(integrator, sensed, power_pct, mach, theta2, delta2, nf, nc, t24,
    ps30)`` gives ``(integrator, sensed, u, limited)``: the same formulas in the same
    order as ``control_step`` (and the schedules of ``actuators.py``), so the same
    floats (tests/estimation/engine/test_controller.py).
    """
    d = design or engine_design()
    ru_d = design_ratio_units(d)
    grid, line = _steady_ru_line(d, SCALAR)
    g0, g_end, f0, f_end = grid[0], grid[-1], line[0], line[-1]
    alpha = dt / (gains.sensor_tau + dt)
    d_nf, d_nc, d_t24 = d.nf, d.nc, d.t24
    kp, ki0, ki_to = gains.kp, gains.ki, gains.ki_takeoff
    decel, accel = gains.decel_ratio, gains.accel_ratio
    idle0, idle_slope = IDLE_FRACTION, FLIGHT_IDLE_SLOPE
    vsv_lo, vsv_span = VSV_CLOSED, VSV_OPEN - VSV_CLOSED
    vbv_hi, vbv_span = VBV_OPEN, VBV_OPEN - VBV_SHUT
    sqrt = math.sqrt

    def law(integrator: float, sensed: list[float], power_pct: float, mach: float,
            theta2: float, delta2: float, m_nf: float, m_nc: float, m_t24: float,
            m_ps30: float) -> tuple[float, list[float], list[float], int]:
        s0, s1, s2, s3 = sensed
        nf = s0 + alpha * (m_nf - s0)
        nc = s1 + alpha * (m_nc - s1)
        t24 = s2 + alpha * (m_t24 - s2)
        ps30 = s3 + alpha * (m_ps30 - s3)
        # actuators.demanded_corrected_fan_speed / idle_fraction
        idle = idle0 + idle_slope * max(mach - 0.05, 0.0)
        demand = d_nf * (idle + (1.0 - idle) * (power_pct / 100.0))
        nf_corr = nf / sqrt(theta2)
        error = (demand - nf_corr) / d_nf
        nrc = nc / sqrt(t24 / RANKINE / d_t24) / d_nc
        # xp.SCALAR.interp on the steady RU line
        if nrc <= g0:
            ru_ss = f0
        elif nrc >= g_end:
            ru_ss = f_end
        else:
            j = bisect_right(grid, nrc) - 1
            ru_ss = (line[j + 1] - line[j]) / (grid[j + 1] - grid[j]) * (nrc - grid[j]) + line[j]
        ru_min, ru_max = decel * ru_ss, accel * ru_ss
        s = min(max((nf_corr / d_nf - 0.42) / 0.58, 0.0), 1.0)
        ki = ki0 + (ki_to * min(delta2, 1.0) ** DELTA_EXP - ki0) * s
        integ = integrator + ki * error * dt
        ru_free = (integ + kp * error) * ru_d
        ru = min(max(ru_free, ru_min), ru_max)
        limited = 1 if ru_free > ru_max else (-1 if ru_free < ru_min else 0)
        if limited != 0:
            integ = ru / ru_d - kp * error
        # actuators.vsv_schedule / vbv_schedule (smoothstep ramps)
        a = min(max((nrc - 0.70) / 0.27, 0.0), 1.0)
        b = min(max((nrc - 0.65) / 0.27, 0.0), 1.0)
        u = [ru * ps30, vsv_lo + vsv_span * (a * a * (3.0 - 2.0 * a)),
             vbv_hi - vbv_span * (b * b * (3.0 - 2.0 * b))]
        return integ, [nf, nc, t24, ps30], u, limited

    return law
