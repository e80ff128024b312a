"""The nonlinear two-spool turbofan: gas path, spool and heat-soak dynamics, outputs.

Stations (SAE AS755): 0 ambient, 2 fan face, 13 fan exit, 15 bypass duct,
18 bypass nozzle, 21 LPC inlet (= 13), 24 LPC exit / HPC inlet, 30 HPC exit,
40 burner exit / HPT inlet, 48 HPT exit / LPT inlet (called 45 in code),
50 LPT exit, 8 core nozzle.

States x = [Nf rpm, Nc rpm, TMHPC degR, TMHPT degR] (spool speeds and the
metal temperatures of the HPC and HPT, seed 000 Table 1 keeps these among its
nine), inputs u = [Wf pps, VSV % open, VBV % open], environment
env = [altitude ft, Mach, dTamb K], health h = the 13 percent parameters of
``health.py``. Every function takes one engine (1-D arrays) or a batch
(leading axis B) and returns the same layout.

The gas path is quasi-steady: five unknowns (fan, LPC and HPC map beta, HPT and
LPT pressure ratio over design) are solved by batched Newton so that flows match
at the bypass nozzle, HPC inlet, HPT, LPT and core nozzle. The states then move by

    dN/dt   = (eta_m P_turbine - P_compressors) / (J (pi/30)^2 N)      [rpm/s]
    dTm/dt  = Q / (m c),  Q = hA (W/W_d)^0.8 (T_gas - Tm)               [K/s]

and Q is taken out of the gas (HPC exit; HPT between inlet and exit), so a cold
engine accelerates with lower T30, T48 and T50 than a soaked one (seed 004's
model-plant mismatch). At steady state Q = 0 and Tm equals the gas temperature.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from estimation.engine.actuators import vbv_schedule, vsv_schedule
from estimation.engine.atmosphere import (
    LBF,
    LBM,
    PSI,
    RANKINE,
    FlightCondition,
    flight_condition,
)
from estimation.engine.components import (
    bleed_valve,
    burner,
    compression,
    corrected_flow,
    expansion,
    nozzle,
    physical_flow,
    static_pressure,
)
from estimation.engine.design import EngineDesign, engine_design
from estimation.engine.errors import EngineConvergenceError
from estimation.engine.gas import enthalpy, temperature_from_enthalpy
from estimation.engine.health import N_HEALTH
from estimation.engine.maps import compressor, stall_margin, turbine
from estimation.engine.newton import newton
from estimation.engine.xp import NP

STATE_NAMES = ("Nf", "Nc", "TMHPC", "TMHPT")
STATE_UNITS = ("rpm", "rpm", "degR", "degR")
INPUT_NAMES = ("Wf", "VSV", "VBV")
INPUT_UNITS = ("pps", "%", "%")
ENV_NAMES = ("alt", "mach", "dtamb")
ENV_UNITS = ("ft", "-", "K")
INNER_NAMES = ("beta_fan", "beta_lpc", "beta_hpc", "pr_hpt_rel", "pr_lpt_rel")
INNER_DESIGN = np.array([0.5, 0.5, 0.5, 1.0, 1.0])
RESIDUAL_NAMES = ("bypass nozzle flow", "HPC inlet flow", "HPT flow", "LPT flow",
                  "core nozzle flow")
_RPM2 = (np.pi / 30.0) ** 2


class Operating(NamedTuple):
    """Per-engine arrays [B] the gas path needs besides its five unknowns."""

    nf: np.ndarray
    nc: np.ndarray
    tm_hpc: np.ndarray  # K
    tm_hpt: np.ndarray  # K
    wf: np.ndarray  # commanded fuel flow, kg/s
    vsv: np.ndarray  # commanded, % open
    vbv: np.ndarray
    fc: FlightCondition
    h: np.ndarray  # [B, 13] percent

    def take(self, rows: np.ndarray) -> Operating:
        fc = FlightCondition(*(a[rows] for a in self.fc))
        return Operating(
            self.nf[rows], self.nc[rows], self.tm_hpc[rows], self.tm_hpt[rows],
            self.wf[rows], self.vsv[rows], self.vbv[rows], fc, self.h[rows],
        )


def operating_variables(op: Operating) -> tuple[Any, ...]:
    """The states and commands the gas path depends on, v = (Nf, Nc, TMHPC, TMHPT,
    Wf, VSV, VBV) in Operating's units (arrays [B], or floats for one engine)."""
    return op.nf, op.nc, op.tm_hpc, op.tm_hpt, op.wf, op.vsv, op.vbv


