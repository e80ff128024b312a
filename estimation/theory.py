"""Analytic estimation errors of the steady-state tuner filter (docs/math.md section 3).

Open-loop steady state, constant h, fleet health covariance P_h (seed 002
eq. 15-19; seed 003 "Analytical derivation of Kalman estimation error"):

    Phi      = A_xq - K C_xq A_xq
    Gamma    = (I - Phi)^-1 = (I - A_xq + K C_xq A_xq)^-1
    B_h      = [0 V*^+] Gamma K G_y - I        B_z = F_xq Gamma K G_y - G_z
    bias^2   = diag(B P_h B^T)
    P_hat    = Phi P_hat Phi^T + K R K^T       (discrete Lyapunov)
    variance = diag([0 V*^+] P_hat [0 V*^+]^T)  (F_xq in place of [0 V*^+] for z)
    SSEE     = sum(bias^2) + sum(variance)
    P_q      = [0 I_m] P_hat [0 I_m]^T

Process noise. The Lyapunov equation above (docs/math.md section 3, seed 003's
"Analytical derivation of Kalman estimation error"; seed 002 itself refers to
Simon & Garg 2010 for it) counts sensor noise only, yet the plant of seed 002
eq. 1 has process noise w ~ N(0, Q) as well. Here the project goes beyond the
seeds: with x~ = x - x_ss the plant state's fluctuation and e = x_hat - x_hat_ss
the estimate's, the filter x_hat[k] = Phi x_hat[k-1] + K y[k] and the plant give
the joint linear system (u = 0, constant h)

    [x~[k]]   [A      0  ] [x~[k-1]]   [I  ]            [0]
    [e[k] ] = [K C A  Phi] [e[k-1] ] + [K C] w[k-1]  +  [K] v[k]

whose stationary covariance Sigma solves the joint Lyapunov equation

    Sigma = Acal Sigma Acal^T + Gcal Q Gcal^T + Kcal R Kcal^T

and P_hat = Sigma_ee, the lower-right [n, n] block (exact when the plant's
process noise is the design's Q). That is the default variance
(``WITH_PROCESS_NOISE``); the seed formula stays available as
``SENSOR_NOISE_ONLY``. With Q = 0 the two agree.

``analytic_errors`` evaluates one design with scipy's Lyapunov solver;
``batched_errors`` evaluates a stack of V* matrices at once (doubling solvers)
for the tuner search. Tests compare the two.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import scipy.linalg

from estimation.kalman import dare_doubling, solve_or_nan, stein_doubling
from estimation.model import LinearModel
from estimation.reduced import ReducedModel

WITH_PROCESS_NOISE = "with_process_noise"
"""Variance from sensor and state process noise (joint Lyapunov equation; the default)."""
SENSOR_NOISE_ONLY = "sensor_noise_only"
"""Variance from sensor noise only: P_hat = Phi P_hat Phi^T + K R K^T (docs/math.md section 3)."""
VARIANCE_MODES = (WITH_PROCESS_NOISE, SENSOR_NOISE_ONLY)


def check_variance_mode(variance: str) -> str:
    if variance not in VARIANCE_MODES:
        raise ValueError(f"variance must be one of {VARIANCE_MODES}, got {variance!r}")
    return variance


def joint_system(
    A: np.ndarray, C: np.ndarray, K: np.ndarray, Phi: np.ndarray, Q: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Transition Acal and driving covariance Wcal of [x~; e], batched over leading axes.

    A [nx, nx], C [ny, nx], Q [nx, nx] of the plant; R [ny, ny]; K [..., n, ny] and
    Phi [..., n, n] of the filter. Returns Acal [..., nx + n, nx + n] and
    Wcal = Gcal Q Gcal^T + Kcal R Kcal^T (see the module docstring).
    """
    nx = A.shape[0]
    lead = Phi.shape[:-2]
    n = Phi.shape[-1]
    KC = K @ C  # [..., n, nx]
    Acal = np.zeros(lead + (nx + n, nx + n))
    Acal[..., :nx, :nx] = A
    Acal[..., nx:, :nx] = KC @ A
    Acal[..., nx:, nx:] = Phi
    KCt = np.swapaxes(KC, -1, -2)
    Wcal = np.zeros_like(Acal)
    Wcal[..., :nx, :nx] = Q
    Wcal[..., nx:, :nx] = KC @ Q
    Wcal[..., :nx, nx:] = Q @ KCt
    Wcal[..., nx:, nx:] = KC @ Q @ KCt + K @ R @ np.swapaxes(K, -1, -2)
    return Acal, 0.5 * (Wcal + np.swapaxes(Wcal, -1, -2))


