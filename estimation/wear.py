"""Gradual deterioration (wear) detection on one engine's sequence of tuner estimates.

The shift detector (``estimation.detection``) compares the estimate with a moving baseline a
few records back, so a slow drift is absorbed into its baseline and never alarms. Here the
baseline stays where it was set: the mean of the engine's first settled records after a start
or a maintenance reset, and the whole change since then is attributed and watched.

Notation (one stretch between resets; records k = 0 ... S-1 of it):

- x_k [m]: tuner (or health) estimate; c_k: the engine's cycle count at record k;
- x_0 = mean of x_k over k in [settle, settle + n_base): the baseline;
- d_k = x_k - x_0: the accumulated change;
- W [m, m]: the weight of the attribution. For tuners of a design V* the choice here is
  W = V*^+T V*^+, the change measured as a health change h = V*^+ q with every health
  parameter in percent weighted alike (the design's isotropic fleet prior P_h ~ I makes
  W proportional to P_q^-1 = (V* P_h V*^T)^-1 for V* with orthonormal rows);
- H [m, n]: the tuner change of each library fault at nominal magnitude (its direction).

Attribution (seed 002 eq. 21-23 with the weight W): per fault i

    f_i   = h_i^T W d / (h_i^T W h_i)                  (eq. 22, least-squares magnitude)
    WSSR_i = d^T W d - (h_i^T W d)^2 / (h_i^T W h_i)    (eq. 21/23)

and the attributed fault is the candidate with the smallest WSSR among those with f_i > 0
(wear moves a module in its deterioration direction; a negative fit is not that fault).

Alerts (the first of a stretch; one alert per stretch, the next after a reset):

- ``limit``: the attributed magnitude f reaches ``limit`` (times the library's nominal
  shift): the engine has lost as much as a nominal fault since its baseline, however slowly.
- ``rate``: a CUSUM on the drift of each candidate fault's magnitude f_i,k = a_i^T d_k
  (a_i = W h_i / h_i^T W h_i) beyond the allowed rate rho per cycle:

      g_i,k = max(0, g_i,k-1 + (f_i,k - f_i,k-1) - rho (c_k - c_k-1))

  Page's CUSUM on the increments with reference rho (between the fleet's normal rate r_0
  and the rate to detect r_1, rho = (r_0 + r_1) / 2); it alarms when g_i,k > delta_i,
  delta_i = max(margin * sigma_i, margin_floor) with sigma_i the scatter (standard
  deviation) of f_i over the baseline records. With C_i,k = f_i,k - rho c_k the recursion
  is g_k = C_k - min_{j <= k} C_j (j from the record the CUSUM starts at): the change over
  some recent stretch of records exceeds the normal wear over it by delta. Computed for all
  records at once (a running minimum), not record by record.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LIMIT = "limit"
RATE = "rate"


@dataclass(frozen=True)
class WearSettings:
    """Settings of the wear detector.

    settle: records after a start or reset left out of the baseline (filter transient);
    n_base: records averaged into the baseline x_0;
    limit: accumulated magnitude (times the nominal library shift) that alerts;
    rate: CUSUM reference rho, nominal magnitudes per cycle (above the fleet's normal rate);
    margin: CUSUM threshold in baseline standard deviations of f_i;
    margin_floor: smallest CUSUM threshold (nominal magnitudes), for a very quiet baseline.
    """

    settle: int = 20
    n_base: int = 30
    limit: float = 1.0
    # Chosen on bench/bench_wear.py: the demo fleet's false wear alerts fall below one per
    # engine-year from margin ~10 on; a lower margin or rate buys FD001 lead for more of them.
    rate: float = 1.0e-3
    margin: float = 10.0
    margin_floor: float = 0.03


@dataclass(frozen=True)
class WearAlert:
    """One wear alert: the record ``index`` (into the sequence given), its ``kind``
    (``LIMIT`` or ``RATE``), the attributed fault's index in H (None if no candidate fits
    with a positive magnitude), WSSR per fault [n] and fitted magnitudes f [n] of the
    accumulated change at that record, the attributed magnitude, the CUSUM value and
    threshold of the fault that alarmed (rate alerts), and the baseline's first record."""

    index: int
    kind: str
    fault: int | None
    wssr: np.ndarray
    f: np.ndarray
    magnitude: float
    statistic: float
    threshold: float
    baseline_start: int


