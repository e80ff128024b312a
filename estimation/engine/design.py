"""Design point and sizing of the generic two-spool turbofan.

The design point is sea-level static take-off, fitted to the C-MAPSS FD001
early-life means (T24 642.37 degR, T30 1586.80, T50 1402.65, P15 21.61 psia,
P30 553.96, Nf 2388.06 rpm, Nc 9055.99, BPR 8.418, P2 14.62). Component
efficiencies and losses are chosen; the fan and LPC pressure ratios, the HPC
efficiency and the fuel flow then follow from the targets, and the maps,
turbine flow capacities and nozzle areas are sized so that the off-design model
sits exactly on this point at map coordinate beta = 0.5. C-MAPSS's Ps30 and phi
columns are not on the scale of its P30 and are not used.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.optimize import brentq

from estimation.engine.atmosphere import PSI, RANKINE, flight_condition
from estimation.engine.components import (
    bleed_valve,
    burner,
    compression,
    corrected_flow,
    nozzle,
)
from estimation.engine.gas import (
    R_GAS,
    enthalpy,
    entropy_function,
    isentropic_temperature,
    temperature_from_enthalpy,
)
from estimation.engine.maps import CompressorMap, TurbineMap

# C-MAPSS FD001 early-life means (first ten cycles of the 100 training units).
CMAPSS_TARGETS = {
    "T24": 642.37, "T30": 1586.80, "T50": 1402.65, "P15": 21.609, "P30": 553.96,
    "Nf": 2388.06, "Nc": 9055.99, "BPR": 8.418,
}


@dataclass(frozen=True)
class EngineDesign:
    """Sized engine: maps, areas, losses, inertias and the design-point values."""

    fan: CompressorMap
    lpc: CompressorMap
    hpc: CompressorMap
    hpt: TurbineMap
    lpt: TurbineMap
    nf: float  # design fan speed [rpm] (T2 = 288.15 K, so also corrected)
    nc: float  # design core speed [rpm]
    t13: float  # design temperatures [K] used to correct speeds
    t24: float
    t4: float
    t45: float
    w2: float  # design flows [kg/s]
    w_core: float
    w_byp: float
    w25: float
    w4: float
    wf: float  # design fuel flow [kg/s]
    wc_byp: float  # design corrected bypass flow, for the duct loss
    wc3: float  # design corrected burner-inlet flow, for the burner loss
    dp_byp: float  # bypass duct total-pressure loss at design
    dp_burner: float
    eta_burner: float
    eta_mech: float
    a_byp: float  # nozzle throat areas [m^2]
    a_core: float
    a_30: float  # HPC exit duct area for Ps30 [m^2]
    k_vbv: float  # VBV flow constant
    k_vsv: float  # relative HPC flow change per unit VSV stroke
    j_lp: float  # spool inertias [kg m^2]
    j_hp: float
    mc_hpc: float  # metal heat capacities [J/K]
    mc_hpt: float
    ha_hpc: float  # metal heat-transfer conductances at design flow [W/K]
    ha_hpt: float
    power_fan: float  # design fan power [W], scale of the spool balances
    power_hpc: float
    fn: float  # design net thrust [N]


def _pressure_ratio_from_temperatures(t_in: float, t_is: float, far: float = 0.0) -> float:
    """Pressure ratio p_in/p_out of an isentropic expansion t_in -> t_is."""
    return float(np.exp((entropy_function(t_in, far) - entropy_function(t_is, far)) / R_GAS))


@lru_cache(maxsize=1)
def engine_design() -> EngineDesign:
    """Size the engine at sea-level static take-off (cached; about a millisecond)."""
    tg = CMAPSS_TARGETS
    fc = flight_condition(0.0, 0.0)
    t2, p2, pamb = float(fc.t2), float(fc.p2), float(fc.p_amb)
    w2 = 1460.0
    bpr = tg["BPR"]
    w_core = w2 / (1.0 + bpr)
    w_byp = w2 - w_core
    dp_byp, dp_burner, eta_b, eta_m = 0.01, 0.04, 0.995, 0.99
    eff_fan, eff_lpc, eff_hpt, eff_lpt = 0.905, 0.88, 0.895, 0.915

    # Fan: pressure ratio from P15 through the duct loss.
    pr_fan = tg["P15"] * PSI / (p2 * (1.0 - dp_byp))
    t13, dh_fan = compression(t2, pr_fan, eff_fan)
    p13 = p2 * pr_fan
    # LPC: the pressure ratio that gives T24 at its efficiency.
    t24 = tg["T24"] / RANKINE
    dh_lpc = float(enthalpy(t24) - enthalpy(t13))
    t24_is = float(temperature_from_enthalpy(enthalpy(t13) + eff_lpc * dh_lpc))
    pr_lpc = float(np.exp((entropy_function(t24_is) - entropy_function(t13)) / R_GAS))
    p24 = p13 * pr_lpc
    # VBV: 100 % open bleeds 12 % of the core flow here; the 1 % take-off leak is kept.
    k_vbv = 0.12 * w_core / float(bleed_valve(100.0, p24, t24, pamb, 1.0))
    w25 = w_core - float(bleed_valve(1.0, p24, t24, pamb, k_vbv))
    # HPC: pressure ratio from P30, efficiency from T30.
    p3 = tg["P30"] * PSI
    pr_hpc = p3 / p24
    t3 = tg["T30"] / RANKINE
    dh_hpc = float(enthalpy(t3) - enthalpy(t24))
    eff_hpc = float(enthalpy(isentropic_temperature(t24, pr_hpc)) - enthalpy(t24)) / dh_hpc
    p4 = p3 * (1.0 - dp_burner)
    power_fan, power_lpc, power_hpc = w2 * dh_fan, w_core * dh_lpc, w25 * dh_hpc

    def turbines(wf: float) -> dict[str, float]:
        t4, far = burner(t3, w25, wf, eta_b)
        w4 = w25 + wf
        h4 = float(enthalpy(t4, far))
        dh = power_hpc / (eta_m * w4)
        t45 = float(temperature_from_enthalpy(h4 - dh, far))
        t45s = float(temperature_from_enthalpy(h4 - dh / eff_hpt, far))
        pr_hpt = _pressure_ratio_from_temperatures(float(t4), t45s, float(far))
        h45 = h4 - dh
        dl = (power_fan + power_lpc) / (eta_m * w4)
        t5 = float(temperature_from_enthalpy(h45 - dl, far))
        t5s = float(temperature_from_enthalpy(h45 - dl / eff_lpt, far))
        pr_lpt = _pressure_ratio_from_temperatures(t45, t5s, float(far))
        return dict(t4=float(t4), far=float(far), w4=w4, t45=t45, pr_hpt=pr_hpt,
                    t5=t5, pr_lpt=pr_lpt)

    t50 = tg["T50"] / RANKINE
    wf = brentq(lambda wf: turbines(wf)["t5"] - t50, 0.5, 8.0, xtol=1e-12)
    tb = turbines(wf)
    p45 = p4 / tb["pr_hpt"]
    p5 = p45 / tb["pr_lpt"]

    # Nozzles sized to pass the design flows.
    p15 = p13 * (1.0 - dp_byp)
    w_unit_b, fg_unit_b = nozzle(p15, t13, pamb, 1.0, 0.0)
    a_byp = w_byp / float(w_unit_b)
    w_unit_c, fg_unit_c = nozzle(p5, tb["t5"], pamb, 1.0, tb["far"])
    a_core = tb["w4"] / float(w_unit_c)
    _, fg_b = nozzle(p15, t13, pamb, a_byp, 0.0)
    _, fg_c = nozzle(p5, tb["t5"], pamb, a_core, tb["far"])
    # HPC exit duct: Ps30 / P30 = 0.96 at design (exit Mach about 0.24).
    a_30 = float(np.sqrt(w25**2 * R_GAS * t3 / (2.0 * p3 * 0.04 * p3)))

    fan = CompressorMap(float(corrected_flow(w2, t2, p2)), pr_fan, eff_fan,
                        flow_exp=1.35, pr_exp=2.0, flow_slope=0.25, pr_slope=0.39,
                        eff_speed=0.2)
    lpc = CompressorMap(float(corrected_flow(w_core, t13, p13)), pr_lpc, eff_lpc,
                        flow_exp=1.4, pr_exp=2.0, flow_slope=0.30, pr_slope=0.57,
                        eff_speed=0.2)
    hpc = CompressorMap(float(corrected_flow(w25, t24, p24)), pr_hpc, eff_hpc,
                        flow_exp=2.5, pr_exp=3.0, flow_slope=0.06, pr_slope=0.40)
    hpt = TurbineMap(float(corrected_flow(tb["w4"], tb["t4"], p4)), tb["pr_hpt"], eff_hpt)
    lpt = TurbineMap(float(corrected_flow(tb["w4"], tb["t45"], p45)), tb["pr_lpt"], eff_lpt)

    mc_hpc, mc_hpt = 2.5e5, 8.0e4
    return EngineDesign(
        fan=fan, lpc=lpc, hpc=hpc, hpt=hpt, lpt=lpt,
        nf=tg["Nf"], nc=tg["Nc"], t13=float(t13), t24=t24, t4=tb["t4"], t45=tb["t45"],
        w2=w2, w_core=w_core, w_byp=w_byp, w25=w25, w4=tb["w4"], wf=float(wf),
        wc_byp=float(corrected_flow(w_byp, t13, p13)),
        wc3=float(corrected_flow(w25, t3, p3)),
        dp_byp=dp_byp, dp_burner=dp_burner, eta_burner=eta_b, eta_mech=eta_m,
        a_byp=a_byp, a_core=a_core, a_30=a_30, k_vbv=k_vbv, k_vsv=0.3,
        j_lp=700.0, j_hp=45.0,
        mc_hpc=mc_hpc, mc_hpt=mc_hpt, ha_hpc=mc_hpc / 60.0, ha_hpt=mc_hpt / 20.0,
        power_fan=float(power_fan), power_hpc=float(power_hpc),
        fn=float(fg_b + fg_c),
    )
