"""Steady-state Kalman gain and the batched stream filter (docs/math.md section 3).

    P_inf = DARE(A^T, C^T, Q, R)                 (a-priori covariance)
    K     = P_inf C^T (C P_inf C^T + R)^-1
    x_hat[k] = A x_hat[k-1] + K (y[k] - C A x_hat[k-1])           (u = 0)

``steady_state_gain`` uses scipy's Schur-method DARE and then checks what
scipy does not: that (A, C) is detectable and that the error dynamics
(I - K C) A are stable. ``dare_doubling`` is a batched structure-preserving
doubling solver used where many small designs are evaluated at once (the
tuner search); ``stein_doubling`` likewise for X = Phi X Phi^T + W.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.linalg

from estimation.errors import DimensionError, UnobservableDesignError
from estimation.model import check_shape
from estimation.reduced import ReducedModel

__all__ = [
    "SteadyStateGain",
    "StreamEstimate",
    "steady_state_gain",
    "unobservable_modes",
    "dare_doubling",
    "stein_doubling",
    "solve_or_nan",
    "filter_stream",
    "filter_stream_states",
    "stream_input_terms",
]


class SteadyStateGain(NamedTuple):
    """K [n, ny]; P_prior [n, n] a-priori covariance; P_post = (I - K C) P_prior;
    spectral_radius of the error dynamics (I - K C) A (< 1)."""

    K: np.ndarray
    P_prior: np.ndarray
    P_post: np.ndarray
    spectral_radius: float


def unobservable_modes(A: np.ndarray, C: np.ndarray, rtol: float = 1e-9) -> list[complex]:
    """Eigenvalues of A on or outside the unit circle that C cannot see (PBH test).

    (A, C) is detectable iff the list is empty: rank [lambda I - A; C] = n for
    every eigenvalue |lambda| >= 1.
    """
    n = A.shape[0]
    scale = max(1.0, float(np.abs(A).max()), float(np.abs(C).max()) if C.size else 1.0)
    bad: list[complex] = []
    for lam in np.linalg.eigvals(A):
        if abs(lam) < 1.0 - 1e-9:
            continue
        pbh = np.vstack([lam * np.eye(n) - A, C.astype(complex)])
        s = np.linalg.svd(pbh, compute_uv=False)
        if s[-1] <= rtol * scale:
            bad.append(complex(lam))
    return bad


def steady_state_gain(
    A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray
) -> SteadyStateGain:
    """Steady-state Kalman gain of x[k+1] = A x + w, y = C x + v (docs/math.md section 3).

    A [n, n], C [ny, n], Q [n, n], R [ny, ny] (positive definite).
    Raises UnobservableDesignError if (A, C) is not detectable (more tuners than
    the sensors can separate) or if the Riccati solution is not stabilising
    (for example a tuner that Q does not excite).
    """
    n = np.shape(A)[0]
    A = check_shape("A", A, (n, n))
    if np.ndim(C) != 2:
        raise DimensionError(f"C must be a matrix [ny, {n}], found shape {np.shape(C)}")
    ny = np.shape(C)[0]
    C = check_shape("C", C, (ny, n))
    Q = check_shape("Q", Q, (n, n))
    R = check_shape("R", R, (ny, ny))
    if np.linalg.eigvalsh(0.5 * (R + R.T))[0] <= 0:
        raise ValueError("R must be positive definite")
    bad = unobservable_modes(A, C)
    if bad:
        raise UnobservableDesignError(
            f"the sensors cannot observe {len(bad)} mode(s) of the reduced model "
            f"(eigenvalues {[round(b.real, 6) for b in bad]}): use fewer tuners "
            "or more sensors"
        )
    try:
        P = scipy.linalg.solve_discrete_are(A.T, C.T, Q, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise UnobservableDesignError(f"no stabilising Riccati solution: {exc}") from exc
    P = 0.5 * (P + P.T)
    S = C @ P @ C.T + R
    K = np.linalg.solve(S, C @ P).T  # K = P C^T S^-1, S symmetric
    closed = (np.eye(n) - K @ C) @ A
    rho = float(np.max(np.abs(np.linalg.eigvals(closed))))
    if not np.all(np.isfinite(P)) or rho >= 1.0 - 1e-12:
        raise UnobservableDesignError(
            f"the Riccati solution is not stabilising (spectral radius {rho:.6g} of (I-KC)A): "
            "every tuner needs random-walk noise (Qh) and must be observable"
        )
    if np.linalg.eigvalsh(P)[0] < -1e-8 * max(1.0, np.abs(P).max()):
        raise UnobservableDesignError("the Riccati solution is not positive semidefinite")
    P_post = (np.eye(n) - K @ C) @ P
    return SteadyStateGain(K, P, 0.5 * (P_post + P_post.T), rho)


def solve_or_nan(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched np.linalg.solve(a, b) (a [..., n, n], b [..., n, k]) that gives NaN for the
    batch elements whose a is singular instead of raising for the whole batch.

    LAPACK stops at an exactly singular pivot; a batch of candidate designs may hold
    one (an unexcited, unobserved tuner leaves I - Phi singular), and that design
    alone is infeasible. The whole batch is tried first; only on failure is it
    solved element by element.
    """
    try:
        return np.linalg.solve(a, b)
    except np.linalg.LinAlgError:
        pass
    lead = np.broadcast_shapes(a.shape[:-2], b.shape[:-2])
    a_b = np.broadcast_to(a, lead + a.shape[-2:])
    b_b = np.broadcast_to(b, lead + b.shape[-2:])
    out = np.full(lead + b.shape[-2:], np.nan)
    for idx in np.ndindex(*lead):
        try:
            out[idx] = np.linalg.solve(a_b[idx], b_b[idx])
        except np.linalg.LinAlgError:
            continue
    return out