def joint_covariance(
    model: LinearModel, reduced: ReducedModel, K: np.ndarray, Q: np.ndarray | None = None
) -> np.ndarray:
    """Stationary covariance Sigma [nx + n, nx + n] of the plant fluctuation x~ and the
    estimate fluctuation e (joint Lyapunov equation of the module docstring).

    Q [nx, nx]: the plant's process noise (default the design's, reduced.Q[:nx, :nx]).
    """
    nx = reduced.n_states
    Q = reduced.Q[:nx, :nx] if Q is None else np.asarray(Q, float)
    Phi = (np.eye(reduced.A.shape[0]) - K @ reduced.C) @ reduced.A
    Acal, Wcal = joint_system(np.asarray(model.A), np.asarray(model.C), K, Phi, Q, model.R)
    S = scipy.linalg.solve_discrete_lyapunov(Acal, Wcal)
    return 0.5 * (S + S.T)


class Theory(NamedTuple):
    """Analytic squared bias and variance per health parameter and per aux output.

    health_bias2, health_variance [p]; aux_bias2, aux_variance [nz];
    units: percent squared (deviations in percent of trim).
    """

    health_names: tuple[str, ...]
    health_bias2: np.ndarray
    health_variance: np.ndarray
    aux_names: tuple[str, ...]
    aux_bias2: np.ndarray
    aux_variance: np.ndarray

    @property
    def health_squared_error(self) -> np.ndarray:
        return self.health_bias2 + self.health_variance

    @property
    def aux_squared_error(self) -> np.ndarray:
        return self.aux_bias2 + self.aux_variance

    @property
    def ssee_health(self) -> float:
        return float(np.sum(self.health_squared_error))

    @property
    def ssee_aux(self) -> float:
        return float(np.sum(self.aux_squared_error))

    def to_dict(self) -> dict[str, object]:
        """JSON-ready form used in the design result (``theory``)."""
        return {
            "health": {
                "names": list(self.health_names),
                "bias2": self.health_bias2.tolist(),
                "variance": self.health_variance.tolist(),
                "squared_error": self.health_squared_error.tolist(),
            },
            "aux": {
                "names": list(self.aux_names),
                "bias2": self.aux_bias2.tolist(),
                "variance": self.aux_variance.tolist(),
                "squared_error": self.aux_squared_error.tolist(),
            },
            "ssee_health": self.ssee_health,
            "ssee_aux": self.ssee_aux,
        }


class FilterErrors(NamedTuple):
    """theory; Gamma [n, n]; P_hat [n, n] estimate covariance; P_q [m, m]."""

    theory: Theory
    Gamma: np.ndarray
    P_hat: np.ndarray
    P_q: np.ndarray


def analytic_errors(
    model: LinearModel,
    reduced: ReducedModel,
    K: np.ndarray,
    Ph: np.ndarray,
    variance: str = WITH_PROCESS_NOISE,
) -> FilterErrors:
    """Analytic bias^2, variance and P_q of one steady-state design (docs/math.md section 3).

    model gives G_y, G_z and R; reduced the matrices A_xq, C_xq, F_xq and V*^+ and the
    design's process noise Q (reduced.Q[:nx, :nx]); K [n, ny] the gain; Ph [p, p] the
    fleet health covariance. variance: ``WITH_PROCESS_NOISE`` (joint Lyapunov
    equation, module docstring) or ``SENSOR_NOISE_ONLY`` (the seeds' formula).
    """
    check_variance_mode(variance)
    n, nx = reduced.A.shape[0], reduced.n_states
    Gy, Gz = model.steady_state_gains()
    Phi = (np.eye(n) - K @ reduced.C) @ reduced.A
    I_Phi = np.eye(n) - Phi
    Gamma = np.linalg.solve(I_Phi, np.eye(n))
    X = np.linalg.solve(I_Phi, K @ Gy)  # x_hat_ss per unit h: Gamma K G_y (seed 002 eq. 18)
    if variance == WITH_PROCESS_NOISE and np.any(reduced.Q[:nx, :nx]):
        P_hat = joint_covariance(model, reduced, K)[nx:, nx:]
    else:  # seed 003: P_hat = Phi P_hat Phi^T + K R K^T
        W = K @ model.R @ K.T
        P_hat = scipy.linalg.solve_discrete_lyapunov(Phi, 0.5 * (W + W.T))
    P_hat = 0.5 * (P_hat + P_hat.T)
    S_h = reduced.health_map()
    B_h = S_h @ X - np.eye(model.n_health)
    B_z = reduced.F @ X - Gz
    theory = Theory(
        tuple(model.health_names),
        np.einsum("ij,jk,ik->i", B_h, Ph, B_h),
        np.einsum("ij,jk,ik->i", S_h, P_hat, S_h),
        tuple(model.aux_names),
        np.einsum("ij,jk,ik->i", B_z, Ph, B_z),
        np.einsum("ij,jk,ik->i", reduced.F, P_hat, reduced.F),
    )
    P_q = P_hat[nx:, nx:]
    return FilterErrors(theory, Gamma, P_hat, 0.5 * (P_q + P_q.T))


