"""Sensor and auxiliary-output names, units and noise.

Names follow station numbering (SAE AS755) and the units are those of the
C-MAPSS data where C-MAPSS has the signal (degR, psia, rpm, pps, lbf).

Noise standard deviations, percent of the trim value at ground maximum power,
from seed 001 Table 2 (the same numbers as seed 000 Table 2, "std. dev. as % of
steady-state values at full power"): XN12 -> Nf 0.25, XN25 -> Nc 0.25,
P17 -> P15 0.5, P25 -> P24 0.5, T25 -> T24 0.75, PS3 -> Ps30 0.5, T3 -> T30 0.75,
T49 -> T48 0.75. The seeds give none for P30, P50, T50 and Wf; these take the
value of the like sensor (pressure 0.5, gas temperature 0.75, Wf 0.5).
Seed 002 Table 2 gives a second, smaller set for six sensors (its column reads
0.005 / 0.015 / 0.010 "percent"; ``NOISE_STD_SEED002`` keeps the fraction-of-
trim reading, in percent) for studies that reproduce seed 002.
"""

from __future__ import annotations

import numpy as np

SENSOR_NAMES = ("Nf", "Nc", "T24", "P24", "T30", "Ps30", "P30", "T48", "P50", "T50", "P15", "Wf")
SENSOR_UNITS = ("rpm", "rpm", "degR", "psia", "degR", "psia", "psia", "degR", "psia", "degR",
                "psia", "pps")
SENSOR_DESCRIPTIONS = (
    "physical fan speed", "physical core speed", "LPC outlet total temperature",
    "LPC outlet total pressure", "HPC outlet total temperature", "HPC outlet static pressure",
    "HPC outlet total pressure", "HPT outlet total temperature (EGT)",
    "LPT outlet total pressure", "LPT outlet total temperature",
    "bypass-duct total pressure", "fuel flow (command)",
)
AUX_NAMES = ("Fn", "T40", "SM_fan", "SM_LPC", "SM_HPC", "BPR")
AUX_UNITS = ("lbf", "degR", "%", "%", "%", "-")
AUX_DESCRIPTIONS = (
    "net thrust", "burner outlet / HPT inlet total temperature", "fan stall margin",
    "LPC stall margin", "HPC stall margin", "bypass ratio",
)

NOISE_STD_PERCENT = {
    "Nf": 0.25, "Nc": 0.25, "T24": 0.75, "P24": 0.5, "T30": 0.75, "Ps30": 0.5,
    "P30": 0.5, "T48": 0.75, "P50": 0.5, "T50": 0.75, "P15": 0.5, "Wf": 0.5,
}
NOISE_STD_SEED002 = {"Nf": 0.5, "Nc": 0.5, "T24": 1.5, "Ps30": 1.0, "T30": 1.5, "T48": 1.5}


def noise_std_percent(names: tuple[str, ...] = SENSOR_NAMES) -> np.ndarray:
    """Noise standard deviations [len(names)] in percent of trim (seed 001 Table 2)."""
    return np.array([NOISE_STD_PERCENT[n] for n in names])


def noise_std(trim_sensors: np.ndarray) -> np.ndarray:
    """Noise standard deviations in sensor units: percent of the given trim values.

    trim_sensors [..., 12] in the order of SENSOR_NAMES.
    """
    return np.abs(np.asarray(trim_sensors)) * noise_std_percent() / 100.0


def add_noise(
    sensors: np.ndarray, trim_sensors: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """Sensors [..., 12] plus Gaussian noise of ``noise_std(trim_sensors)``."""
    std = noise_std(trim_sensors)
    return sensors + std * rng.standard_normal(np.shape(sensors))
