"""Steady-state operating points over the envelope.

At steady state the spool power balances close (dNf/dt = dNc/dt = 0), the metal
temperatures equal the gas temperatures (no heat flow), VSV and VBV sit on their
nominal schedules, and the five gas-path flow matches hold. With a power setting
the fan speed is fixed by the demanded corrected fan speed and the unknowns are
the five gas-path unknowns, Nc and Wf; with a fuel flow they are the five, Nf
and Nc. Both are solved by batched Newton (``newton.py``), started from a
corrected-parameter guess (the sea-level line scaled by theta and delta) and, for
rows that still fail, by continuation from sea-level static in steps. A row
that does not converge raises EngineConvergenceError; an operating condition
outside the envelope raises EnvelopeError. Never a silent wrong answer.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from estimation.engine.actuators import demanded_corrected_fan_speed
from estimation.engine.atmosphere import LBM, RANKINE, flight_condition
from estimation.engine.design import EngineDesign, engine_design
from estimation.engine.errors import EngineConvergenceError, EnvelopeError
from estimation.engine.health import N_HEALTH
from estimation.engine.newton import newton
from estimation.engine.turbofan import (
    INNER_DESIGN,
    Operating,
    gas_path,
    outputs_from_stations,
)

# Envelope: altitude [ft], Mach, power [%], dTamb [K].
ENVELOPE = {"alt": (0.0, 40000.0), "mach": (0.0, 0.85), "power": (0.0, 100.0),
            "dtamb": (-40.0, 40.0)}
_TOL = {"alt": 100.0, "mach": 0.005, "power": 0.5, "dtamb": 0.5}


class SteadyState(NamedTuple):
    """A converged operating point (arrays over the batch, or 1-D for one engine).

    x [4] states (Nf, Nc rpm; TMHPC, TMHPT degR), u [3] commands (Wf pps, VSV %,
    VBV %), env [3], health [13], inner [5] gas-path unknowns, sensors [12] and
    aux [6] (names and units in ``sensors.py``), stations (SI values),
    power [%] (NaN when solved for a fuel flow).
    """

    x: np.ndarray
    u: np.ndarray
    env: np.ndarray
    health: np.ndarray
    inner: np.ndarray
    sensors: np.ndarray
    aux: np.ndarray
    stations: dict[str, np.ndarray]
    power: np.ndarray


def check_envelope(env: np.ndarray, power: np.ndarray | None = None) -> None:
    """Raise EnvelopeError naming the first row and quantity outside the envelope."""
    cols = {"alt": env[:, 0], "mach": env[:, 1], "dtamb": env[:, 2]}
    if power is not None:
        cols["power"] = power
    for name, vals in cols.items():
        lo, hi = ENVELOPE[name]
        bad = np.flatnonzero(~((vals >= lo - _TOL[name]) & (vals <= hi + _TOL[name])))
        if bad.size:
            i = int(bad[0])
            raise EnvelopeError(
                f"{name} = {vals[i]:g} (row {i}) is outside the envelope [{lo:g}, {hi:g}]"
            )


def _operating(
    fc_rows: tuple[np.ndarray, ...], h: np.ndarray, nf: np.ndarray, nc: np.ndarray,
    wf: np.ndarray,
) -> Operating:
    from estimation.engine.atmosphere import FlightCondition

    zero = np.zeros_like(nf)
    return Operating(nf, nc, zero + 300.0, zero + 300.0, wf, zero, zero,
                     FlightCondition(*fc_rows), h)


def _solve(
    env: np.ndarray, h: np.ndarray, mode: str, target: np.ndarray, v0: np.ndarray,
    d: EngineDesign, tol: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Newton on v = [z (5), a, b] with a, b = (Nc, Wf) or (Nf, Nc) over design."""
    fc = flight_condition(env[:, 0], env[:, 1], env[:, 2])

    def split(v: np.ndarray, rows: np.ndarray) -> Operating:
        fcr = tuple(a[rows] for a in fc)
        if mode == "power":
            nf = target[rows] * np.sqrt(fcr[5])
            return _operating(fcr, h[rows], nf, v[:, 5] * d.nc, v[:, 6] * d.wf)
        return _operating(fcr, h[rows], v[:, 5] * d.nf, v[:, 6] * d.nc, target[rows])

    def fun(v: np.ndarray, rows: np.ndarray) -> np.ndarray:
        res, st = gas_path(split(v, rows), v[:, :5], d, heat=False, scheduled_actuators=True)
        return np.concatenate([res, st["lp_balance"][:, None], st["hp_balance"][:, None]], 1)

    sol = newton(fun, v0, tol=tol, max_iter=30, max_step=0.25)
    return sol.x, sol.converged


