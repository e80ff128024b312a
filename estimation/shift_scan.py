"""Batched pieces of the tuner-level shift detector (``estimation.shift_detector``), many records
at once.

The CUSUM recursion S_k = max(0, S_{k-1} + s_k - m - kappa) is cheap scalar arithmetic; what
costs is the level statistic s_k = (q_k - q_0,k)^T P_k^-1 (q_k - q_0,k) with its baseline
q_0,k (a sliding mean of earlier estimates) and the WSSR of every library fault (seed 002
eq. 21-23). Those do not depend on the CUSUM's state between two resets, so they are computed
here for a whole run of records; the caller keeps only the alarm bookkeeping per record.

Every record's figures are computed with the same operations in the same order as one record
alone (sequential sums, one LAPACK Cholesky factorisation per record), so they do not depend on
which records share a call: re-runs and split runs stay bit-identical.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from estimation.stacked import cholesky_lower, forward_substitute


class LevelScan(NamedTuple):
    """Per record (K records): distance [K] = shift^T P^-1 shift, wssr [K, n_faults] and
    f [K, n_faults] (seed 002 eq. 21-23, WSSR_i = d - (H_i^T P^-1 shift)^2 / H_i^T P^-1 H_i)."""

    distance: np.ndarray
    wssr: np.ndarray
    f: np.ndarray


def sliding_baselines(series: np.ndarray, n_base: int) -> np.ndarray:
    """Row i is the mean of ``series[i : i + n_base]`` for i = 0 ... T - n_base, summed row by
    row in order (as ``np.mean`` over axis 0 of one window does) and divided by ``n_base``.

    series [T, m] -> [T - n_base + 1, m] (empty when T < n_base).
    """
    series = np.asarray(series, float)
    if series.ndim != 2:
        raise ValueError(f"series must be [T, m], got shape {series.shape}")
    T = series.shape[0]
    K = T - n_base + 1
    if K <= 0:
        return np.zeros((0, series.shape[1]))
    acc = series[0:K].copy()
    for t in range(1, n_base):
        acc += series[t : t + K]
    return acc / n_base


def level_scan(shift: np.ndarray, P: np.ndarray, H: np.ndarray) -> LevelScan:
    """Level statistic and fault WSSR of K records at once.

    shift [K, m] (tuner estimate minus baseline), P [K, m, m] (filter covariance),
    H [m, n_faults] (tuner change per library fault). With the Cholesky factor P_k = L L^T
    of each record (``estimation.stacked``) and Y = L^-1 [shift, H], every figure of seed 002
    eq. 21-23 is a sum over Y's rows: distance = |Y_s|^2, H_i^T P^-1 H_i = |Y_i|^2 and
    H_i^T P^-1 shift = Y_i . Y_s; one LAPACK factorisation per record and a forward
    substitution over all of them cost two thirds of one inverse per record. A single record goes
    through here too (``estimation.shift_detector``), so a record's figures do not depend on
    the records it is computed with.
    """
    shift = np.asarray(shift, float)
    P = np.asarray(P, float)
    K, m = shift.shape
    if P.shape != (K, m, m):
        raise ValueError(f"P must be [{K}, {m}, {m}], got {P.shape}")
    if H.shape[0] != m:
        raise ValueError(f"H must be [{m}, n_faults], got {H.shape}")
    nf = H.shape[1]
    if K == 0:
        return LevelScan(np.zeros(0), np.zeros((0, nf)), np.zeros((0, nf)))
    # The factors laid out records last, as ``forward_substitute`` takes them, written there
    # by the factorisation itself.
    L = np.empty((m, m, K))
    with np.errstate(invalid="ignore"):
        cholesky_lower(P, out=L.transpose(2, 0, 1))
    if not np.isfinite(L).all():
        raise np.linalg.LinAlgError("filter covariance not positive definite")
    # Right-hand sides [m, 1 + n_faults, K]: the shift, then every fault's tuner change.
    Y = np.empty((m, 1 + nf, K))
    Y[:, 0] = shift.T
    Y[:, 1:] = np.asarray(H, float)[:, :, None]
    forward_substitute(L, Y)
    # Sums over Y's rows, row after row in order (each record's own): numpy reduces over
    # the outer axis row by row, as ``np.mean`` over axis 0 does (``sliding_baselines``).
    squares = np.add.reduce(Y * Y, axis=0)  # [1 + nf, K]: distance, then H_i^T P^-1 H_i
    cross = np.add.reduce(Y[:, :1] * Y[:, 1:], axis=0)  # [nf, K]: H_i^T P^-1 shift
    distance = squares[0].copy()
    if nf == 0:
        return LevelScan(distance, np.zeros((K, 0)), np.zeros((K, 0)))
    proj = cross.T
    f = proj / squares[1:].T
    wssr = np.maximum(distance[:, None] - proj * f, 0.0)
    return LevelScan(distance, wssr, f)
