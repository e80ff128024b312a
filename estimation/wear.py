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
- ``directional`` (when the sensor deviations are given): a bank of per-fault matched-filter
  CUSUMs on the records' sensor deviations dy_k [ny] (noise variances r_k, signatures G_k
  [ny, n] at each record's condition). Per fault i and record k

      z_i,k = g_i^T R^-1 dy_k / sqrt(g_i^T R^-1 g_i)                   (matched filter)
      u_i,k = (z_i,k - mu_i) / s_i - kappa - rho_z (c_k - c_b)
      G_i,k = max(0, G_i,k-1 + u_i,k)

  with mu_i, s_i the mean and standard deviation of z_i over the stretch's first n_base
  records (the records are not filtered, so no settling is needed), kappa the reference in
  standard deviations, rho_z an allowed normal drift of z in standard deviations per cycle
  (from c_b, the baseline's last cycle). The bank has crossed once any candidate's G_i
  exceeds h (armed, as the other kinds, from the baseline's end). Page's CUSUM per fault;
  for n independent directions the bank's first crossing comes about n times sooner than
  one CUSUM's (the family-wise rate), which the tests check against Siegmund's
  approximation. The threshold is low (h = 2: a crossing alone is no alert); the false
  alerts are held down by the attribution condition that follows. The sensor signatures
  of the library faults are too alike for the winning CUSUM to name the fault, so the
  alert waits, after the crossing, for the WSSR attribution of the tuner change to be
  confident: the best candidate (f > 0) fits at least ``confidence`` times better than any
  other candidate (WSSR ratio) on ``hold`` consecutive records, and names that fault.
  When the bank runs, the rate CUSUM does not alert (``rate_with_bank``): the limit alert
  stays as the backstop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LIMIT = "limit"
RATE = "rate"
DIRECTIONAL = "directional"


@dataclass(frozen=True)
class WearSettings:
    """Settings of the wear detector.

    settle: records after a start or reset left out of the baseline (filter transient);
    n_base: records averaged into the baseline x_0;
    limit: accumulated magnitude (times the nominal library shift) that alerts;
    rate: CUSUM reference rho, nominal magnitudes per cycle (above the fleet's normal rate);
    margin: CUSUM threshold in baseline standard deviations of f_i;
    margin_floor: smallest CUSUM threshold (nominal magnitudes), for a very quiet baseline;
    bank_reference, bank_threshold: the directional bank's kappa and h (standard deviations);
    bank_rate: the bank's allowed drift rho_z (standard deviations per cycle);
    confidence, hold: the WSSR ratio the directional alert's attribution needs, and on how
    many consecutive records (confidence <= 0: no condition, the alert at the crossing);
    rate_with_bank: whether the rate CUSUM alerts too when the bank runs (by default the
    bank replaces it: on the demo fleet the rate alerts were the false ones).
    """

    settle: int = 20
    n_base: int = 30
    limit: float = 1.0
    # Chosen on bench/bench_wear.py: the demo fleet's false wear alerts fall below one per
    # engine-year from margin ~10 on; a lower margin or rate buys FD001 lead for more of them.
    rate: float = 1.0e-3
    margin: float = 10.0
    margin_floor: float = 0.03
    # Chosen on bench/bench_wear.py (FD001 lead and HPC share, demo fleet false alerts).
    bank_reference: float = 0.5
    bank_threshold: float = 2.0
    bank_rate: float = 1.0e-3
    confidence: float = 1.6
    hold: int = 3
    rate_with_bank: bool = False


@dataclass(frozen=True)
class WearAlert:
    """One wear alert: the record ``index`` (into the sequence given), its ``kind``
    (``LIMIT``, ``RATE`` or ``DIRECTIONAL``), the attributed fault's index in H (None if
    no candidate fits with a positive magnitude), WSSR per fault [n] and fitted magnitudes
    f [n] of the accumulated change at that record, the attributed magnitude, the CUSUM value and
    threshold of the fault that alarmed (rate and directional alerts; for a directional
    alert the bank's largest CUSUM over the threshold at the crossing), and the baseline's
    first record."""

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
    ``g`` [S, n] (0 until armed), the alerts (at most one per stretch between resets) and,
    with sensor deviations, the directional bank's CUSUMs ``bank`` [S, n] (0 until armed)."""

    f: np.ndarray
    wssr: np.ndarray
    g: np.ndarray
    alerts: tuple[WearAlert, ...]
    bank: np.ndarray | None = None


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


def matched_filter(dy: np.ndarray, var: np.ndarray, signatures: np.ndarray) -> np.ndarray:
    """z_i,k = g_i^T R^-1 dy_k / sqrt(g_i^T R^-1 g_i) of every fault and record.

    dy [S, ny] (NaN = missing: left out of that record's sums), var [ny] or [S, ny],
    signatures [ny, n] or [S, ny, n] -> z [S, n].
    """
    dy = np.asarray(dy, float)
    S, ny = dy.shape
    sig = np.broadcast_to(np.asarray(signatures, float), (S, ny, np.shape(signatures)[-1]))
    w = np.broadcast_to(1.0 / np.asarray(var, float), dy.shape)
    present = np.isfinite(dy)
    wg = np.where(present[:, :, None], w[:, :, None] * sig, 0.0)
    num = np.einsum("sjn,sj->sn", wg, np.where(present, dy, 0.0))
    den = np.einsum("sjn,sjn->sn", wg, sig)
    return num / np.sqrt(np.maximum(den, 1e-300))


def confident_fault(
    wssr: np.ndarray, f: np.ndarray, candidates: np.ndarray, ratio: float, hold: int
) -> tuple[np.ndarray, np.ndarray]:
    """The attributed fault per row (``best_fault``) and whether it is confident there: the
    other candidates' smallest WSSR is at least ``ratio`` times its WSSR, on this row and the
    ``hold - 1`` before it, with the same fault. ratio <= 0: every row is (-1: no fault)."""
    best = best_fault(wssr, f, candidates)
    rows = np.arange(len(best))
    if ratio <= 0:
        return best, np.ones(len(best), bool)
    w_best = np.where(best >= 0, wssr[rows, np.maximum(best, 0)], np.inf)
    others = candidates[None, :] & (np.arange(wssr.shape[1])[None, :] != best[:, None])
    runner_up = np.where(others, wssr, np.inf).min(axis=1)
    ok = (best >= 0) & (runner_up >= ratio * w_best)
    held = ok.copy()
    for lag in range(1, max(hold, 1)):
        held[lag:] &= ok[:-lag] & (best[:-lag] == best[lag:])
        held[:lag] = False
    return best, held


def _cusum(u: np.ndarray) -> np.ndarray:
    """Page's CUSUM max(0, G_k-1 + u_k) from G = 0 of every column, as a running minimum."""
    C = np.vstack([np.zeros((1, u.shape[1])), np.cumsum(u, axis=0)])
    return (C - np.minimum.accumulate(C, axis=0))[1:]


def wear_scan(
    x: np.ndarray,
    H: np.ndarray,
    W: np.ndarray,
    cycles: np.ndarray,
    resets: np.ndarray | None = None,
    candidates: np.ndarray | None = None,
    settings: WearSettings | None = None,
    dy: np.ndarray | None = None,
    var: np.ndarray | None = None,
    signatures: np.ndarray | None = None,
) -> WearScan:
    """Scan one engine's estimates for wear (see the module docstring for the equations).

    x [S, m] estimates (time order); H [m, n] fault directions; W [m, m] attribution weight;
    cycles [S] the engine's cycle count at each record (non-decreasing within a stretch;
    two records of one flight share it); resets [S] bool, True where a maintenance action
    (or a new start) precedes the record; candidates [n] bool, the faults wear may be
    attributed to and whose drift is watched (default all). With the records' sensor
    deviations dy [S, ny], their noise variances var [ny] or [S, ny] and the faults' sensor
    signatures [ny, n] or [S, ny, n] (the same faults as H's columns), the directional bank
    runs too; the first alert of a stretch, of whichever kind, is the one reported.
    """
    cfg = settings or WearSettings()
    x = np.asarray(x, float)
    S, _m = x.shape
    n = H.shape[1]
    cycles = np.asarray(cycles, float)
    resets = np.zeros(S, bool) if resets is None else np.asarray(resets, bool)
    cand = np.ones(n, bool) if candidates is None else np.asarray(candidates, bool)
    z = None
    if dy is not None or var is not None or signatures is not None:
        if dy is None or var is None or signatures is None:
            raise ValueError("the directional bank needs dy, var and signatures together")
        z = matched_filter(dy, var, signatures)
    use_bank = z is not None
    f_all = np.full((S, n), np.nan)
    wssr_all = np.full((S, n), np.nan)
    g_all = np.zeros((S, n))
    bank_all = np.zeros((S, n)) if use_bank else None
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
        if z is not None and not cfg.rate_with_bank:
            k_rate = None  # the bank watches the drift; the limit stays as the backstop
        hits = [(k, kind) for k, kind in ((k_limit, LIMIT), (k_rate, RATE)) if k is not None]
        bank_fault, bank_stat = None, 0.0
        if z is not None and bank_all is not None:
            zs = z[s0:s1]
            base = zs[: cfg.n_base]  # unfiltered records: no settling
            sd = base.std(axis=0, ddof=1)
            u = (zs - base.mean(axis=0)) / np.where(sd > 0, sd, np.inf)
            u -= cfg.bank_reference + cfg.bank_rate * (cycles[s0:s1, None] - cycles[b1 - 1])
            G = np.zeros_like(u)
            G[b1 - s0 :] = _cusum(u[b1 - s0 :])  # from the baseline's end, as the rate CUSUM
            bank_all[s0:s1] = G
            crossed = np.maximum.accumulate(armed & np.any((G > cfg.bank_threshold) & cand, 1))
            named, sure = confident_fault(wssr, f, cand, cfg.confidence, cfg.hold)
            bank_hit = crossed & sure
            if bank_hit.any():
                k = int(np.argmax(bank_hit))
                hits.append((k, DIRECTIONAL))
                kc = int(np.argmax(crossed))
                top = np.where(cand, G[kc], -np.inf)
                bank_stat = float(np.max(top))
                # No fault fits with f > 0 (confidence off): the CUSUM that crossed names it.
                bank_fault = int(named[k]) if named[k] >= 0 else int(np.argmax(top))
        if not hits:
            continue
        k, kind = min(hits)
        if kind == DIRECTIONAL:
            alerts.append(WearAlert(
                index=s0 + k, kind=kind, fault=bank_fault, wssr=wssr[k], f=f[k],
                magnitude=float(f[k, bank_fault]) if bank_fault is not None else 0.0,
                statistic=bank_stat, threshold=cfg.bank_threshold, baseline_start=b0,
            ))
            continue
        gk = g[k - (b1 - 1 - s0)]
        over = np.where(cand, gk - delta, -np.inf)
        i = int(np.argmax(over))
        alerts.append(WearAlert(
            index=s0 + k, kind=kind, fault=int(best[k]) if best[k] >= 0 else None,
            wssr=wssr[k], f=f[k], magnitude=float(mag[k]),
            statistic=float(gk[i]), threshold=float(delta[i]), baseline_start=b0,
        ))
    return WearScan(f_all, wssr_all, g_all, tuple(alerts), bank_all)


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
