"""Analytic estimation errors of the steady-state tuner filter (MATH.md section 3).

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

``analytic_errors`` evaluates one design with scipy's Lyapunov solver;
``batched_errors`` evaluates a stack of V* matrices at once (doubling solvers)
for the tuner search. Tests compare the two.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import scipy.linalg

from estimation.kalman import dare_doubling, stein_doubling
from estimation.model import LinearModel
from estimation.reduced import ReducedModel


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
    model: LinearModel, reduced: ReducedModel, K: np.ndarray, Ph: np.ndarray
) -> FilterErrors:
    """Analytic bias^2, variance and P_q of one steady-state design (MATH.md section 3).

    model gives G_y, G_z and R; reduced the matrices A_xq, C_xq, F_xq and V*^+;
    K [n, ny] the gain; Ph [p, p] the fleet health covariance.
    """
    n, nx = reduced.A.shape[0], reduced.n_states
    Gy, Gz = model.steady_state_gains()
    Phi = (np.eye(n) - K @ reduced.C) @ reduced.A
    I_Phi = np.eye(n) - Phi
    Gamma = np.linalg.solve(I_Phi, np.eye(n))
    X = np.linalg.solve(I_Phi, K @ Gy)  # x_hat_ss per unit h: Gamma K G_y (seed 002 eq. 18)
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
    aux outputs [nz]; optional fault influence data for the diagnostics-aware
    objective: Gy_full [ny, p_full] and signatures S [p_full, n_faults].
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


def error_problem(
    model: LinearModel,
    Q: np.ndarray,
    Qh: np.ndarray,
    Ph: np.ndarray,
    health_weights: Sequence[float] | np.ndarray | None = None,
    aux_weights: Sequence[float] | np.ndarray | None = None,
) -> ErrorProblem:
    """Precompute the V*-independent part; default objective: unweighted health SSEE."""
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
    """Analytic errors for a stack of tuner matrices V [b, m, p] (MATH.md section 3).

    One batched doubling DARE and Stein solve for the whole stack; no Python
    loop over designs.
    """
    V = np.asarray(V, float)
    b, m, p = V.shape
    nx = problem.A.shape[0]
    n = nx + m
    with np.errstate(all="ignore"):
        Vp = np.swapaxes(np.linalg.solve(V @ np.swapaxes(V, 1, 2), V), 1, 2)  # [b, p, m]
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
        K = np.swapaxes(np.linalg.solve(S, C @ P), 1, 2)  # [b, n, ny]
        Phi = (np.eye(n) - K @ C) @ A
        P_hat = stein_doubling(Phi, K @ problem.R @ np.swapaxes(K, 1, 2))
        X = np.linalg.solve(np.eye(n) - Phi, K @ problem.Gy)  # Gamma K G_y
        B_h = Vp @ X[:, nx:, :] - np.eye(p)
        B_z = Fx @ X - problem.Gz
        bias2_h = np.einsum("bij,jk,bik->bi", B_h, problem.Ph, B_h)
        var_h = np.einsum("bij,bjk,bik->bi", Vp, P_hat[:, nx:, nx:], Vp)
        bias2_z = np.einsum("bij,jk,bik->bi", B_z, problem.Ph, B_z)
        var_z = np.einsum("bij,bjk,bik->bi", Fx, P_hat, Fx)
        obj = (bias2_h + var_h) @ problem.health_weights + (bias2_z + var_z) @ problem.aux_weights
    obj = np.where(np.isfinite(obj), obj, np.nan)
    return BatchedErrors(bias2_h, var_h, bias2_z, var_z, obj, K, Phi, P_hat, Vp)
