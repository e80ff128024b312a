"""Linear models of the engine at an operating point (docs/math.md section 1).

Around a steady state (x0, u0, h0) the nonlinear model (``turbofan.evaluate``,
heat flows included) is differentiated by central differences in every state,
input and health parameter, all scaled to percent of trim:

    d(x%)/dt = Ac x% + Bc u% + Lc h          y% = C x% + D u% + M h
                                             z% = F x% + G u% + N h

with x% = 100 (x - x0) / x0 (likewise u, y, z; h is already percent). Each
Jacobian is taken with steps s and s/2 (all 2 (nx + nu + np) perturbed points in
one batched evaluation) and Richardson-extrapolated, J = (4 J(s/2) - J(s)) / 3;
the two estimates must agree (``step_check``), else a smaller step is tried and
EngineConvergenceError is raised if none agrees. The continuous model is then
discretised with a zero-order hold over dt,

    [A  B  L]        ( [Ac Bc Lc]      )
    [0  I  0] = expm ( [ 0  0  0 ] dt  ),
    [0  0  I]        ( [ 0  0  0]      )

and returned as ``estimation.model.LinearModel``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.linalg import expm

from estimation.engine.errors import EngineConvergenceError
from estimation.engine.health import HEALTH_NAMES, HEALTH_UNITS
from estimation.engine.sensors import (
    AUX_NAMES,
    AUX_UNITS,
    SENSOR_NAMES,
    SENSOR_UNITS,
    noise_std_percent,
)
from estimation.engine.steady import SteadyState, steady_state
from estimation.engine.turbofan import (
    INPUT_NAMES,
    INPUT_UNITS,
    STATE_NAMES,
    STATE_UNITS,
    evaluate,
)
from estimation.model import LinearModel, Signal

DEFAULT_DT = 0.015  # s, seed 002's update rate


class ContinuousModel(NamedTuple):
    """Continuous-time Jacobians in percent of trim (Ac [4,4], Bc [4,3], Lc [4,13];
    C [12,4], D [12,3], M [12,13]; F [6,4], G [6,3], N [6,13]) and the largest
    relative disagreement between the step-s and step-s/2 estimates."""

    Ac: np.ndarray
    Bc: np.ndarray
    Lc: np.ndarray
    C: np.ndarray
    D: np.ndarray
    M: np.ndarray
    F: np.ndarray
    G: np.ndarray
    N: np.ndarray
    step: float
    step_check: float


def _jacobian(trim: SteadyState, step: float) -> tuple[np.ndarray, int, float]:
    """Richardson Jacobian [out, 20] of [xdot%, y%, z%] in [x%, u%, h] and the step check."""
    nx, nu, nh = 4, 3, len(HEALTH_NAMES)
    n = nx + nu + nh
    base = np.concatenate([trim.x, trim.u, trim.health])
    scale = np.concatenate([trim.x / 100.0, trim.u / 100.0, np.ones(nh)])
    pts = []
    for s in (step, step / 2.0):
        for sign in (1.0, -1.0):
            pts.append(base + sign * s * np.diag(scale))
    p = np.concatenate(pts, axis=0)  # [4 n, n]
    ev = evaluate(p[:, :nx], p[:, nx:nx + nu], trim.env, p[:, nx + nu:], guess=trim.inner)
    out = np.concatenate(
        [
            100.0 * ev.xdot / trim.x,
            100.0 * (ev.sensors - trim.sensors) / trim.sensors,
            100.0 * (ev.aux - trim.aux) / trim.aux,
        ],
        axis=1,
    ).reshape(4, n, -1)
    j1 = ((out[0] - out[1]) / (2.0 * step)).T
    j2 = ((out[2] - out[3]) / step).T
    # Disagreement of the two steps, relative to each output row's largest entry.
    row = np.maximum(np.max(np.abs(j2), axis=1, keepdims=True), 1e-12)
    check = float(np.max(np.abs(j2 - j1) / row))
    return (4.0 * j2 - j1) / 3.0, out.shape[-1], check


def continuous_model(
    trim: SteadyState, step: float = 0.5, tolerance: float = 0.02
) -> ContinuousModel:
    """Continuous Jacobians at a steady state, with a checked step (percent of trim).

    Tries ``step``, then step / 4 and step / 16; the first whose s and s/2
    estimates agree within ``tolerance`` (relative to each row's largest entry) is used.
    """
    if np.ndim(trim.x) != 1:
        raise ValueError("linearise one operating point at a time (trim.x must be 1-D)")
    if np.any(np.abs(np.concatenate([trim.x, trim.u, trim.sensors, trim.aux])) < 1e-9):
        raise EngineConvergenceError(
            "a trim value is zero at this point; percent-of-trim deviations are undefined"
        )
    best = None
    for s in (step, step / 4.0, step / 16.0):
        jac, _, check = _jacobian(trim, s)
        if best is None or check < best[2]:
            best = (jac, s, check)
        if check <= tolerance:
            break
    assert best is not None
    jac, s, check = best
    if check > tolerance:
        raise EngineConvergenceError(
            f"finite-difference Jacobian not consistent between steps (worst {check:.3g})"
        )
    nx, nu = 4, 3
    ny = len(SENSOR_NAMES)
    dx = jac[:nx]
    dy = jac[nx:nx + ny]
    dz = jac[nx + ny:]
    cu = slice(nx, nx + nu)
    ch = slice(nx + nu, None)
    return ContinuousModel(
        dx[:, :nx], dx[:, cu], dx[:, ch], dy[:, :nx], dy[:, cu], dy[:, ch],
        dz[:, :nx], dz[:, cu], dz[:, ch], s, check,
    )


def discretise(
    Ac: np.ndarray, Bc: np.ndarray, Lc: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation of x' = Ac x + Bc u + Lc h over dt."""
    nx, nu = Bc.shape
    nh = Lc.shape[1]
    big = np.zeros((nx + nu + nh, nx + nu + nh))
    big[:nx, :nx] = Ac
    big[:nx, nx:nx + nu] = Bc
    big[:nx, nx + nu:] = Lc
    e = expm(big * dt)
    return e[:nx, :nx], e[:nx, nx:nx + nu], e[:nx, nx + nu:]


def linear_model_at(
    trim: SteadyState, dt: float = DEFAULT_DT, step: float = 0.5
) -> LinearModel:
    """The discrete LinearModel at a computed steady state ``trim``."""
    cm = continuous_model(trim, step)
    A, B, L = discretise(cm.Ac, cm.Bc, cm.Lc, dt)
    trims: dict[str, float] = {}
    for names, values in ((STATE_NAMES, trim.x), (INPUT_NAMES, trim.u),
                          (SENSOR_NAMES, trim.sensors), (AUX_NAMES, trim.aux)):
        for n, v in zip(names, values, strict=True):
            trims[n] = float(v)
    cond = {
        "alt_ft": float(trim.env[0]), "mach": float(trim.env[1]), "dtamb_K": float(trim.env[2]),
        "jacobian_step_pct": cm.step, "jacobian_step_check": cm.step_check,
    }
    # A point trimmed for a fuel flow has no power setting; JSON has no NaN.
    if np.isfinite(trim.power):
        cond["power_pct"] = float(trim.power)
    else:
        cond["wf_pps"] = float(trim.u[0])
    return LinearModel(
        dt=dt,
        states=tuple(Signal(n, u) for n, u in zip(STATE_NAMES, STATE_UNITS, strict=True)),
        inputs=tuple(Signal(n, u) for n, u in zip(INPUT_NAMES, INPUT_UNITS, strict=True)),
        health=tuple(Signal(n, u) for n, u in zip(HEALTH_NAMES, HEALTH_UNITS, strict=True)),
        sensors=tuple(Signal(n, u) for n, u in zip(SENSOR_NAMES, SENSOR_UNITS, strict=True)),
        aux=tuple(Signal(n, u) for n, u in zip(AUX_NAMES, AUX_UNITS, strict=True)),
        A=A, B=B, C=cm.C, D=cm.D, L=L, M=cm.M, F=cm.F, G=cm.G, N=cm.N,
        trim=trims,
        sensor_noise_std=noise_std_percent(),
        operating_condition=cond,
    )


def linearize(
    alt: float,
    mach: float,
    power: float,
    dtamb: float = 0.0,
    health: np.ndarray | None = None,
    dt: float = DEFAULT_DT,
) -> LinearModel:
    """Steady state at (alt ft, Mach, power %, dTamb K, health) and its LinearModel."""
    trim = steady_state(np.array([alt, mach, dtamb], dtype=float), power=power, health=health)
    return linear_model_at(trim, dt)