@lru_cache(maxsize=1)
def _sea_level_line() -> tuple[np.ndarray, np.ndarray]:
    """Converged sea-level static points from take-off down to idle (by continuation).

    Returns corrected fan speed over design [K] and corrected unknowns [K, 7]:
    z, Nc / sqrt(theta2) / Nc_d, Wf / (delta2 sqrt(theta2)) / Wf_d.
    """
    d = engine_design()
    powers = np.linspace(100.0, 0.0, 41)
    env = np.zeros((1, 3))
    h = np.zeros((1, N_HEALTH))
    v = np.concatenate([INNER_DESIGN, [1.0, 1.0]])[None]
    fc = flight_condition(0.0, 0.0)
    line = []
    for p in powers:
        nrf = demanded_corrected_fan_speed(np.array([p]), d.nf)
        v, ok = _solve(env, h, "power", nrf, v, d, 1e-10)
        if not ok.all():
            raise EngineConvergenceError(f"sea-level line did not converge at power {p:g} %")
        vc = v[0].copy()
        vc[5] /= np.sqrt(fc.theta)
        vc[6] /= fc.delta * np.sqrt(fc.theta)
        line.append(vc)
    nrf_rel = demanded_corrected_fan_speed(powers, d.nf) / d.nf
    return nrf_rel[::-1], np.array(line)[::-1]


def _guess(nrf_rel: np.ndarray, env: np.ndarray, d: EngineDesign) -> np.ndarray:
    """Corrected-parameter guess [B, 7] (power mode layout) from the sea-level line."""
    grid, line = _sea_level_line()
    fc = flight_condition(env[:, 0], env[:, 1], env[:, 2])
    g = np.stack([np.interp(nrf_rel, grid, line[:, j]) for j in range(7)], axis=1)
    g[:, 5] *= np.sqrt(fc.theta)
    g[:, 6] *= fc.delta * np.sqrt(fc.theta)
    return g


def steady_state(
    env: np.ndarray,
    power: np.ndarray | float | None = None,
    wf: np.ndarray | float | None = None,
    health: np.ndarray | None = None,
    tol: float = 1e-10,
    design: EngineDesign | None = None,
) -> SteadyState:
    """Steady operating point(s) at env [3] or [B, 3] for a power setting or a fuel flow.

    power: percent, 0 ground idle .. 100 take-off (corrected fan speed demand);
    wf: fuel flow [pps] instead of power. health: [13] or [B, 13] percent.
    """
    d = design or engine_design()
    if (power is None) == (wf is None):
        raise ValueError("give exactly one of power and wf")
    env_a = np.asarray(env, dtype=float)
    h_a = np.zeros(N_HEALTH) if health is None else np.asarray(health, dtype=float)
    given = np.asarray(power if power is not None else wf, dtype=float)
    single = env_a.ndim == 1 and h_a.ndim == 1 and given.ndim == 0
    if env_a.shape[-1] != 3:
        raise ValueError(f"env must have shape (3,) or (B, 3), found {env_a.shape}")
    if h_a.shape[-1] != N_HEALTH:
        raise ValueError(
            f"health must have shape ({N_HEALTH},) or (B, {N_HEALTH}), found {h_a.shape}"
        )
    b = max(np.atleast_2d(env_a).shape[0], np.atleast_2d(h_a).shape[0], given.size)
    env2 = np.broadcast_to(np.atleast_2d(env_a), (b, 3)).copy()
    h2 = np.broadcast_to(np.atleast_2d(h_a), (b, N_HEALTH)).copy()
    given = np.broadcast_to(given.ravel() if given.ndim else given, (b,)).copy()
    if not (np.isfinite(env2).all() and np.isfinite(given).all() and np.isfinite(h2).all()):
        raise ValueError("operating condition, power/fuel flow and health must be finite")
    check_envelope(env2, given if power is not None else None)
    if power is not None:
        target = demanded_corrected_fan_speed(given, d.nf, env2[:, 1])
        v, ok = _solve(env2, h2, "power", target, _guess(target / d.nf, env2, d), d, tol)
        mode = "power"
    else:
        if np.any(given <= 0):
            raise EnvelopeError("fuel flow must be positive")
        target = given * LBM
        # Guess: the power-mode guess whose corrected fuel flow is nearest.
        grid, line = _sea_level_line()
        fc = flight_condition(env2[:, 0], env2[:, 1], env2[:, 2])
        wfc = target / (fc.delta * np.sqrt(fc.theta)) / d.wf
        nrf_rel = np.interp(wfc, line[:, 6], grid)
        g = _guess(nrf_rel, env2, d)
        v0 = np.concatenate([g[:, :5], (nrf_rel * np.sqrt(fc.theta))[:, None], g[:, 5:6]], 1)
        v, ok = _solve(env2, h2, "wf", target, v0, d, tol)
        mode = "wf"
    if not ok.all():
        v, ok = _continuation(env2, h2, mode, target, v, ok, d, tol)
    if not ok.all():
        bad = np.flatnonzero(~ok)
        i = int(bad[0])
        raise EngineConvergenceError(
            f"steady state did not converge for {bad.size} of {b} points, first at "
            f"alt {env2[i, 0]:g} ft, Mach {env2[i, 1]:g}, dTamb {env2[i, 2]:g} K, "
            f"{mode} {given[i]:g}"
        )
    return _result(env2, h2, mode, target, v, given if power is not None else None, d, single)