def _sym(X: np.ndarray) -> np.ndarray:
    return 0.5 * (X + np.swapaxes(X, -1, -2))


def dare_doubling(
    A: np.ndarray,
    C: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    tol: float = 1e-13,
    max_iter: int = 80,
) -> np.ndarray:
    """Batched filtering DARE by structure-preserving doubling.

    Solves P = A P A^T - A P C^T (C P C^T + R)^-1 C P A^T + Q for every batch
    element: A [..., n, n], C [..., ny, n], Q [..., n, n], R [..., ny, ny].
    Returns P [..., n, n]; elements that did not converge (undetectable or
    unstabilisable designs) are NaN. The doubling converges quadratically in
    the closed-loop spectral radius (rho^(2^k)).

    SDA with a0 = A^T, g0 = C^T R^-1 C, h0 = Q:
        a' = a (I + g h)^-1 a,  g' = g + a (I + g h)^-1 g a^T,  h' = h + a^T h (I + g h)^-1 a
    """
    a = np.swapaxes(np.asarray(A, float), -1, -2).copy()
    C = np.asarray(C, float)
    g = np.swapaxes(C, -1, -2) @ np.linalg.solve(R, C)
    h = np.array(np.broadcast_to(Q, a.shape), dtype=float)
    g = np.array(np.broadcast_to(g, a.shape), dtype=float)
    n = a.shape[-1]
    eye = np.eye(n)
    done = np.zeros(a.shape[:-2], dtype=bool)
    for _ in range(max_iter):
        igh = eye + g @ h
        z = solve_or_nan(igh, np.concatenate([a, g], axis=-1))
        za, zg = z[..., :n], z[..., n:]
        a_t = np.swapaxes(a, -1, -2)
        h_new = _sym(h + a_t @ h @ za)
        g = _sym(g + a @ zg @ a_t)
        a = a @ za
        step = np.max(np.abs(h_new - h), axis=(-1, -2))
        size = np.max(np.abs(h_new), axis=(-1, -2))
        h = h_new
        with np.errstate(invalid="ignore"):
            done = step <= tol * np.maximum(size, 1e-300)
        if np.all(done):
            break
    h[~(done & np.all(np.isfinite(h), axis=(-1, -2)))] = np.nan
    return h