class ErrorProblem(NamedTuple):
    """Everything the analytic errors need that does not depend on V*.

    Matrices of the model, G_y [ny, p], G_z [nz, p], noise Q [nx, nx], Qh [p, p],
    R [ny, ny], Ph [p, p], objective weights on the health parameters [p] and
    aux outputs [nz]; variance: ``WITH_PROCESS_NOISE`` or ``SENSOR_NOISE_ONLY``.
    """

    A: np.ndarray
    C: np.ndarray
    L: np.ndarray
    M: np.ndarray
    F: np.ndarray
    N: np.ndarray
    Gy: np.ndarray
    Gz: np.ndarray
    Q: np.ndarray
    Qh: np.ndarray
    R: np.ndarray
    Ph: np.ndarray
    health_weights: np.ndarray
    aux_weights: np.ndarray
    variance: str = WITH_PROCESS_NOISE


def error_problem(
    model: LinearModel,
    Q: np.ndarray,
    Qh: np.ndarray,
    Ph: np.ndarray,
    health_weights: Sequence[float] | np.ndarray | None = None,
    aux_weights: Sequence[float] | np.ndarray | None = None,
    variance: str = WITH_PROCESS_NOISE,
) -> ErrorProblem:
    """Precompute the V*-independent part; default objective: unweighted health SSEE."""
    check_variance_mode(variance)
    Gy, Gz = model.steady_state_gains()
    wh = np.ones(model.n_health) if health_weights is None else np.asarray(health_weights, float)
    wz = np.zeros(model.n_aux) if aux_weights is None else np.asarray(aux_weights, float)
    if wh.shape != (model.n_health,) or wz.shape != (model.n_aux,):
        raise ValueError(
            f"objective weights: expected ({model.n_health},) health and ({model.n_aux},) aux, "
            f"found {wh.shape} and {wz.shape}"
        )
    return ErrorProblem(
        np.asarray(model.A), np.asarray(model.C), np.asarray(model.L), np.asarray(model.M),
        np.asarray(model.F), np.asarray(model.N), Gy, Gz,
        np.asarray(Q, float), np.asarray(Qh, float), model.R, np.asarray(Ph, float), wh, wz,
        variance,
    )


class BatchedErrors(NamedTuple):
    """Analytic errors of a stack of b designs.

    health_bias2, health_variance [b, p]; aux_bias2, aux_variance [b, nz];
    objective [b] = w_h . (bias2 + variance)_h + w_z . (bias2 + variance)_z (NaN
    where the design is unobservable); X [b, n, p] = Gamma K G_y;
    K [b, n, ny]; Phi [b, n, n]; P_hat [b, n, n]; vstar_pinv [b, p, m].
    """

    health_bias2: np.ndarray
    health_variance: np.ndarray
    aux_bias2: np.ndarray
    aux_variance: np.ndarray
    objective: np.ndarray
    K: np.ndarray
    Phi: np.ndarray
    P_hat: np.ndarray
    vstar_pinv: np.ndarray


