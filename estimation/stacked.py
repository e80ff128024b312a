"""Cholesky factors and triangular solves of stacks of small symmetric positive definite
matrices (the filter's innovation covariances, the detector's tuner covariances).

LAPACK's general solve and inverse on matrices of a dozen rows cost 2-3 us each, mostly per
call; a stack of them is thousands. With the factor L of each matrix (one LAPACK ``potrf``,
a third of that) only a forward substitution is left, and it runs as a dozen array
operations over the whole stack with the stack on the last axis (``forward_substitute``;
``cholesky_lower`` writes the factors there itself, given that memory seen stack first).

Every figure of a matrix is computed by the same operations in the same order whatever the
other matrices of the stack, so results do not depend on how records are grouped.
"""

from __future__ import annotations

from typing import Any

import numpy as np

# numpy's own gufunc behind np.linalg.cholesky (numpy 1.26 and 2.x); None: the public one.
_GUFUNC_CHOLESKY: Any = getattr(getattr(np.linalg, "_umath_linalg", None), "cholesky_lo", None)


def cholesky_lower(a: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """The lower Cholesky factors [..., n, n] of symmetric positive definite matrices
    [..., n, n], without the wrapper's checks and error state per call; a matrix that is not
    positive definite gives NaN (an invalid-value warning unless the caller's error state
    ignores it), which the caller checks once. ``out``: where to write them (any strides,
    for instance a ``SubstitutionPlan``'s L seen as [K, n, n])."""
    if _GUFUNC_CHOLESKY is None:  # pragma: no cover - a numpy without the gufunc
        try:
            L = np.linalg.cholesky(a)
        except np.linalg.LinAlgError:
            L = np.full(np.shape(a), np.nan)
        if out is None:
            return L
        out[...] = L
        return out
    if out is None:
        return _GUFUNC_CHOLESKY(a, signature="d->d")
    return _GUFUNC_CHOLESKY(a, signature="d->d", out=out)


def forward_substitute(L: np.ndarray, X: np.ndarray) -> np.ndarray:
    """X <- L^-1 X in place for lower-triangular L, the stack last: L [n, n, K], X [n, r, K]
    (r right-hand sides of each of K systems). Row by row, each solved row taken out of the
    rows below it."""
    n = L.shape[0]
    terms = np.empty((max(n - 1, 0), *X.shape[1:]))
    for k in range(n):
        X[k] /= L[k, k]
        if k + 1 < n:
            below = terms[: n - k - 1]
            np.multiply(L[k + 1:, k, None, :], X[k, None], out=below)
            X[k + 1:] -= below
    return X


class SubstitutionPlan:
    """``forward_substitute`` of one shape done again and again on the same two buffers (the
    filter's step after step): ``L`` [n, n, K] (``L_stack``: the same seen as [K, n, n],
    where ``cholesky_lower`` writes) and ``X`` [n, r, K], written by the caller before each
    ``run``. The views of every row's operations are made once, so a small stack
    costs its arithmetic, not the indexing (the same operations in the same order: the same
    numbers)."""

    def __init__(self, n: int, r: int, K: int):
        self.L = np.empty((n, n, K))
        self.L_stack = self.L.transpose(2, 0, 1)  # the same memory seen as [K, n, n]
        self.X = np.empty((n, r, K))
        terms = np.empty((max(n - 1, 0), r, K))
        L, X = self.L, self.X
        # Row by row: (the row, its pivot) and, but for the last row, (the column below the
        # pivot, the solved row, the products' buffer, the rows below), as ``run`` takes them.
        self._steps = [(X[k], L[k, k], L[k + 1:, k, None, :], X[k, None], terms[: n - k - 1],
                        X[k + 1:]) for k in range(n - 1)]
        self._last = (X[n - 1], L[n - 1, n - 1]) if n else None

    def run(self) -> np.ndarray:
        """X <- L^-1 X in place, as ``forward_substitute``; returns X. (The ufuncs' outputs
        given by position: the same operations, without parsing a keyword a call.)"""
        divide, multiply, subtract = np.divide, np.multiply, np.subtract
        for row, pivot, column, solved, terms, rest in self._steps:
            divide(row, pivot, row)
            multiply(column, solved, terms)
            subtract(rest, terms, rest)
        if self._last is not None:
            row, pivot = self._last
            divide(row, pivot, row)
        return self.X
