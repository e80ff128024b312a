"""Reduced-order tuner model (docs/math.md section 2; seed 002 eq. 4-7).

A tuner vector q = V* h (q in R^m, m < p) replaces the health parameters:

    A_xq = [[A, L V*^+], [0, I_m]]     B_xq = [[B], [0]]
    C_xq = [C, M V*^+]                  F_xq = [F, N V*^+]
    Q_xq = blockdiag(Q, V* Q_h V*^T)

and h_hat = V*^+ q_hat (seed 002 eq. 11).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from estimation.errors import DimensionError
from estimation.model import LinearModel, check_shape


class ReducedModel(NamedTuple):
    """Reduced-order state-space matrices; the state is [x; q], n = nx + m.

    A [n, n], B [n, nu], C [ny, n], D [ny, nu], F [nz, n], G [nz, nu], Q [n, n],
    vstar [m, p], vstar_pinv [p, m], n_states = nx, n_tuners = m.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    F: np.ndarray
    G: np.ndarray
    Q: np.ndarray
    vstar: np.ndarray
    vstar_pinv: np.ndarray
    n_states: int
    n_tuners: int

    def health_map(self) -> np.ndarray:
        """[0 V*^+] [p, n]: h_hat = health_map @ [x_hat; q_hat]."""
        return np.hstack([np.zeros((self.vstar_pinv.shape[0], self.n_states)), self.vstar_pinv])

    def tuner_map(self) -> np.ndarray:
        """[0 I_m] [m, n]: q_hat = tuner_map @ [x_hat; q_hat]."""
        return np.hstack([np.zeros((self.n_tuners, self.n_states)), np.eye(self.n_tuners)])


def tuner_pinv(vstar: np.ndarray) -> np.ndarray:
    """V*^+ = V*^T (V* V*^T)^-1 for a full-row-rank V* [m, p] (solved, not inverted)."""
    V = np.asarray(vstar, float)
    gram = V @ V.T
    s = np.linalg.svd(V, compute_uv=False)
    if s.size == 0 or s[-1] <= 1e-10 * s[0]:
        raise DimensionError("V* must have full row rank (its tuners must be independent)")
    return np.linalg.solve(gram, V).T


def covariance(value: object, n: int, name: str) -> np.ndarray:
    """A covariance [n, n] from standard deviations [n], a scalar std, or a full matrix.

    A 1-D list is read as standard deviations (diag(std**2)), as in the design spec.
    """
    arr = np.asarray(value, float)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.ndim == 1:
        if arr.shape != (n,):
            raise DimensionError(
                f"Incompatible dimensions of {name} standard deviations; "
                f"expected ({n},) but found {arr.shape}"
            )
        if np.any(arr < 0) or not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} standard deviations must be finite and non-negative")
        return np.diag(arr**2)
    cov = check_shape(name, arr, (n, n)).copy()
    if not np.allclose(cov, cov.T, rtol=1e-10, atol=1e-14):
        raise ValueError(f"{name} covariance must be symmetric")
    cov = 0.5 * (cov + cov.T)
    if np.linalg.eigvalsh(cov)[0] < -1e-10 * max(1.0, np.abs(cov).max()):
        raise ValueError(f"{name} covariance must be positive semidefinite")
    return cov


def reduced_model(
    model: LinearModel, vstar: np.ndarray, Q: np.ndarray, Qh: np.ndarray
) -> ReducedModel:
    """Reduced-order model for tuners q = V* h (seed 002 eq. 6-7).

    model : LinearModel with p health parameters; vstar [m, p];
    Q [nx, nx] state process noise; Qh [p, p] health random-walk covariance.
    """
    p, nx, nu = model.n_health, model.n_states, model.n_inputs
    V = np.asarray(vstar, float)
    if V.ndim != 2 or V.shape[1] != p:
        raise DimensionError(
            f"Incompatible dimensions of V* matrix; expected (m, {p}) but found {V.shape}"
        )
    m = V.shape[0]
    Q = check_shape("Q", Q, (nx, nx))
    Qh = check_shape("Qh", Qh, (p, p))
    Vp = tuner_pinv(V)
    n = nx + m
    A = np.zeros((n, n))
    A[:nx, :nx] = model.A
    A[:nx, nx:] = model.L @ Vp
    A[nx:, nx:] = np.eye(m)
    B = np.vstack([model.B, np.zeros((m, nu))])
    C = np.hstack([model.C, model.M @ Vp])
    F = np.hstack([model.F, model.N @ Vp])
    Qxq = np.zeros((n, n))
    Qxq[:nx, :nx] = Q
    Qq = V @ Qh @ V.T
    Qxq[nx:, nx:] = 0.5 * (Qq + Qq.T)
    return ReducedModel(
        A, B, C, np.array(model.D), F, np.array(model.G), Qxq, V.copy(), Vp, nx, m
    )