def stein_doubling(
    Phi: np.ndarray, W: np.ndarray, tol: float = 1e-14, max_iter: int = 80
) -> np.ndarray:
    """Batched discrete Lyapunov (Stein) equation X = Phi X Phi^T + W by doubling.

    Phi [..., n, n] stable, W [..., n, n] symmetric. X = sum_k Phi^k W Phi^kT,
    summed as X_{j+1} = X_j + Phi_j X_j Phi_j^T, Phi_{j+1} = Phi_j^2.
    Elements that do not converge (unstable Phi) are NaN.
    """
    X = np.array(W, dtype=float)
    F = np.array(Phi, dtype=float)
    done = np.zeros(X.shape[:-2], dtype=bool)
    for _ in range(max_iter):
        X = _sym(X + F @ X @ np.swapaxes(F, -1, -2))
        F = F @ F
        with np.errstate(invalid="ignore", over="ignore"):
            done = np.max(np.abs(F), axis=(-1, -2)) <= tol
        if np.all(done):
            break
    X[~(done & np.all(np.isfinite(X), axis=(-1, -2)))] = np.nan
    return X


class StreamEstimate(NamedTuple):
    """Batched stream filter output, time-major.

    x_hat [n_steps, n_engines, n] reduced state [x; q]; q_hat [n_steps, n_engines, m];
    h_hat [n_steps, n_engines, p]; z_hat [n_steps, n_engines, nz] (F_xq x_hat + G u).
    """

    x_hat: np.ndarray
    q_hat: np.ndarray
    h_hat: np.ndarray
    z_hat: np.ndarray


class FilterTerms(NamedTuple):
    """A constant gain's products that the recursion of ``filter_stream_states`` uses, formed
    once (``filter_terms``) for row vectors: Phi^T = ((I - K C) A)^T, K^T, and with inputs
    (K D)^T and ((I - K C) B)^T."""

    PhiT: np.ndarray
    KT: np.ndarray
    KDT: np.ndarray | None
    IKCBT: np.ndarray | None


def filter_terms(
    A: np.ndarray, C: np.ndarray, K: np.ndarray, B: np.ndarray | None = None,
    D: np.ndarray | None = None,
) -> FilterTerms:
    """``FilterTerms`` of gain K on (A, C) and, given B (and D), of the inputs."""
    n = A.shape[0]
    A = check_shape("A", A, (n, n))
    ny = np.shape(C)[0]
    C = check_shape("C", C, (ny, n))
    K = check_shape("K", K, (n, ny))
    I_KC = np.eye(n) - K @ C
    if B is None:
        return FilterTerms((I_KC @ A).T, K.T, None, None)
    nu = np.shape(B)[1]
    B = check_shape("B", B, (n, nu))
    D = check_shape("D", D, (ny, nu))
    return FilterTerms((I_KC @ A).T, K.T, (K @ D).T, (I_KC @ B).T)


def input_terms(
    terms: FilterTerms, y: np.ndarray, u: np.ndarray | None, u_prev: np.ndarray | None,
) -> np.ndarray:
    """The terms of the recursion that do not depend on x_hat, for all steps:
    K (y[k] - D u[k]) + (I - K C) B u[k-1] [n_steps, n_engines, n].
    y [n_steps, n_engines, ny] (time-major, checked by the caller)."""
    T, E, ny = y.shape
    if terms.KT.shape[0] != ny:
        raise DimensionError(
            f"y has {ny} sensors but the gain K and matrix C take {terms.KT.shape[0]}")
    out = y @ terms.KT  # K y[k] for all steps, [T, E, n]
    if u is not None:
        if terms.KDT is None or terms.IKCBT is None:
            raise DimensionError("inputs u need the terms of B and D (filter_terms)")
        u = np.asarray(u, float)
        nu = terms.IKCBT.shape[0]
        if u.shape != (T, E, nu):
            raise DimensionError(
                f"u must be [n_steps, n_engines, n_inputs] = ({T}, {E}, {nu}), found {u.shape}"
            )
        out -= u @ terms.KDT
        drive = u @ terms.IKCBT  # applies at the next step
        out[1:] += drive[:-1]
        if u_prev is not None:  # [nu] or [n_engines, nu]: broadcast over the engines
            out[0] += np.asarray(u_prev, float) @ terms.IKCBT
    return out


