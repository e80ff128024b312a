"""A damped Newton solver vectorised over a batch of independent systems.

Each row of the batch is its own n x n system; the Jacobian of every row is
taken by forward differences in one batched call of the residual function
(n + 1 stacked evaluations), then np.linalg.solve on the stack. Steps are
limited to ``max_step`` in every unknown and halved while the residual norm
grows (backtracking), per row. Unknowns should be scaled to order one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np


class NewtonResult(NamedTuple):
    """x [B, n] solution; residual [B, n] there; converged [B]; iterations used."""

    x: np.ndarray
    residual: np.ndarray
    converged: np.ndarray
    iterations: int


def newton(
    fun: Callable[[np.ndarray, np.ndarray], np.ndarray],
    x0: np.ndarray,
    tol: float = 1e-10,
    max_iter: int = 40,
    eps: float = 1e-7,
    max_step: float = 0.2,
) -> NewtonResult:
    """Solve fun(x, rows) = 0 for every row of x0 [B, n].

    ``fun(x, rows)`` takes unknowns x [K, n] belonging to batch rows ``rows`` [K]
    (indices into the batch, so the caller can pick each row's parameters) and
    returns residuals [K, n]. Convergence: max |residual| <= tol per row.
    """
    x = np.array(x0, dtype=float)
    b, n = x.shape
    rows = np.arange(b)
    steps = eps * np.eye(n)
    r = fun(x, rows)
    err = np.max(np.abs(r), axis=1)
    it = 0
    for it in range(1, max_iter + 1):
        active = ~(err <= tol)
        if not active.any():
            it -= 1
            break
        xa, ra, ia = x[active], r[active], rows[active]
        k = xa.shape[0]
        xs = np.concatenate([xa] + [xa + steps[j] for j in range(n)], axis=0)
        rs = fun(xs, np.tile(ia, n + 1)).reshape(n + 1, k, n)
        jac = np.transpose((rs[1:] - rs[0]) / eps, (1, 2, 0))  # [k, residual, unknown]
        try:
            dx = np.linalg.solve(jac, -ra[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a singular row: least squares for every row
            pairs = zip(jac, ra, strict=True)
            dx = np.stack([np.linalg.lstsq(j, -q, rcond=None)[0] for j, q in pairs])
        big = np.max(np.abs(dx), axis=1, keepdims=True)
        dx = dx * np.minimum(1.0, max_step / np.maximum(big, 1e-300))
        dx[~np.isfinite(dx)] = 0.0
        norm0 = np.sum(ra * ra, axis=1)
        lam = np.ones(k)
        xn, rn = xa + dx, fun(xa + dx, ia)
        for _ in range(6):
            normn = np.sum(rn * rn, axis=1)
            worse = ~(normn < norm0) & (lam > 1.0 / 32.0)
            if not worse.any():
                break
            lam[worse] *= 0.5
            xn[worse] = xa[worse] + lam[worse, None] * dx[worse]
            rn[worse] = fun(xn[worse], ia[worse])
        x[active], r[active] = xn, rn
        err = np.max(np.abs(r), axis=1)
    return NewtonResult(x, r, err <= tol, it)
