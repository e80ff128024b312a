"""The 13 health and actuator-bias parameters (seed 002 Table 1), in percent.

Order: efficiency and flow capacity of Fan, LPC, HPC, HPT, LPT, then biases of
Wf, VSV and VBV. A value of -2 means 2 % below nominal. Sign convention: a
negative efficiency is deterioration; compressor flow capacity deteriorates
downwards, turbine flow capacity upwards (seed 002 Table 3: HPT fault is -2 %
efficiency and +2 % flow). Component scalars multiply map efficiency and
corrected flow by (1 + h/100); actuator biases multiply the commanded value by
(1 + h/100), so a bias is a percent of the command, as the linear model's
inputs are percent of trim. Read as offsets of full stroke instead, the
library's VSV and VBV faults change no more at take-off and cruise (stators
fully open, bleed valve at its 1 % leak); docs/math.md section 4 gives the
figures.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

HEALTH_NAMES = (
    "fan_eff", "fan_flow", "lpc_eff", "lpc_flow", "hpc_eff",
    "hpc_flow", "hpt_eff", "hpt_flow", "lpt_eff", "lpt_flow",
    "wf_bias", "vsv_bias", "vbv_bias",
)
HEALTH_UNITS = ("%",) * len(HEALTH_NAMES)
N_HEALTH = len(HEALTH_NAMES)
TURBOMACHINERY = HEALTH_NAMES[:10]
ACTUATOR_BIASES = HEALTH_NAMES[10:]


def health_vector(values: Mapping[str, float] | None = None) -> np.ndarray:
    """A (13,) health vector from a name -> percent mapping (missing names are 0).

    Raises KeyError naming an unknown parameter.
    """
    h = np.zeros(N_HEALTH)
    for name, value in (values or {}).items():
        if name not in HEALTH_NAMES:
            raise KeyError(f"unknown health parameter {name!r}; known: {list(HEALTH_NAMES)}")
        h[HEALTH_NAMES.index(name)] = float(value)
    return h
