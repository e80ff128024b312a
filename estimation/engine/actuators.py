"""Nominal actuator schedules and the power setting.

VSV and VBV are positions in percent of full stroke (100 % VSV = stators fully
open; 0 % VBV = bleed valves shut). Both are scheduled on corrected core speed
NRc = Nc / sqrt(T24 / 288.15 K) relative to its take-off value, with smoothstep
ramps so that the schedules have continuous slopes (linearisation sees no kink):
VSV closes to 40 % at low speed, VBV opens to 60 % at low speed. At take-off
the VBV keeps a 1 % leak, so its trim, and percent-of-trim deviations of it, exist.

Power setting p (percent, 0 = idle, 100 = take-off) is a demanded corrected
fan speed NRf = Nf / sqrt(T2 / 288.15 K), linear between idle and take-off.
Idle rises with flight Mach number (flight idle): with ram pressure the fan
would otherwise fall to windmilling, off its map.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimation.engine.xp import NP

VSV_CLOSED, VSV_OPEN = 40.0, 100.0
VBV_SHUT, VBV_OPEN = 1.0, 60.0
IDLE_FRACTION = 0.42  # ground-idle corrected fan speed / take-off corrected fan speed
FLIGHT_IDLE_SLOPE = 0.5  # rise of the idle fraction per unit Mach above 0.05


def _smoothstep(s: np.ndarray, xp: Any = NP) -> np.ndarray:
    s = xp.clip(s, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def vsv_schedule(nrc_rel: np.ndarray, xp: Any = NP) -> np.ndarray:
    """Nominal VSV position [% open] at corrected core speed / take-off value."""
    return VSV_CLOSED + (VSV_OPEN - VSV_CLOSED) * _smoothstep((nrc_rel - 0.70) / 0.27, xp)


def vbv_schedule(nrc_rel: np.ndarray, xp: Any = NP) -> np.ndarray:
    """Nominal VBV position [% open] at corrected core speed / take-off value."""
    return VBV_OPEN - (VBV_OPEN - VBV_SHUT) * _smoothstep((nrc_rel - 0.65) / 0.27, xp)


def idle_fraction(mach: np.ndarray | float, xp: Any = NP) -> np.ndarray:
    """Idle corrected fan speed over take-off: 0.42 on the ground, rising with Mach."""
    m = xp.asarray(mach, dtype=float)
    return IDLE_FRACTION + FLIGHT_IDLE_SLOPE * xp.maximum(m - 0.05, 0.0)


def demanded_corrected_fan_speed(
    power: np.ndarray | float, nrf_takeoff: float, mach: np.ndarray | float = 0.0,
    xp: Any = NP,
) -> np.ndarray:
    """Corrected fan speed [rpm] for a power setting in percent (0 idle, 100 take-off)."""
    p = xp.asarray(power, dtype=float) / 100.0
    idle = idle_fraction(mach, xp)
    return nrf_takeoff * (idle + (1.0 - idle) * p)