@dataclass(frozen=True)
class WearScan:
    """Per record figures of a scan (S records): accumulated change attribution
    ``f`` [S, n] and ``wssr`` [S, n] (NaN before the baseline exists), the drift CUSUM
    ``g`` [S, n] (0 until armed), and the alerts (at most one per stretch between resets)."""

    f: np.ndarray
    wssr: np.ndarray
    g: np.ndarray
    alerts: tuple[WearAlert, ...]


def attribute(
    change: np.ndarray, W: np.ndarray, H: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """WSSR_i and f_i (seed 002 eq. 21-23 with weight W) of K changes at once.

    change [K, m], W [m, m] symmetric positive (semi)definite, H [m, n] -> wssr [K, n],
    f [K, n]. A fault with h_i^T W h_i = 0 gets f = 0 and WSSR = d^T W d.
    """
    d = np.atleast_2d(np.asarray(change, float))
    WH = W @ H  # [m, n]
    a = np.einsum("mn,mn->n", H, WH)  # h_i^T W h_i
    b = d @ WH  # [K, n] h_i^T W d
    c = np.einsum("km,mn,kn->k", d, W, d)  # d^T W d
    ok = a > 0
    f = np.where(ok, b / np.where(ok, a, 1.0), 0.0)
    wssr = np.maximum(c[:, None] - b * f, 0.0)
    return wssr, f


def best_fault(wssr: np.ndarray, f: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Index of the attributed fault per row: smallest WSSR among the candidates with f > 0
    (-1 where none). wssr, f [K, n], candidates [n] bool -> [K] int."""
    allowed = candidates[None, :] & (f > 0)
    masked = np.where(allowed, wssr, np.inf)
    best = np.argmin(masked, axis=1)
    return np.where(allowed.any(axis=1), best, -1)


def _segments(S: int, resets: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of each stretch; a reset at record k starts a stretch there."""
    starts = sorted({0, *np.flatnonzero(resets).tolist()})
    ends = [*starts[1:], S]
    return [(a, b) for a, b in zip(starts, ends, strict=True) if b > a]


def wear_scan(
    x: np.ndarray,
    H: np.ndarray,
    W: np.ndarray,
    cycles: np.ndarray,
    resets: np.ndarray | None = None,
    candidates: np.ndarray | None = None,
    settings: WearSettings | None = None,
) -> WearScan:
    """Scan one engine's estimates for wear (see the module docstring for the equations).

    x [S, m] estimates (time order); H [m, n] fault directions; W [m, m] attribution weight;
    cycles [S] the engine's cycle count at each record (non-decreasing within a stretch;
    two records of one flight share it); resets [S] bool, True where a maintenance action
    (or a new start) precedes the record; candidates [n] bool, the faults wear may be
    attributed to and whose drift is watched (default all).
    """
    cfg = settings or WearSettings()
    x = np.asarray(x, float)
    S, _m = x.shape
    n = H.shape[1]
    cycles = np.asarray(cycles, float)
    resets = np.zeros(S, bool) if resets is None else np.asarray(resets, bool)
    cand = np.ones(n, bool) if candidates is None else np.asarray(candidates, bool)
    f_all = np.full((S, n), np.nan)
    wssr_all = np.full((S, n), np.nan)
    g_all = np.zeros((S, n))
    alerts: list[WearAlert] = []
    WH = W @ H
    hWh = np.einsum("mn,mn->n", H, WH)
    A = WH / np.where(hWh > 0, hWh, 1.0)  # a_i columns [m, n]
    for s0, s1 in _segments(S, resets):
        b0 = s0 + cfg.settle
        b1 = b0 + cfg.n_base
        if b1 > s1:
            continue
        x0 = x[b0:b1].mean(axis=0)
        d = x[s0:s1] - x0
        wssr, f = attribute(d, W, H)
        f_all[s0:s1], wssr_all[s0:s1] = f, wssr
        sigma = f[b0 - s0 : b1 - s0].std(axis=0, ddof=1)
        delta = np.maximum(cfg.margin * sigma, cfg.margin_floor)
        # Drift CUSUM from the baseline's end (record b1 - 1 is its zero): Lindley's form.
        C = d[b1 - 1 - s0 :] @ A - cfg.rate * cycles[b1 - 1 : s1, None]
        g = C - np.minimum.accumulate(C, axis=0)
        g_all[b1 - 1 : s1] = g
        best = best_fault(wssr, f, cand)
        mag = np.where(best >= 0, f[np.arange(len(f)), np.maximum(best, 0)], 0.0)
        armed = np.arange(s0, s1) >= b1
        rate_hit = armed[b1 - 1 - s0 :] & np.any((g > delta) & cand, axis=1)
        limit_hit = armed & (mag >= cfg.limit)
        k_rate = int(np.argmax(rate_hit)) + b1 - 1 - s0 if rate_hit.any() else None
        k_limit = int(np.argmax(limit_hit)) if limit_hit.any() else None
        hits = [(k, kind) for k, kind in ((k_limit, LIMIT), (k_rate, RATE)) if k is not None]
        if not hits:
            continue
        k, kind = min(hits)
        gk = g[k - (b1 - 1 - s0)]
        over = np.where(cand, gk - delta, -np.inf)
        i = int(np.argmax(over))
        alerts.append(WearAlert(
            index=s0 + k, kind=kind, fault=int(best[k]) if best[k] >= 0 else None,
            wssr=wssr[k], f=f[k], magnitude=float(mag[k]),
            statistic=float(gk[i]), threshold=float(delta[i]), baseline_start=b0,
        ))
    return WearScan(f_all, wssr_all, g_all, tuple(alerts))


def health_weight(Vp: np.ndarray) -> np.ndarray:
    """W = V*^+T V*^+ [m, m] from V*^+ [p, m]: a tuner change weighted as its health change."""
    return np.asarray(Vp, float).T @ np.asarray(Vp, float)


def signature_cusum(
    dy: np.ndarray, var: np.ndarray, signature: np.ndarray, n_base: int = 30,
    reference: float = 0.5, threshold: float = 5.0, arm_at: int = 50,
) -> int | None:
    """A naive per-engine signature CUSUM on sensor deviations (the peer of the benchmark).

    dy [S, ny] sensor deviations (percent of trim, NaN = missing), var [ny] or [S, ny]
    noise variances, signature [ny] the fault's sensor change. The matched-filter projection
    z_k = g^T R^-1 dy_k / sqrt(g^T R^-1 g) is standardised by the mean and standard deviation
    of its first ``n_base`` records, and the one-sided CUSUM
    S_k = max(0, S_k-1 + z'_k - reference) alarms at the first record k >= ``arm_at`` with
    S_k > threshold (the index, None without an alarm).
    """
    dy = np.asarray(dy, float)
    w = np.broadcast_to(1.0 / np.asarray(var, float), dy.shape)
    present = np.isfinite(dy)
    wg = np.where(present, w * signature, 0.0)
    z = np.sum(wg * np.where(present, dy, 0.0), axis=1) / np.sqrt(
        np.maximum(np.sum(wg * signature, axis=1), 1e-300)
    )
    mu, sd = z[:n_base].mean(), z[:n_base].std(ddof=1)
    C = np.concatenate([[0.0], np.cumsum((z - mu) / sd - reference)])
    S = (C - np.minimum.accumulate(C))[1:]
    hit = (S > threshold) & (np.arange(len(z)) >= arm_at)
    return int(np.argmax(hit)) if hit.any() else None
