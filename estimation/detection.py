"""Abrupt-shift detection on tuner trends: a chi-squared CUSUM normalised by P_q.

Seed 002 assumes the fault has been detected; this module finds the event.
Each sample of the tuner estimate is compared with an archived baseline and
normalised by its covariance P_q (docs/math.md section 4)::

    s_k = (q_hat[k] - q_0)^T P_q^-1 (q_hat[k] - q_0)       ~ chi2_m       (no fault)
                                                           ~ chi2_m(lam)  (shift d,
                                                              lam = d^T P_q^-1 d)
    S_k = max(0, S_{k-1} + s_k - m - kappa)                (one-sided CUSUM, S_0 = 0)
    alarm when S_k > h, then S restarts from 0.

The statistic does not need the fault direction, so any fault (library or
not) is found; isolation (``estimation.isolation``) then names it.

False-alarm rate and detection delay (theory)
---------------------------------------------
With independent samples the CUSUM is a Markov process, and its run length
follows from the Brook & Evans (1972) chain: [0, h] is cut into ``n_cells``
cells plus the atom S = 0, R is the transition matrix among the transient
cells for increments s - m - kappa with s ~ chi2_m(lam), and

    ARL(lam)      = e_0^T (I - R)^-1 1            (average run length, samples)
    P(T > n | lam) = e_0^T R^n 1                   (run-length survival)

``ARL(0)`` is the mean number of samples between false alarms (the false
alarm rate is 1 / ARL(0) per sample, because S restarts after an alarm);
``ARL(lam)`` is the mean detection delay (in samples, counting the first
faulty sample as 1) for a fault that appears when S = 0, and
``start="steady"`` gives it for a fault that appears after a long healthy
run (the quasi-stationary distribution of S). ``design_cusum`` picks h for a
target ARL(0). tests/estimation/test_detection.py measures both by Monte
Carlo. For example, six tuners with kappa = 3 and a target of one false
alarm per 500 samples give h = 14.615; 400 sequences of 5000 healthy samples
then raised 0.00204 alarms per sample (theory 0.00200), and a shift with
lam = 6 was detected after 5.70 samples on average (theory 5.72; P(T > 10) =
0.104 measured, 0.103 theory).

The recursion is ``cusum_step`` on one sample (the snapshot pipeline's shift detector,
``estimation.shift_detector``, runs it on a rescaled statistic) and ``cusum_scan`` on a batch
of sequences; the two do the same operations in the same order.

Samples must be independent for these figures to hold: snapshots a flight
apart, or a stream decimated by ``decorrelation_stride``, because the
steady-state filter's q_hat is strongly correlated from one step to the next.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import optimize, stats

from estimation.isolation import whitener


class DetectionError(ValueError):
    """A detector design or input that cannot be used."""


@dataclass(frozen=True)
class CusumDesign:
    """Chi-squared CUSUM settings and their theoretical in-control run length.

    m         : dimension of the monitored vector (number of tuners)
    reference : kappa, allowance subtracted from each s_k beyond its mean m
    threshold : h, alarm level of S
    arl0      : mean samples between false alarms (theory)
    """

    m: int
    reference: float
    threshold: float
    arl0: float

    @property
    def false_alarm_rate(self) -> float:
        """False alarms per sample (theory), 1 / ARL(0)."""
        return 1.0 / self.arl0


@dataclass(frozen=True)
class Detection:
    """Detector output for a batch of sequences.

    statistic   : (..., T) CUSUM S_k after each sample
    alarms      : (..., T) True where an alarm is raised (S restarts after it)
    first_alarm : (...) index of the first alarm, -1 if none
    """

    statistic: np.ndarray
    alarms: np.ndarray
    first_alarm: np.ndarray


def _transition(m: int, reference: float, threshold: float, lam: float, n_cells: int):
    """Brook-Evans transient matrix R over the atom {0} and n_cells cells of (0, h]."""
    w = threshold / n_cells
    # Representative values: 0 for the atom, cell mid-points otherwise.
    s = np.concatenate([[0.0], (np.arange(n_cells) + 0.5) * w])
    edges = np.arange(n_cells + 1) * w  # upper edges of the atom and cells, 0..h
    c = m + reference
    dist = stats.chi2(m) if lam == 0.0 else stats.ncx2(m, lam)
    cdf = dist.cdf(edges[None, :] - s[:, None] + c)  # P(next <= edge)
    R = np.empty((n_cells + 1, n_cells + 1))
    R[:, 0] = cdf[:, 0]
    R[:, 1:] = np.diff(cdf, axis=1)
    return R


def _check_design(m: int, reference: float, threshold: float) -> None:
    if m < 1:
        raise DetectionError(f"dimension m must be >= 1, got {m}")
    if threshold <= 0:
        raise DetectionError(f"threshold h must be positive, got {threshold}")
    if reference < -m:
        raise DetectionError(f"reference kappa must be >= -m, got {reference}")


def _start_vector(R0: np.ndarray, start: str) -> np.ndarray:
    if start == "zero":
        p = np.zeros(R0.shape[0])
        p[0] = 1.0
        return p
    if start == "steady":
        # Quasi-stationary law of S in control: left Perron vector of R0.
        lam, V = np.linalg.eig(R0.T)
        v = np.abs(np.real(V[:, np.argmax(np.real(lam))]))
        return v / v.sum()
    raise DetectionError(f"start must be 'zero' or 'steady', got {start!r}")


def average_run_length(
    m: int,
    reference: float,
    threshold: float,
    noncentrality: float = 0.0,
    start: str = "zero",
    n_cells: int = 400,
) -> float:
    """Mean run length (samples) of the chi-squared CUSUM, Brook-Evans chain.

    noncentrality : lam = d^T P_q^-1 d of the shift d (0: no fault -> ARL(0)).
    start         : "zero" (S = 0 when the shift appears) or "steady".
    """
    _check_design(m, reference, threshold)
    R = _transition(m, reference, threshold, float(noncentrality), n_cells)
    a = np.linalg.solve(np.eye(R.shape[0]) - R, np.ones(R.shape[0]))
    if start == "zero":
        return float(a[0])
    R0 = R if noncentrality == 0.0 else _transition(m, reference, threshold, 0.0, n_cells)
    return float(_start_vector(R0, start) @ a)


def run_length_survival(
    m: int,
    reference: float,
    threshold: float,
    noncentrality: float,
    n_max: int,
    start: str = "zero",
    n_cells: int = 400,
) -> np.ndarray:
    """P(T > n) for n = 0..n_max (T in samples, first faulty sample counts 1).

    Returns (n_max + 1,). The detection-delay distribution of a shift with
    noncentrality lam; with lam = 0 the run length to a false alarm.
    """
    _check_design(m, reference, threshold)
    R = _transition(m, reference, threshold, float(noncentrality), n_cells)
    R0 = R if noncentrality == 0.0 else _transition(m, reference, threshold, 0.0, n_cells)
    p = _start_vector(R0, start)
    out = np.empty(n_max + 1)
    for n in range(n_max + 1):
        out[n] = p.sum()
        p = p @ R
    return out


def design_cusum(
    m: int, arl0: float = 1000.0, reference: float | None = None, n_cells: int = 400
) -> CusumDesign:
    """Threshold h giving a target mean run length between false alarms.

    reference : kappa; default m / 2 (tuned to shifts with noncentrality ~ m,
                about one standard deviation per tuner).
    """
    kappa = 0.5 * m if reference is None else float(reference)
    if arl0 <= 1.0:
        raise DetectionError(f"target ARL(0) must exceed 1 sample, got {arl0}")

    def gap(h: float) -> float:
        return np.log(average_run_length(m, kappa, h, 0.0, n_cells=n_cells)) - np.log(arl0)

    hi = 2.0 * m + 10.0
    while gap(hi) < 0.0:
        hi *= 2.0
        if hi > 1e6:
            raise DetectionError(f"no threshold reaches ARL(0) = {arl0}")
    h = optimize.brentq(gap, 1e-6, hi, xtol=1e-8, rtol=1e-10)
    return CusumDesign(m, kappa, float(h), average_run_length(m, kappa, h, 0.0, n_cells=n_cells))


def normalised_shift(q_hat: np.ndarray, baseline: np.ndarray, P_q: np.ndarray) -> np.ndarray:
    """s_k = (q_hat - q_0)^T P_q^-1 (q_hat - q_0) for (..., T, m) sequences; returns (..., T)."""
    q_hat = np.asarray(q_hat, float)
    m = q_hat.shape[-1]
    if np.asarray(P_q).shape != (m, m):
        raise DetectionError(f"P_q: expected ({m}, {m}) but found {np.asarray(P_q).shape}")
    base = np.asarray(baseline, float)
    if base.shape[-1] != m:
        raise DetectionError(f"baseline: expected last dimension {m}, found {base.shape}")
    W = whitener(P_q, "P_q")
    e = (q_hat - base[..., None, :]) @ W.T
    return np.sum(e**2, axis=-1)


def cusum_step(S: float, s: float, m: float, reference: float) -> float:
    """One sample of the CUSUM on Python floats: S_k = max(0, S_{k-1} + s_k - m - kappa)
    (NaN counts as 0). The scalar form of ``cusum_scan``, with the same operations."""
    S = S + s - m - reference
    return S if S > 0.0 else 0.0


def cusum_scan(s: np.ndarray, design: CusumDesign) -> Detection:
    """The CUSUM over (..., T) statistics s_k, vectorised over the sequences; S restarts
    from 0 after an alarm. The same operations as ``cusum_step``, sample by sample."""
    s = np.asarray(s, float)
    S = np.zeros(s.shape[:-1])
    stat = np.empty_like(s)
    alarms = np.zeros(s.shape, dtype=bool)
    for k in range(s.shape[-1]):
        S = S + s[..., k] - design.m - design.reference
        S = np.where(S > 0.0, S, 0.0)
        hit = S > design.threshold
        alarms[..., k] = hit
        stat[..., k] = S
        S = np.where(hit, 0.0, S)
    return _detection(stat, alarms)


def cusum_steps(s: np.ndarray, design: CusumDesign) -> Detection:
    """``cusum_scan`` one sample at a time through ``cusum_step`` (the scalar reference)."""
    s = np.asarray(s, float)
    flat = s.reshape(-1, s.shape[-1]) if s.ndim else s.reshape(1, 0)
    stat = np.empty_like(flat)
    alarms = np.zeros(flat.shape, dtype=bool)
    for e, row in enumerate(flat.tolist()):
        S = 0.0
        for k, s_k in enumerate(row):
            S = cusum_step(S, s_k, design.m, design.reference)
            stat[e, k] = S
            if S > design.threshold:
                alarms[e, k] = True
                S = 0.0
    return _detection(stat.reshape(s.shape), alarms.reshape(s.shape))


def _detection(stat: np.ndarray, alarms: np.ndarray) -> Detection:
    first = np.where(alarms.any(axis=-1), np.argmax(alarms, axis=-1), -1)
    return Detection(stat, alarms, first)


def cusum_detect(
    q_hat: np.ndarray, baseline: np.ndarray, P_q: np.ndarray, design: CusumDesign,
    scan: Callable[[np.ndarray, CusumDesign], Detection] = cusum_scan,
) -> Detection:
    """Run the chi-squared CUSUM over tuner sequences, batched over engines.

    q_hat    : (..., T, m) tuner estimates in time order (independent samples)
    baseline : (..., m) or (m,) archived tuner baseline q_0
    P_q      : (m, m) covariance of a tuner sample about its mean
    scan     : ``cusum_scan`` (vectorised) or ``cusum_steps`` (sample by sample)
    """
    if np.asarray(q_hat).shape[-1] != design.m:
        raise DetectionError(
            f"q_hat: expected last dimension {design.m} (design.m), found {np.shape(q_hat)}"
        )
    return scan(normalised_shift(q_hat, baseline, P_q), design)


def decorrelation_stride(
    Phi: np.ndarray, P_hat: np.ndarray, m: int, level: float = 0.05, max_lag: int = 1_000_000
) -> int:
    """Smallest lag j at which the whitened tuner autocorrelation falls below ``level``.

    The filter error obeys e[k] = Phi e[k-1] + K v[k], so the lag-j covariance
    of q_hat is [0 I] Phi^j P_hat [0 I]^T; it is normalised by P_q and its
    largest absolute entry compared with ``level``. Sampling the stream every
    ``stride`` steps makes the detector's independence assumption reasonable.
    """
    Phi = np.asarray(Phi, float)
    n = Phi.shape[0]
    Pq = P_hat[n - m :, n - m :]
    W = whitener(Pq, "P_q")
    X = np.asarray(P_hat, float)
    for j in range(1, max_lag + 1):
        X = Phi @ X
        corr = W @ X[n - m :, n - m :] @ W.T
        if np.max(np.abs(corr)) < level:
            return j
    raise DetectionError(f"tuner autocorrelation stays above {level} for {max_lag} lags")