def _continuation(
    env: np.ndarray, h: np.ndarray, mode: str, target: np.ndarray, v: np.ndarray,
    ok: np.ndarray, d: EngineDesign, tol: float, steps: int = 12,
) -> tuple[np.ndarray, np.ndarray]:
    """Retry failed rows by walking from sea-level static, nominal health, in steps."""
    bad = np.flatnonzero(~ok)
    v, ok = v.copy(), ok.copy()
    for i in bad:
        e_end, h_end = env[i], h[i]
        e_start = np.array([0.0, 0.0, 0.0])
        t = target[i : i + 1]
        if mode == "power":
            vi = _guess(t / d.nf, e_start[None], d)
        else:
            vi = v[i : i + 1].copy()
        good = True
        for s in np.linspace(0.0, 1.0, steps + 1):
            ei = (e_start + s * (e_end - e_start))[None]
            vi_new, oki = _solve(ei, (s * h_end)[None], mode, t, vi, d, tol)
            if not oki.all():
                good = False
                break
            vi = vi_new
        if good:
            v[i], ok[i] = vi[0], True
    return v, ok


def _result(
    env: np.ndarray, h: np.ndarray, mode: str, target: np.ndarray, v: np.ndarray,
    power: np.ndarray | None, d: EngineDesign, single: bool,
) -> SteadyState:
    fc = flight_condition(env[:, 0], env[:, 1], env[:, 2])
    if mode == "power":
        nf, nc, wf = target * np.sqrt(fc.theta), v[:, 5] * d.nc, v[:, 6] * d.wf
    else:
        nf, nc, wf = v[:, 5] * d.nf, v[:, 6] * d.nc, target
    op = _operating(tuple(fc), h, nf, nc, wf)
    _, st = gas_path(op, v[:, :5], d, heat=False, scheduled_actuators=True)
    x = np.stack([nf, nc, st["tm_hpc_eq"] * RANKINE, st["tm_hpt_eq"] * RANKINE], axis=1)
    u = np.stack([wf / LBM, st["vsv_cmd"], st["vbv_cmd"]], axis=1)
    op = op._replace(vsv=u[:, 1], vbv=u[:, 2])
    y, aux = outputs_from_stations(st, op)
    p = np.full(len(nf), np.nan) if power is None else power
    if single:
        return SteadyState(x[0], u[0], env[0], h[0], v[0, :5], y[0], aux[0],
                           {k: val[0] for k, val in st.items()}, p[0])
    return SteadyState(x, u, env, h, v[:, :5], y, aux, st, p)