def as_batch(
    x: np.ndarray, u: np.ndarray, env: np.ndarray, health: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """Broadcast x [.., 4], u [.., 3], env [.., 3], health [.., 13] to a common batch B.

    Returns 2-D arrays and whether every input was 1-D (one engine).
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    env = np.asarray(env, dtype=float)
    h = np.zeros(N_HEALTH) if health is None else np.asarray(health, dtype=float)
    single = x.ndim == 1 and u.ndim == 1 and env.ndim == 1 and h.ndim == 1
    for name, arr, n in (("x", x, 4), ("u", u, 3), ("env", env, 3), ("health", h, N_HEALTH)):
        if arr.ndim not in (1, 2) or arr.shape[-1] != n:
            raise ValueError(f"{name} must have shape ({n},) or (B, {n}), found {arr.shape}")
    b = max(a.shape[0] if a.ndim == 2 else 1 for a in (x, u, env, h))
    out = []
    for name, arr in (("x", x), ("u", u), ("env", env), ("health", h)):
        a2 = np.atleast_2d(arr)
        if a2.shape[0] not in (1, b):
            raise ValueError(f"{name} has {a2.shape[0]} rows, other inputs have {b}")
        out.append(np.broadcast_to(a2, (b, a2.shape[1])))
    return out[0], out[1], out[2], out[3], single


def operating(x: np.ndarray, u: np.ndarray, env: np.ndarray, h: np.ndarray) -> Operating:
    """Pack 2-D batches (states in their units) into SI per-engine arrays."""
    fc = flight_condition(env[:, 0], env[:, 1], env[:, 2])
    return Operating(
        x[:, 0], x[:, 1], x[:, 2] / RANKINE, x[:, 3] / RANKINE,
        u[:, 0] * LBM, u[:, 1], u[:, 2], fc, h,
    )


def gas_path(
    op: Operating,
    z: np.ndarray,
    d: EngineDesign,
    heat: bool = True,
    scheduled_actuators: bool = False,
    stations: bool = True,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Residuals [B, 5] of the five flow matches and every station value.

    ``heat=False`` removes the heat flows (steady state), and the returned
    metal temperatures are then the gas temperatures they settle at.
    ``scheduled_actuators=True`` commands VSV and VBV by their nominal schedules
    on corrected core speed instead of ``op.vsv``, ``op.vbv`` (steady state).
    ``stations=False``: only the state derivatives, t24 and ps30 (a transient step).
    """
    hs = op.h / 100.0
    res, st = gas_path_columns(
        op, [z[:, i] for i in range(5)], [hs[:, i] for i in range(N_HEALTH)], d,
        heat, scheduled_actuators, NP, stations,
    )
    return np.stack(res, axis=1), st


def gas_path_columns(
    op: Operating,
    z: Sequence[Any],
    hs: Sequence[Any],
    d: EngineDesign,
    heat: bool = True,
    scheduled_actuators: bool = False,
    xp: Any = NP,
    stations: bool = True,
) -> tuple[list[Any], dict[str, Any]]:
    """The cycle of ``gas_path`` on columns: z the five unknowns, hs the 13 health
    parameters as fractions (h / 100), each an array [B] with ``xp = NP`` or a
    float with ``xp = SCALAR`` (one engine; ``op`` then holds floats). Returns the
    five residuals and the stations, in the same layout; ``stations=False`` keeps
    only the state derivatives (dnf, dnc, dtm_hpc, dtm_hpt), t24 and ps30.
    """
    fc = op.fc
    wf = op.wf * (1.0 + hs[10])
    t2, p2, pamb = fc.t2, fc.p2, fc.p_amb

    # Fan (one map for core and bypass streams).
    n_fan = op.nf / xp.sqrt(fc.theta) / d.nf
    wc2, pr_fan, eff_fan = compressor(d.fan, n_fan, z[0], 1.0 + hs[1], 1.0 + hs[0])
    w2 = physical_flow(wc2, t2, p2, xp)
    t13, dh_fan = compression(t2, pr_fan, eff_fan, xp)
    p13 = p2 * pr_fan
    # LPC (booster) on the fan shaft.
    n_lpc = op.nf / xp.sqrt(t13 / d.t13) / d.nf
    wc21, pr_lpc, eff_lpc = compressor(d.lpc, n_lpc, z[1], 1.0 + hs[3], 1.0 + hs[2])
    w_core = physical_flow(wc21, t13, p13, xp)
    t24, dh_lpc = compression(t13, pr_lpc, eff_lpc, xp)
    p24 = p13 * pr_lpc
    # Bypass duct and nozzle.
    w_byp = w2 - w_core
    dp = d.dp_byp * (corrected_flow(w_byp, t13, p13, xp) / d.wc_byp) ** 2
    p15 = p13 * (1.0 - dp)
    w18, fg_byp = nozzle(p15, t13, pamb, d.a_byp, 0.0, xp)
    # Variable bleed overboard, then the HPC with its variable stators.
    n_hpc = op.nc / xp.sqrt(t24 / d.t24) / d.nc
    vsv_nominal = vsv_schedule(n_hpc, xp)
    if scheduled_actuators:
        vsv_cmd, vbv_cmd = vsv_nominal, vbv_schedule(n_hpc, xp)
    else:
        vsv_cmd, vbv_cmd = op.vsv, op.vbv
    vsv = vsv_cmd * (1.0 + hs[11])
    vbv = vbv_cmd * (1.0 + hs[12])
    w_vbv = bleed_valve(vbv, p24, t24, pamb, d.k_vbv, xp)
    w25 = w_core - w_vbv
    dv = (vsv - vsv_nominal) / 100.0
    flow_vsv = 1.0 + d.k_vsv * (vsv - 100.0) / 100.0
    wc25, pr_hpc, eff_hpc = compressor(
        d.hpc, n_hpc, z[2], (1.0 + hs[5]) * flow_vsv, (1.0 + hs[4]) * (1.0 - 0.5 * dv * dv)
    )
    w_hpc = physical_flow(wc25, t24, p24, xp)
    t3a, dh_hpc = compression(t24, pr_hpc, eff_hpc, xp)
    p3 = p24 * pr_hpc
    if heat:
        q_hpc = d.ha_hpc * xp.abs(w25 / d.w25) ** 0.8 * (t3a - op.tm_hpc)
        t3 = temperature_from_enthalpy(enthalpy(t3a) - q_hpc / w25, 0.0, xp)
    else:
        q_hpc = xp.zeros_like(t3a)
        t3 = t3a
    # Burner.
    dpb = d.dp_burner * (corrected_flow(w25, t3, p3, xp) / d.wc3) ** 2
    p4 = p3 * (1.0 - dpb)
    t4, far = burner(t3, w25, wf, d.eta_burner, xp)
    w4 = w25 + wf
    # HPT.
    pr_hpt = z[3] * d.hpt.pr_design
    n_hpt = op.nc / xp.sqrt(t4 / d.t4) / d.nc
    wc4, eff_hpt = turbine(d.hpt, n_hpt, pr_hpt, 1.0 + hs[7], 1.0 + hs[6], xp)
    w4_map = physical_flow(wc4, t4, p4, xp)
    t45a, dh_hpt = expansion(t4, pr_hpt, eff_hpt, far, xp)
    t_gas_hpt = 0.5 * (t4 + t45a)
    if heat:
        q_hpt = d.ha_hpt * xp.abs(w4 / d.w4) ** 0.8 * (t_gas_hpt - op.tm_hpt)
        t45 = temperature_from_enthalpy(enthalpy(t45a, far) - q_hpt / w4, far, xp)
    else:
        q_hpt = xp.zeros_like(t45a)
        t45 = t45a
    p45 = p4 / pr_hpt
    # LPT.
    pr_lpt = z[4] * d.lpt.pr_design
    n_lpt = op.nf / xp.sqrt(t45 / d.t45) / d.nf
    wc45, eff_lpt = turbine(d.lpt, n_lpt, pr_lpt, 1.0 + hs[9], 1.0 + hs[8], xp)
    w45_map = physical_flow(wc45, t45, p45, xp)
    t5, dh_lpt = expansion(t45, pr_lpt, eff_lpt, far, xp)
    p5 = p45 / pr_lpt
    # Core nozzle.
    w8, fg_core = nozzle(p5, t5, pamb, d.a_core, far, xp)

    res = [
        (w18 - w_byp) / d.w_byp,
        (w_hpc - w25) / d.w25,
        (w4_map - w4) / d.w4,
        (w45_map - w4) / d.w4,
        (w8 - w4) / d.w4,
    ]
    p_fan, p_lpc, p_hpc = w2 * dh_fan, w_core * dh_lpc, w25 * dh_hpc
    p_hpt, p_lpt = w4 * dh_hpt, w4 * dh_lpt
    lp_surplus = d.eta_mech * p_lpt - p_fan - p_lpc
    hp_surplus = d.eta_mech * p_hpt - p_hpc
    # What a transient step needs: the state derivatives and the sensors the
    # controller reads besides the spool speeds.
    dynamics = dict(
        dnf=lp_surplus / (d.j_lp * _RPM2 * op.nf),
        dnc=hp_surplus / (d.j_hp * _RPM2 * op.nc),
        dtm_hpc=q_hpc / d.mc_hpc * RANKINE,
        dtm_hpt=q_hpt / d.mc_hpt * RANKINE,
        t24=t24,
        ps30=static_pressure(p3, t3, w25, d.a_30, xp),
    )
    if not stations:
        return res, dynamics
    st = dict(
        t2=t2, p2=p2, p_amb=pamb, v0=fc.v0, w2=w2, t13=t13, p13=p13, p15=p15,
        w_core=w_core, w_byp=w_byp, w18=w18, p24=p24, w_vbv=w_vbv, w25=w25,
        w_hpc=w_hpc, t3=t3, t3_adiabatic=t3a, p3=p3, q_hpc=q_hpc, t4=t4, p4=p4, far=far,
        wf=wf, w4=w4, t45=t45, t45_adiabatic=t45a, p45=p45, q_hpt=q_hpt, t5=t5, p5=p5,
        w8=w8, fg_byp=fg_byp, fg_core=fg_core, fn=fg_byp + fg_core - w2 * fc.v0,
        vsv=vsv, vbv=vbv, vsv_cmd=vsv_cmd, vbv_cmd=vbv_cmd,
        n_fan=n_fan, n_lpc=n_lpc, n_hpc=n_hpc, n_hpt=n_hpt, n_lpt=n_lpt,
        wc2=wc2, pr_fan=pr_fan, wc21=wc21, pr_lpc=pr_lpc, wc25=wc25, pr_hpc=pr_hpc,
        eff_fan=eff_fan, eff_lpc=eff_lpc, eff_hpc=eff_hpc, eff_hpt=eff_hpt, eff_lpt=eff_lpt,
        pr_hpt=pr_hpt, pr_lpt=pr_lpt,
        # Stall lines move with the stators, not with deterioration: a flow
        # capacity loss at the same pressure ratio eats stall margin.
        sm_fan=stall_margin(d.fan, wc2, pr_fan, 1.0, xp),
        sm_lpc=stall_margin(d.lpc, wc21, pr_lpc, 1.0, xp),
        sm_hpc=stall_margin(d.hpc, wc25, pr_hpc, flow_vsv, xp),
        tm_hpc_eq=t3a, tm_hpt_eq=t_gas_hpt,
        power_fan=p_fan, power_lpc=p_lpc, power_hpc=p_hpc, power_hpt=p_hpt, power_lpt=p_lpt,
        # Spool power balances over design fan / HPC power (steady-state residuals).
        lp_balance=lp_surplus / d.power_fan,
        hp_balance=hp_surplus / d.power_hpc,
    )
    st.update(dynamics)
    return res, st


class EngineEvaluation(NamedTuple):
    """One evaluation of the model.

    xdot [B, 4] state derivatives (per second, state units); sensors [B, ny] and
    aux [B, nz] in the units of ``sensors.py``; inner [B, 5] the solved gas-path
    unknowns (pass back as ``guess`` next step); stations: every station value
    (SI) for checks; jacobian_inv [B, 5, 5] the inverse Jacobian of the gas-path
    residuals in the unknowns (pass back as ``jacobian_inv`` next step to iterate
    with it), when asked for. Arrays are 1-D / 2-D when the call was for one engine.
    """

    xdot: np.ndarray
    sensors: np.ndarray
    aux: np.ndarray
    inner: np.ndarray
    stations: dict[str, np.ndarray]
    jacobian_inv: np.ndarray | None = None


def solve_inner(
    op: Operating,
    guess: np.ndarray | None,
    d: EngineDesign,
    heat: bool = True,
    tol: float = 1e-10,
) -> np.ndarray:
    """Solve the five gas-path unknowns [B, 5]; EngineConvergenceError if any row fails."""
    b = op.nf.shape[0]
    z0 = np.broadcast_to(INNER_DESIGN if guess is None else np.asarray(guess, float), (b, 5))

    def fun(z: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return gas_path(op.take(rows), z, d, heat)[0]

    sol = newton(fun, z0, tol=tol, max_iter=40)
    if not sol.converged.all():
        bad = np.flatnonzero(~sol.converged)
        i = int(bad[0])
        k = int(np.argmax(np.abs(sol.residual[i])))
        betas = ", ".join(f"{n} {v:.2f}" for n, v in zip(INNER_NAMES, sol.x[i], strict=True))
        raise EngineConvergenceError(
            f"gas-path balance did not converge for engines {bad[:10].tolist()}; engine {i}: "
            f"{RESIDUAL_NAMES[k]} mismatch {sol.residual[i, k]:+.2e} of design flow at "
            f"{betas} (a compressor beta above 1 lies past its stall line)"
        )
    return sol.x


def outputs_from_stations(
    st: dict[str, np.ndarray], op: Operating, xp: Any = NP
) -> tuple[np.ndarray, np.ndarray]:
    """Sensors [B, 12] and aux [B, 6] in C-MAPSS units (see ``sensors.py``); lists of
    floats for one engine on the scalar path (``xp = SCALAR``)."""
    sensors = xp.stack(
        [
            op.nf, op.nc, st["t24"] * RANKINE, st["p24"] / PSI, st["t3"] * RANKINE,
            st["ps30"] / PSI, st["p3"] / PSI, st["t45"] * RANKINE, st["p5"] / PSI,
            st["t5"] * RANKINE, st["p15"] / PSI, op.wf / LBM,
        ]
    )
    aux = xp.stack(
        [
            st["fn"] / LBF, st["t4"] * RANKINE, st["sm_fan"], st["sm_lpc"], st["sm_hpc"],
            st["w_byp"] / st["w_core"],
        ]
    )
    return sensors, aux


def inner_jacobian_inv(
    op: Operating, z: np.ndarray, d: EngineDesign, heat: bool = True, eps: float = 1e-7
) -> np.ndarray:
    """Inverse Jacobian [B, 5, 5] of the gas-path residuals in the unknowns at z [B, 5].

    Forward differences, all 6 B points in one gas-path call.
    """
    b, n = z.shape
    stacked = op.take(np.tile(np.arange(b), n + 1))
    zs = np.concatenate([z] + [z + eps * np.eye(n)[j] for j in range(n)])
    r = gas_path(stacked, zs, d, heat)[0].reshape(n + 1, b, n)
    return np.linalg.inv(np.transpose((r[1:] - r[0]) / eps, (1, 2, 0)))


def _chord(
    op: Operating, z: np.ndarray, jinv: np.ndarray, d: EngineDesign, tol: float,
    max_iter: int = 6,
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Chord iterations z <- z - J^-1 r with a kept inverse Jacobian; returns z,
    converged rows [B] and the stations at the last z."""
    res, st = gas_path(op, z, d)
    for _ in range(max_iter):
        ok = np.max(np.abs(res), axis=1) <= tol
        if ok.all():
            break
        z = z - np.einsum("bij,bj->bi", jinv, res) * (~ok)[:, None]
        res, st = gas_path(op, z, d)
    return z, np.max(np.abs(res), axis=1) <= tol, st


def evaluate(
    x: np.ndarray,
    u: np.ndarray,
    env: np.ndarray,
    health: np.ndarray | None = None,
    guess: np.ndarray | None = None,
    design: EngineDesign | None = None,
    jacobian_inv: np.ndarray | None = None,
    with_jacobian: bool = False,
    tol: float = 1e-10,
) -> EngineEvaluation:
    """Derivatives and outputs at states x, inputs u, environment env, health h.

    Shapes: x [4] or [B, 4]; u [3] or [B, 3]; env [3] or [B, 3]; health [13] or
    [B, 13] (percent; None = nominal); guess [5] or [B, 5] (previous ``inner``).
    With ``jacobian_inv`` [5, 5] or [B, 5, 5] (a previous result's) the gas path
    is solved by chord iterations from ``guess`` (two or three gas-path calls
    for a 15 ms step), falling back to Newton for rows that do not converge;
    ``with_jacobian=True`` returns the inverse Jacobian at the solution.
    tol: largest relative flow mismatch accepted.
    """
    d = design or engine_design()
    x2, u2, e2, h2, single = as_batch(x, u, env, health)
    op = operating(x2, u2, e2, h2)
    b = x2.shape[0]
    jinv = None
    if jacobian_inv is not None and guess is not None:
        jinv = np.broadcast_to(np.asarray(jacobian_inv, dtype=float), (b, 5, 5))
        z0 = np.broadcast_to(np.asarray(guess, dtype=float), (b, 5))
        z, ok, st = _chord(op, z0, jinv, d, tol)
        if not ok.all():
            rows = np.flatnonzero(~ok)
            z = z.copy()
            z[rows] = solve_inner(op.take(rows), z0[rows], d, tol=tol)
            _, st = gas_path(op, z, d)
    else:
        z = solve_inner(op, guess, d, tol=tol)
        _, st = gas_path(op, z, d)
    if with_jacobian and jinv is None:
        jinv = inner_jacobian_inv(op, z, d)
    xdot = np.stack([st["dnf"], st["dnc"], st["dtm_hpc"], st["dtm_hpt"]], axis=1)
    y, aux = outputs_from_stations(st, op)
    if single:
        return EngineEvaluation(xdot[0], y[0], aux[0], z[0], {k: v[0] for k, v in st.items()},
                                None if jinv is None else jinv[0])
    return EngineEvaluation(xdot, y, aux, z, st, jinv)


def derivatives(
    x: np.ndarray,
    u: np.ndarray,
    env: np.ndarray,
    health: np.ndarray | None = None,
    guess: np.ndarray | None = None,
) -> np.ndarray:
    """State derivatives xdot [4] or [B, 4] (rpm/s, rpm/s, degR/s, degR/s)."""
    return evaluate(x, u, env, health, guess).xdot


def outputs(
    x: np.ndarray,
    u: np.ndarray,
    env: np.ndarray,
    health: np.ndarray | None = None,
    guess: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Sensors [12] or [B, 12] and aux [6] or [B, 6], names and units in ``sensors.py``."""
    ev = evaluate(x, u, env, health, guess)
    return ev.sensors, ev.aux