def batched_errors(problem: ErrorProblem, V: np.ndarray) -> BatchedErrors:
    """Analytic errors for a stack of tuner matrices V [b, m, p] (docs/math.md section 3).

    One batched doubling DARE and Stein solve for the whole stack; no Python
    loop over designs. Designs whose tuners the sensors cannot observe in steady
    state (G_y V*^+ [ny, m] rank deficient: the PBH test at the tuners' eigenvalue
    1, which ``kalman.steady_state_gain`` refuses) are NaN and left out of the
    solves, where they would only slow the doubling of the whole stack.
    """
    V = np.asarray(V, float)
    b, m, p = V.shape
    nx = problem.A.shape[0]
    n = nx + m
    with np.errstate(all="ignore"):
        Vp = np.swapaxes(solve_or_nan(V @ np.swapaxes(V, 1, 2), V), 1, 2)  # [b, p, m]
    ok = np.all(np.isfinite(Vp), axis=(1, 2))
    if m > problem.Gy.shape[0]:
        ok[:] = False
    elif np.any(ok):
        s = np.linalg.svd(problem.Gy @ Vp[ok], compute_uv=False)
        ok[ok] = s[:, -1] > UNOBSERVABLE_RTOL * s[:, 0]
    if not np.all(ok):
        return _scatter(batched_errors(problem, V[ok]) if np.any(ok) else None, ok, m, problem)
    with np.errstate(all="ignore"):
        A = np.zeros((b, n, n))
        A[:, :nx, :nx] = problem.A
        A[:, :nx, nx:] = problem.L @ Vp
        A[:, nx:, nx:] = np.eye(m)
        C = np.concatenate([np.broadcast_to(problem.C, (b,) + problem.C.shape), problem.M @ Vp], 2)
        Fx = np.concatenate([np.broadcast_to(problem.F, (b,) + problem.F.shape), problem.N @ Vp], 2)
        Qx = np.zeros((b, n, n))
        Qx[:, :nx, :nx] = problem.Q
        Qx[:, nx:, nx:] = V @ problem.Qh @ np.swapaxes(V, 1, 2)
        P = dare_doubling(A, C, Qx, problem.R)
        Ct = np.swapaxes(C, 1, 2)
        S = C @ P @ Ct + problem.R
        K = np.swapaxes(solve_or_nan(S, C @ P), 1, 2)  # [b, n, ny]
        Phi = (np.eye(n) - K @ C) @ A
        if problem.variance == WITH_PROCESS_NOISE and np.any(problem.Q):
            Acal, Wcal = joint_system(problem.A, problem.C, K, Phi, problem.Q, problem.R)
            P_hat = stein_doubling(Acal, Wcal)[:, nx:, nx:]
        else:
            P_hat = stein_doubling(Phi, K @ problem.R @ np.swapaxes(K, 1, 2))
        X = solve_or_nan(np.eye(n) - Phi, K @ problem.Gy)  # Gamma K G_y
        B_h = Vp @ X[:, nx:, :] - np.eye(p)
        B_z = Fx @ X - problem.Gz
        bias2_h = np.einsum("bij,jk,bik->bi", B_h, problem.Ph, B_h)
        var_h = np.einsum("bij,bjk,bik->bi", Vp, P_hat[:, nx:, nx:], Vp)
        bias2_z = np.einsum("bij,jk,bik->bi", B_z, problem.Ph, B_z)
        var_z = np.einsum("bij,bjk,bik->bi", Fx, P_hat, Fx)
        obj = (bias2_h + var_h) @ problem.health_weights + (bias2_z + var_z) @ problem.aux_weights
    obj = np.where(np.isfinite(obj), obj, np.nan)
    return BatchedErrors(bias2_h, var_h, bias2_z, var_z, obj, K, Phi, P_hat, Vp)


UNOBSERVABLE_RTOL = 1e-9
"""sigma_min / sigma_max of G_y V*^+ at or below which the tuners count as unobservable."""


def _scatter(
    part: BatchedErrors | None, ok: np.ndarray, m: int, problem: ErrorProblem
) -> BatchedErrors:
    """Results of the feasible designs ``part`` placed at ``ok`` in a NaN-filled stack."""
    b = ok.shape[0]
    nx, ny = problem.A.shape[0], problem.C.shape[0]
    p, nz = problem.Gy.shape[1], problem.Gz.shape[0]
    n = nx + m
    shapes = ((p,), (p,), (nz,), (nz,), (), (n, ny), (n, n), (n, n), (p, m))
    fields = []
    for i, shape in enumerate(shapes):
        full = np.full((b,) + shape, np.nan)
        if part is not None:
            full[ok] = part[i]
        fields.append(full)
    return BatchedErrors(*fields)


def information_floor(
    gains: Sequence[np.ndarray], noise_std: Sequence[np.ndarray], prior: np.ndarray,
    records: int,
) -> np.ndarray:
    """The least 1-sigma [p] with which ``records`` snapshots at each of several operating
    points can know constant parameters (the Bayesian Cramer-Rao bound with the fleet's
    prior): each point's steady-state gain G_k [ny, p] (``LinearModel.steady_state_gains``,
    the sensors the design uses) and noise 1-sigma [ny] give the information
    G_k^T R_k^-1 G_k; ``prior`` is the fleet's covariance [p, p] of the parameters, or their
    1-sigma [p] (independent), and

        P = (records sum_k G_k^T R_k^-1 G_k + P_prior^-1)^-1,   floor = sqrt(diag P).

    A parameter whose floor stays near its prior however many records come (a direction no
    phase's sensors see apart from another, as hpc_flow from the VSV rigging on the built-in
    engine) has a level no estimator can know better: its error is each engine's own for life.
    """
    prior = np.asarray(prior, float)
    info = np.diag(1.0 / prior**2) if prior.ndim == 1 else np.linalg.inv(prior)
    for G, s in zip(gains, noise_std, strict=True):
        Gw = np.asarray(G, float) / np.asarray(s, float)[:, None]
        info = info + records * (Gw.T @ Gw)
    return np.sqrt(np.diag(np.linalg.inv(info)))
