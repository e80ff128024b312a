"""Mass and energy balances per component, recomputed from station values.

The engine is put off equilibrium (spools accelerating, metal colder than the
gas) so that the heat and spool terms are not zero.
"""

import numpy as np

from estimation.engine import gas
from estimation.engine.design import engine_design
from estimation.engine.steady import steady_state
from estimation.engine.turbofan import evaluate


def _transient():
    env = np.array([[0.0, 0.0, 0.0], [30000.0, 0.75, 10.0]])
    ss = steady_state(env, power=np.array([80.0, 60.0]))
    x = ss.x.copy()
    x[:, 2] -= 150.0  # cold HPC metal
    x[:, 3] -= 300.0  # cold HPT metal
    u = ss.u.copy()
    u[:, 0] *= 1.15  # fuel step: the spools accelerate
    ev = evaluate(x, u, env, guess=ss.inner)
    return ev, x


def test_mass_balances():
    st = _transient()[0].stations
    tol = 1e-7
    assert np.allclose(st["w18"], st["w_byp"], rtol=tol)  # bypass nozzle passes bypass flow
    assert np.allclose(st["w_core"] + st["w_byp"], st["w2"], rtol=tol)  # fan split
    assert np.allclose(st["w_hpc"], st["w25"], rtol=tol)  # HPC passes LPC flow less bleed
    assert np.allclose(st["w25"] + st["w_vbv"], st["w_core"], rtol=tol)
    assert np.allclose(st["w4"], st["w25"] + st["wf"], rtol=tol)  # burner adds fuel
    assert np.allclose(st["w8"], st["w4"], rtol=tol)  # core nozzle passes turbine flow
    # Engine: air in plus fuel equals what leaves by nozzles and bleed.
    out = st["w18"] + st["w8"] + st["w_vbv"]
    assert np.allclose(st["w2"] + st["wf"], out, rtol=tol)


def test_component_energy_balances():
    ev, _ = _transient()
    st = ev.stations
    h = gas.enthalpy
    d = engine_design()
    far = st["far"]
    assert np.allclose(st["power_fan"], st["w2"] * (h(st["t13"]) - h(st["t2"])))
    assert np.allclose(st["power_lpc"], st["w_core"] * (h(st["t24"]) - h(st["t13"])))
    assert np.allclose(st["power_hpc"], st["w25"] * (h(st["t3_adiabatic"]) - h(st["t24"])))
    # HPC heat soak: what the gas loses the metal gains.
    assert np.allclose(st["q_hpc"], st["w25"] * (h(st["t3_adiabatic"]) - h(st["t3"])))
    assert np.all(st["q_hpc"] > 0)  # hot gas, cold metal
    # Burner: air enthalpy plus released heat equals products enthalpy.
    lhs = st["w4"] * h(st["t4"], far)
    rhs = st["w25"] * h(st["t3"]) + st["wf"] * d.eta_burner * gas.LHV
    assert np.allclose(lhs, rhs, rtol=1e-12)
    # Turbines: work and heat taken out of the gas.
    hpt_out = st["w4"] * (h(st["t4"], far) - h(st["t45"], far))
    assert np.allclose(hpt_out, st["power_hpt"] + st["q_hpt"])
    assert np.allclose(st["power_lpt"], st["w4"] * (h(st["t45"], far) - h(st["t5"], far)))


def test_whole_engine_energy_balance():
    # In: air enthalpy and fuel heat. Out: enthalpy through nozzles and bleed,
    # heat into metal, shaft losses and spool kinetic energy growth.
    ev, x = _transient()
    st = ev.stations
    d = engine_design()
    h = gas.enthalpy
    w_rpm = (np.pi / 30.0) ** 2
    e_in = st["w2"] * h(st["t2"]) + st["wf"] * d.eta_burner * gas.LHV
    spool = (d.j_lp * w_rpm * x[:, 0] * ev.xdot[:, 0] + d.j_hp * w_rpm * x[:, 1] * ev.xdot[:, 1])
    losses = (1.0 - d.eta_mech) * (st["power_hpt"] + st["power_lpt"])
    e_out = (st["w18"] * h(st["t13"]) + st["w_vbv"] * h(st["t24"])
             + st["w8"] * h(st["t5"], st["far"]) + st["q_hpc"] + st["q_hpt"] + losses + spool)
    assert np.allclose(e_in, e_out, rtol=1e-9)
    assert np.all(ev.xdot[:, :2] > 0)  # the fuel step accelerates both spools


def test_metal_heats_at_the_rate_of_the_heat_flow():
    ev, _ = _transient()
    d = engine_design()
    st = ev.stations
    assert np.allclose(ev.xdot[:, 2], st["q_hpc"] / d.mc_hpc * 1.8)
    assert np.allclose(ev.xdot[:, 3], st["q_hpt"] / d.mc_hpt * 1.8)