def stream_input_terms(
    A: np.ndarray,
    C: np.ndarray,
    K: np.ndarray,
    y: np.ndarray,
    u: np.ndarray | None,
    B: np.ndarray | None,
    D: np.ndarray | None,
    u_prev: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """``input_terms`` of gain K, and Phi^T."""
    terms = filter_terms(A, C, K, *((B, D) if u is not None else ()))
    return input_terms(terms, y, u, u_prev), terms.PhiT


def run_filter_terms(
    terms: FilterTerms, y: np.ndarray, u: np.ndarray | None = None,
    x0: np.ndarray | None = None, u_prev: np.ndarray | None = None,
) -> np.ndarray:
    """``filter_stream_states`` with the gain's terms formed beforehand (a gain used for many
    short runs forms them once)."""
    out = input_terms(terms, y, u, u_prev)
    PhiT = terms.PhiT
    if x0 is not None:  # [n] or [n_engines, n]: broadcast over the engines (default 0)
        out[0] += np.asarray(x0, float) @ PhiT
    for k in range(1, out.shape[0]):
        out[k] += out[k - 1] @ PhiT
    return out


def filter_stream_states(
    A: np.ndarray,
    C: np.ndarray,
    K: np.ndarray,
    y: np.ndarray,
    u: np.ndarray | None = None,
    B: np.ndarray | None = None,
    D: np.ndarray | None = None,
    x0: np.ndarray | None = None,
    u_prev: np.ndarray | None = None,
) -> np.ndarray:
    """Constant-gain filter over a batch of engines, one matrix product per step.

        x_pred[k] = A x_hat[k-1] + B u[k-1]
        x_hat[k]  = x_pred[k] + K (y[k] - C x_pred[k] - D u[k])
                  = Phi x_hat[k-1] + (I - K C) B u[k-1] + K (y[k] - D u[k]),  Phi = (I - K C) A

    Arrays are time-major: y [n_steps, n_engines, ny], u [n_steps, n_engines, nu]
    (deviations in percent of trim). x0 [n_engines, n] or [n] (default 0) is
    x_hat[-1]; u_prev [n_engines, nu] is u[-1] (default 0). The input terms
    are formed for all steps in one product beforehand, so the recursion is a
    single [n_engines, n] x [n, n] product per step. NaN in y propagates
    (streams are expected complete; the snapshot filter handles gaps).
    Returns x_hat [n_steps, n_engines, n].
    """
    y = np.asarray(y, float)
    if y.ndim != 3:
        raise DimensionError(
            f"y must be [n_steps, n_engines, n_sensors] (time-major), found shape {y.shape}"
        )
    terms = filter_terms(A, C, K, *((B, D) if u is not None else ()))
    return run_filter_terms(terms, y, u, x0, u_prev)


def filter_stream(
    reduced: ReducedModel,
    K: np.ndarray,
    y: np.ndarray,
    u: np.ndarray | None = None,
    x0: np.ndarray | None = None,
    u_prev: np.ndarray | None = None,
) -> StreamEstimate:
    """Reduced-order steady-state filter over a batch of engines (docs/math.md section 3).

    y [n_steps, n_engines, ny], u [n_steps, n_engines, nu] or None (u = 0);
    see ``filter_stream_states``. Also returns q_hat, h_hat = V*^+ q_hat
    (seed 002 eq. 11) and z_hat = F_xq x_hat + G u.
    """
    x = filter_stream_states(
        reduced.A, reduced.C, K, y, u=u, B=reduced.B, D=reduced.D, x0=x0, u_prev=u_prev
    )
    nx = reduced.n_states
    q = x[..., nx:]
    h = q @ reduced.vstar_pinv.T
    z = x @ reduced.F.T
    if u is not None:
        z += np.asarray(u, float) @ reduced.G.T
    return StreamEstimate(x, q, h, z)
