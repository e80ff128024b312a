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
  shift) and the fault explains at least ``limit_share`` of the change, 1 - WSSR_i / d^T W d
  (``explained``): the engine has lost as much as a nominal
  fault since its baseline, however slowly, and the change is of that fault's kind (a
  change the fault explains a tenth of is estimates wandering where the design hardly
  sees, whose projection on a fault can reach the limit).
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
  approximation.

  The bank's design (``bank_design``): mu_i and s_i come from n_base records only, and their
  errors are shared by every later record of the stretch (a mean error e acts as a drift of
  e per record, which a reference of 0.5 does not absorb: with h = 2 nearly every healthy
  engine crossed within a few dozen records). With ``bank_alpha`` = a the standardisation
  allows for both at level a: the reference becomes kappa + z_(1-a) / sqrt(n_base) (the
  mean's upper bound) and s_i is scaled by sqrt((n_base - 1) / chi2_a(n_base - 1)) (the
  standard deviation's). The threshold h is then set by the false-alarm budget: the issue's
  criterion is at most 1 false wear alert per engine-year on healthy stretches, and the
  bank is designed for A = ``false_alerts_per_year`` (1: the whole of it; the attribution's
  condition below keeps most crossings from alerting). With R the engine's records per
  engine-year flown (``record_rate`` over the stretch's first settle + n_base records'
  times, gaps of 30 days or more left out as time on the ground; the nominal
  ``records_per_year`` without times) the bank's family-wise mean run length to a false
  crossing is ARL = R / A (``bank_arl``), and h is calibrated by Monte Carlo
  (``bank_calibration``, ``calibrated_threshold``): on 2000 seeded white engines, n
  independent candidates standardised as the bank is (mean and scatter of n_base records,
  the allowances, the drift allowance at one record a cycle), h is the smallest threshold
  that at most a share 1 - exp(-T / ARL) of them exceed within T armed records, for every
  T up to min(R, 512): the rate holds from a stretch's start at every horizon up to an
  engine-year. The table is computed once per design (about a second) and kept. The false
  crossings are far from exponential in time: a healthy engine crosses because of its
  baseline's error, so early in a stretch, and the short horizons bind (FD001: h = 4.35
  binds at about 24 armed records; met at one engine-year only, h would be 3.22, with about 45 %
  of white engines crossing within 100 armed records and 63 % within 365: the healthy
  steady fleet of tests/app/services/snapshots/test_wear_events.py, 0.27 engine-years an
  engine, then raised 2.4 false alerts per engine-year at attribution ratio 1.5).
  Independent candidates: the library's signatures are correlated, so the bank's real rate
  is lower. Siegmund's ARL(kappa', h) = n_candidates * R / A (Bonferroni) is the fallback
  (``bank_calibrated`` False, or no horizon with 50 simulated crossings at its level): h =
  5.21 on FD001, about 6.5 at the demo's rate (6.10 calibrated). A crossing alone is no
  alert: the sensor signatures of the library faults are too alike for the winning CUSUM to
  name the fault, so the alert waits, after the crossing, for the WSSR attribution of the
  tuner change to be confident: the best candidate (f > 0) fits at least ``confidence``
  times better than any other candidate (WSSR ratio) on ``hold`` consecutive records, and
  names that fault.
  When the bank runs, the rate CUSUM does not alert (``rate_with_bank``): the limit alert
  stays as the backstop.

  The reference kappa is 0.25 standard deviations: Page's CUSUM is quickest for a shift of
  2 kappa, and wear is to be caught while its shift on the matched filter is still well
  below one standard deviation (a faster drift is crossed a few records later than with
  0.5; abrupt shifts are the shift detector's).

What the bank alone gives (bench/bench_wear.py; with the fleet CUSUM below, the product's
figures differ). FD001 train as imported (one cycle a day: R = 365, ARL 365 records, h =
4.35): the bank crosses a median 119.5 cycles before failure and alerts, once the
attribution is confident (ratio 1.3 on one record), 112.5 cycles before on 100/100 engines,
91 % HPC, against 121.5 for a naive signature CUSUM (HPC direction, reference 0.5, threshold
5, its 30-record baseline taken as exact: a false alarm on 43 % of white-noise engines
within 350 armed records where the bank crosses on 28 %). The demo fleet (R about 1485, h =
6.10): 0.04 false wear alerts per engine-year. Alone, the bank misses the lead target twice
over: the crossing itself, at the budget met from a stretch's start, trails the naive CUSUM
by 2 cycles, and the attribution waits 7 more: at the crossing the tuner change names LPC on
about a quarter of the engines (LPC and HPC deterioration look alike in the tuners). At h =
4.35 ratio 1.2 on one record gives 115.5 cycles at 88 % HPC, 1.3 on two records 108.5 at 92
%, 1.5 on one 106.0 at 94 %. Explored on the threshold met at one engine-year only (h =
3.22, crossing 125.5 cycles ahead; ratio 1.5 on one record 114.5 at 91 %, 1.3 120.0 at 86 %)
and no better at 90 % HPC or more: attributing the mean tuner change of the last 5-20
records; the WSSR summed over the records since the crossing; the sensor-space WSSR of the
mean sensor deviation since the baseline (53 % HPC: the design's noise variances are far
from FD001's); the tuner change that fits that mean deviation by least squares (70 % at
1.5); the filter covariance's inverse as the weight (76 %); the tuner trend over the last 30
records (a slope with an intercept, free of the baseline's error: 97 % HPC at ratio 1.5 but
110 cycles; either it or the record's change at 1.5: 121.0 at 90 %; at h = 4.35, either at
1.3: 116.0 at 91 %); other bank references and allowances (kappa 0.1-0.5, alpha 0-0.2, each
with its threshold met at one engine-year: crossings 123-127 cycles ahead, alerts 109-115 at
ratio 1.5).
The fleet CUSUM (``fleet``; docs/math.md section 13): a design's engines wear along their
own mix of the library's faults, learnt from the other engines, never the one scored. An
engine's drift theta (``latest_drift``) is its latest stretch's change, the mean of its last
``drift_tail`` armed tuner estimates less x_0, as candidate magnitudes by the weighted
least-squares fit on the candidates together (``fault_drift``); the fleet direction for an
engine is v = mean of the other engines' unit drifts, normalised (``fleet_direction``; at
least ``fleet_min`` of them, and v attributed to a fault: ``learnt_direction``). A stretch
adopts v at its first record and keeps it; its matched filter along the signature G_k v
(``along``) is the bank's last column, standardised as the bank's candidates are. The budget
is split (``_budgets``): ``fleet_share`` = 0.9 to the fleet CUSUM (calibrated as a bank of
one: h = 2.83 on FD001), 0.1 to the bank (h = 6.95). Its alert names the fault v's tuner
change H v is attributed to (``fleet_fault``, confident at ``confidence``), at the first
record after its crossing whose own change is of the fleet's kind (``_fleet_like``:
attributed to that fault, or fitted by H v within ``fleet_fit`` times the best candidate's
WSSR): an abrupt fault of another module is left to the shift detector. FD001 through the
product (bench/bench_wear.py): 100/100 engines, median 121.5 cycles before failure, 99 %
HPC, against the naive's 121.5 (parity); without the change-kind condition 122.0, fleet_fit
1.0 121.0, fleet_share 0.75 120.0; v for unit 1 from the other 99: HPC 0.87, LPC 0.43, HPT
-0.18, Fan 0.12, LPT -0.03, attributed to HPC. Before it entered the product the bench
measured the same idea with the drift fitted on the sensor deviations (121.0, its alert at
the crossing) and the library's HPC signature as the direction (117.0): the learnt direction
fits FD001's wear better than the library's fault. ``wear_scan`` (this module's batch form)
has no fleet CUSUM: the bank alone.
Tried on an earlier design (Siegmund's threshold, ARL 2000 records) and no better by more
than a cycle or two at the same false alerts: a GLR for a ramp or step onset (level unknown,
or known up to the baseline's error), a shorter settle or baseline, a longer bank baseline, a
running (successive-difference) scatter estimate, smoothing the tuner change before
attribution.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

LIMIT = "limit"
RATE = "rate"
DIRECTIONAL = "directional"
FLEET = "fleet"


@dataclass(frozen=True)
class WearSettings:
    """Settings of the wear detector.

    settle: records after a start or reset left out of the baseline (filter transient);
    n_base: records averaged into the baseline x_0;
    limit: accumulated magnitude (times the nominal library shift) that alerts;
    limit_share: the least share of the change (``explained``) the fault must explain then;
    rate: CUSUM reference rho, nominal magnitudes per cycle (above the fleet's normal rate);
    margin: CUSUM threshold in baseline standard deviations of f_i;
    margin_floor: smallest CUSUM threshold (nominal magnitudes), for a very quiet baseline;
    bank_reference: the directional bank's kappa (standard deviations);
    bank_alpha: the level of the allowance for the bank baseline's own estimation error
    (0: none, mu_i and s_i taken as exact);
    false_alerts_per_year: the bank's designed false crossings per engine-year, which set
    its threshold h with the engine's record rate (module docstring);
    bank_calibrated: h from the bank's Monte Carlo calibration (else Siegmund's with
    Bonferroni);
    records_per_year: the nominal record rate, used where the records carry no time (or
    too few to measure it over the baseline);
    bank_arl: the bank's family-wise mean run length to a false crossing (records) instead
    of records per year / false alerts per year; bank_threshold: h itself (standard
    deviations) instead;
    bank_rate: the bank's allowed drift rho_z (standard deviations per cycle);
    confidence, hold: the WSSR ratio the directional alert's attribution needs, and on how
    many consecutive records (confidence <= 0: no condition, the alert at the crossing);
    rate_with_bank: whether the rate CUSUM alerts too when the bank runs (by default the
    bank replaces it: on the demo fleet the rate alerts were the false ones).
    """

    settle: int = 20
    n_base: int = 30
    limit: float = 1.0
    # The least part of the change the attributed fault must explain for a limit alert. On
    # bench/bench_wear.py the demo fleet's one false wear alert was a limit alert whose fault
    # explained 10 % of the change; its true one (a Fan fault the shift detector missed) 93 %.
    limit_share: float = 0.5
    # Chosen on bench/bench_wear.py: the demo fleet's false wear alerts fall below one per
    # engine-year from margin ~10 on; a lower margin or rate buys FD001 lead for more of them.
    rate: float = 1.0e-3
    margin: float = 10.0
    margin_floor: float = 0.03
    # A slow drift (module docstring); on bench/bench_wear.py 0.25 gives FD001 2.5 cycles more
    # lead than 0.5 (103.5 against 101.0) with the same false alerts (demo fleet, steady fleet).
    bank_reference: float = 0.25
    bank_alpha: float = 0.05
    # The budget (at most 1 false wear alert per engine-year on healthy stretches),
    # the threshold calibrated to meet it at every horizon from a stretch's start
    # (``calibrated_threshold``): the demo fleet's measured false wear alerts 0.04 per
    # engine-year, the healthy steady fleet's 0.3 (bench/bench_wear.py, test_wear_events.py).
    # Designed for 0.5 (h = 5.16 at one record a day) the FD001 lead is 110.5 cycles.
    false_alerts_per_year: float = 1.0
    # Two snapshots a flight (take-off and cruise), two flights a day: the demo fleet's.
    records_per_year: float = 4.0 * 365.25
    bank_arl: float | None = None
    bank_threshold: float | None = None
    bank_calibrated: bool = True
    bank_rate: float = 1.0e-3
    # The attribution's wait after a crossing (a crossing is necessary, so the false alerts
    # are the bank's design). On bench/bench_wear.py (FD001, h = 4.35) ratio 1.3 on one
    # record: 112.5 cycles at 91 % HPC; 1.2 on one 115.5 at 88 %, 1.3 on two 108.5 at 92 %.
    confidence: float = 1.3
    hold: int = 1
    rate_with_bank: bool = False
    # The fleet CUSUM (``fleet_direction``): its share of the false-alert budget where it
    # runs (the bank keeps the rest), and the latest records whose mean is an engine's drift.
    # The split 0.9 / 0.1 and the tail of 20 records as chosen on the bench's FD001 leads
    # before the fleet CUSUM entered the product (bench/README.md: shares 0.75 and 0.5 and
    # tails of 10 and 40 records gave no more lead).
    fleet_share: float = 0.9
    drift_tail: int = 20
    # Fewer other engines with a drift: no fleet direction (a direction of one or two engines
    # is theirs, not the fleet's; on the bench ten FD001 units gave the whole fleet's within
    # cos 0.97).
    fleet_min: int = 5
    # The fleet alert needs the engine's own change to be the fleet's kind of wear: attributed
    # to the fleet's fault, or the fleet direction fitting it within this WSSR ratio of the
    # best candidate (``_fleet_like``; <= 0: no condition). Without it an abrupt fault of
    # another module crossed the fleet CUSUM first and was named as the fleet's fault
    # (tests/support/test_detection_replay.py). The attribution's own ratio (``confidence``);
    # 1.0 measured half a cycle less FD001 lead (bench/README.md).
    fleet_fit: float = 1.3


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
    change: np.ndarray | None = None  # d = x - x_0 at the record (``wear_steps``' alerts)


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


def explained(wssr: np.ndarray | float, total: np.ndarray | float) -> np.ndarray:
    """The share of a change d that a fault of WSSR_i explains, 1 - WSSR_i / d^T W d (``total``
    the change's own d^T W d, broadcast against ``wssr``; ``attribute``'s WSSR_i is what the
    fault leaves of it); 0 for no change."""
    wssr, total = np.broadcast_arrays(np.asarray(wssr, float), np.asarray(total, float))
    ok = total > 0
    return np.where(ok, np.maximum(1.0 - wssr / np.where(ok, total, 1.0), 0.0), 0.0)


def change_energy(wssr: np.ndarray, f: np.ndarray, W: np.ndarray, H: np.ndarray) -> np.ndarray:
    """d^T W d of each change from one fault's fit: WSSR_i + h_i^T W h_i f_i^2 (the same for
    every fault i of a row; ``attribute``). wssr, f [K, n] -> [K, n]."""
    a = np.einsum("mn,mn->n", H, np.asarray(W) @ H)  # h_i^T W h_i
    return np.asarray(wssr) + a * np.asarray(f) ** 2


def attributable(f: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """The faults wear may be attributed to: candidates fitted with a positive magnitude (wear
    moves a module in its deterioration direction). f [..., n], candidates [n] -> bool."""
    return np.asarray(candidates, bool) & (np.asarray(f) > 0)


def best_fault(wssr: np.ndarray, f: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Index of the attributed fault per row: smallest WSSR among the candidates with f > 0
    (-1 where none). wssr, f [K, n], candidates [n] bool -> [K] int."""
    allowed = attributable(f, candidates[None, :])
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


def siegmund_arl(k: float, h: float) -> float:
    """Siegmund's approximation of Page's CUSUM mean run length on white N(0, 1) records,
    reference k > 0 and threshold h (standard deviations): (exp(2kb) - 2kb - 1) / (2k^2),
    b = h + 1.166."""
    a = 2.0 * k * (h + 1.166)
    return float((np.expm1(a) - a) / (2.0 * k * k))


@dataclass(frozen=True)
class BankDesign:
    """The directional bank's standardisation and threshold: u = (z - mu) / (scale s)
    - reference - drift, crossing at G > threshold."""

    reference: float
    scale: float
    threshold: float


FLOWN_GAP_S = 30 * 86400.0  # longer gaps between records are time on the ground
YEAR_S = 365.25 * 86400.0


def record_rate(epoch: np.ndarray) -> float | None:
    """Records per engine-year flown from the records' times (seconds): the gaps shorter than
    ``FLOWN_GAP_S`` counted and summed (None with no such time: fewer than two records, or
    all at one instant)."""
    gaps = np.diff(np.asarray(epoch, float))
    flown = gaps[(gaps >= 0) & (gaps < FLOWN_GAP_S)]
    span = float(np.sum(flown))
    return len(flown) * YEAR_S / span if span > 0 else None


def bank_arl(cfg: WearSettings, records_per_year: float | None = None) -> float:
    """The bank's family-wise mean run length to a false crossing (records): ``bank_arl`` if
    set, else the record rate (measured, or the nominal ``records_per_year``) over the
    designed false alerts per engine-year."""
    if cfg.bank_arl is not None:
        return cfg.bank_arl
    rate = cfg.records_per_year if records_per_year is None else records_per_year
    return rate / cfg.false_alerts_per_year


@functools.lru_cache(maxsize=4096)
def bank_design(
    cfg: WearSettings, n: int, records_per_year: float | None = None
) -> BankDesign:
    """The bank of n candidate CUSUMs as the settings design it (module docstring), for an
    engine with ``records_per_year`` records a year (None: the nominal rate). With
    ``bank_calibrated`` the threshold is the Monte Carlo one (``calibrated_threshold``), else
    (or where the calibration has too few crossings to tell) Siegmund's with Bonferroni.
    A function of its arguments alone, asked for on every armed run of records: kept."""
    ref, scale = _reference_scale(cfg.bank_reference, cfg.bank_alpha, cfg.n_base)
    if cfg.bank_threshold is not None:
        return BankDesign(ref, scale, cfg.bank_threshold)
    arl = bank_arl(cfg, records_per_year)
    if cfg.bank_calibrated:
        year = cfg.records_per_year if records_per_year is None else records_per_year
        h = calibrated_threshold(max(n, 1), ref, scale, cfg.n_base, cfg.bank_rate, arl, year)
        if h is not None:
            return BankDesign(ref, scale, h)
    return BankDesign(ref, scale, siegmund_threshold(ref, max(n, 1) * arl))


def siegmund_threshold(reference: float, arl: float) -> float:
    """h with Siegmund's ARL(reference, h) = arl (bisection)."""
    lo, hi = 0.0, 1.0
    while siegmund_arl(reference, hi) < arl:
        lo, hi = hi, 2.0 * hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if siegmund_arl(reference, mid) < arl else (lo, mid)
    return hi


# The bank's calibration (``calibrated_threshold``): seeded white engines, their running
# maximum of the bank's largest CUSUM kept at a geometric grid of horizons.
CALIBRATION_ENGINES = 2000
CALIBRATION_RECORDS = 512
CALIBRATION_SEED = 20261125
CALIBRATION_MIN_CROSSINGS = 50  # fewer simulated crossings at a level: that horizon not checked


@dataclass(frozen=True)
class BankCalibration:
    """Running maxima of the bank's largest CUSUM on white engines: ``horizons`` [K] armed
    records, ``maxima`` [K, N] sorted over the N engines at each horizon."""

    horizons: np.ndarray
    maxima: np.ndarray


class CalibrationStore(Protocol):
    """Where computed calibration tables are kept between processes: the arrays ``build``
    returns for ``key``, kept or built."""

    def __call__(self, key: Mapping[str, Any], build: Callable[[], Mapping[str, np.ndarray]]
                 ) -> Mapping[str, np.ndarray]: ...


_store: CalibrationStore | None = None


def keep_calibrations(store: CalibrationStore | None) -> None:
    """Keep the bank's calibrations in ``store`` (None: in this process only). Each table is
    a pure function of its arguments, so a kept one is the one this process would compute."""
    global _store
    if store is not _store:
        _store = store
        bank_calibration.cache_clear()


@functools.lru_cache(maxsize=16)
def bank_calibration(
    n: int, reference: float, scale: float, n_base: int, drift: float,
    engines: int = CALIBRATION_ENGINES, records: int = CALIBRATION_RECORDS,
    seed: int = CALIBRATION_SEED,
) -> BankCalibration:
    """The bank of n CUSUMs on seeded white matched-filter outputs (independent candidates),
    standardised as the bank is: mean and standard deviation from n_base records, u =
    (z - mu) / (scale s) - reference - drift t (t armed records, one a cycle), Page's CUSUM
    from the first armed record. A table computed once per design (about a second), not per
    engine; read from the ``keep_calibrations`` store when one is set."""
    args = (n, reference, scale, n_base, drift, engines, records, seed)
    if _store is None:
        return _simulated_calibration(*args)
    key = dict(zip(("n", "reference", "scale", "n_base", "drift", "engines", "records",
                    "seed"), args, strict=True))

    def build() -> dict[str, np.ndarray]:
        cal = _simulated_calibration(*args)
        return {"horizons": cal.horizons, "maxima": cal.maxima}

    kept = _store(key, build)
    return BankCalibration(np.asarray(kept["horizons"]), np.asarray(kept["maxima"]))


def _simulated_calibration(
    n: int, reference: float, scale: float, n_base: int, drift: float, engines: int,
    records: int, seed: int,
) -> BankCalibration:
    rng = np.random.default_rng(seed)
    horizons = np.unique(np.geomspace(8, records, 64).astype(int))
    maxima = np.empty((len(horizons), engines))
    t = np.arange(1.0, records + 1.0)[None, :, None]
    chunk = 50
    for a in range(0, engines, chunk):
        w = rng.normal(size=(min(chunk, engines - a), n_base + records, n))
        base = w[:, :n_base]
        u = (w[:, n_base:] - base.mean(axis=1, keepdims=True)) / (
            scale * base.std(axis=1, ddof=1, keepdims=True))
        u -= reference + drift * t
        C = np.cumsum(u, axis=1)
        G = C - np.minimum(np.minimum.accumulate(C, axis=1), 0.0)
        top = np.maximum.accumulate(G.max(axis=2), axis=1)
        maxima[:, a : a + len(w)] = top[:, horizons - 1].T
    maxima.sort(axis=1)
    return BankCalibration(horizons, maxima)


def calibrated_threshold(
    n: int, reference: float, scale: float, n_base: int, drift: float, arl: float,
    horizon: float,
) -> float | None:
    """The bank's threshold for a family-wise mean run length ``arl`` (records) to a false
    crossing, met at every horizon up to ``horizon`` armed records (one engine-year of them):
    the smallest h that a white engine crosses within T armed records with probability at
    most 1 - exp(-T / arl), as for an exponential run length of mean arl, for every simulated
    T up to min(horizon, simulated records) (``bank_calibration``, the baseline's own errors
    included). The run lengths are not exponential (an engine with an unlucky baseline
    crosses early), so the short horizons bind: the rate holds from a stretch's start, not
    only over a whole engine-year. Horizons with fewer than ``CALIBRATION_MIN_CROSSINGS``
    simulated crossings at their level are not checked; None if no horizon is."""
    cal = bank_calibration(n, round(reference, 12), round(scale, 12), n_base, drift)
    N = cal.maxima.shape[1]
    T = cal.horizons.astype(float)
    p = -np.expm1(-T / arl)
    use = np.flatnonzero((T <= min(horizon, T[-1])) & (p * N >= CALIBRATION_MIN_CROSSINGS))
    if not len(use):
        return None
    # np.quantile's linear interpolation on the sorted rows, all horizons at once.
    pos = (1.0 - p[use]) * (N - 1)
    lo = np.floor(pos).astype(int)
    hi = np.minimum(lo + 1, N - 1)
    at_lo, at_hi = cal.maxima[use, lo], cal.maxima[use, hi]  # the two maxima each needs
    q = at_lo + (pos - lo) * (at_hi - at_lo)
    return float(q.max())


@functools.lru_cache(maxsize=64)
def _reference_scale(reference: float, alpha: float, n_base: int) -> tuple[float, float]:
    """The bank's reference and statistic scale of ``bank_design`` (the baseline's errors at
    level ``alpha``; a design asked for on every stretch, so kept)."""
    from scipy import stats

    ref, scale = reference, 1.0
    if alpha > 0:
        ref += float(stats.norm.isf(alpha) / np.sqrt(n_base))
        dof = n_base - 1
        scale = float(np.sqrt(dof / stats.chi2.ppf(alpha, dof)))
    return ref, scale


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
    epoch: np.ndarray | None = None,
) -> WearScan:
    """Scan one engine's estimates for wear (see the module docstring for the equations).

    x [S, m] estimates (time order); H [m, n] fault directions; W [m, m] attribution weight;
    cycles [S] the engine's cycle count at each record (non-decreasing within a stretch;
    two records of one flight share it); resets [S] bool, True where a maintenance action
    (or a new start) precedes the record; candidates [n] bool, the faults wear may be
    attributed to and whose drift is watched (default all). With the records' sensor
    deviations dy [S, ny], their noise variances var [ny] or [S, ny] and the faults' sensor
    signatures [ny, n] or [S, ny, n] (the same faults as H's columns), the directional bank
    runs too; the first alert of a stretch, of whichever kind, is the one reported. With
    the records' times epoch [S] (seconds) the bank's threshold is designed for the record
    rate of each stretch's first settle + n_base records (``record_rate``), else for the
    nominal ``records_per_year``.
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
    n_cand = int(cand.sum())
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
        rate = None if epoch is None else record_rate(np.asarray(epoch, float)[s0:b1])
        design = bank_design(cfg, n_cand, rate)
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
        at = (np.arange(len(f)), np.maximum(best, 0))
        mag = np.where(best >= 0, f[at], 0.0)
        share = np.where(best >= 0, explained(wssr, change_energy(wssr, f, W, H))[at], 0.0)
        armed = np.arange(s0, s1) >= b1
        rate_hit = armed[b1 - 1 - s0 :] & np.any((g > delta) & cand, axis=1)
        limit_hit = armed & (mag >= cfg.limit) & (share >= cfg.limit_share)
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
            u = (zs - base.mean(axis=0)) / np.where(sd > 0, design.scale * sd, np.inf)
            u -= design.reference + cfg.bank_rate * (cycles[s0:s1, None] - cycles[b1 - 1])
            G = np.zeros_like(u)
            G[b1 - s0 :] = _cusum(u[b1 - s0 :])  # from the baseline's end, as the rate CUSUM
            bank_all[s0:s1] = G
            crossed = np.maximum.accumulate(armed & np.any((G > design.threshold) & cand, 1))
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
                statistic=bank_stat, threshold=design.threshold, baseline_start=b0,
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


def health_candidates(S_full: np.ndarray, p: int) -> np.ndarray:
    """Library faults that are module deteriorations (no actuator-bias rows in the fault
    matrix S_full [p + biases, n]): the faults wear may be attributed to."""
    return np.all(np.asarray(S_full)[p:] == 0.0, axis=0)


def wear_hypotheses(
    library: Sequence[tuple[str, Mapping[str, float]]], health: Sequence[str]
) -> tuple[str, ...]:
    """``health_candidates`` by name, for a design read back from storage: of the library's
    (name, shifts) faults, those whose every non-zero shift is one of the design's health
    parameters ``health`` (a shift of any other name is an actuator bias, a row of S_full
    below the health parameters)."""
    known = set(health)
    return tuple(name for name, shifts in library
                 if all(k in known for k, v in shifts.items() if v != 0.0))


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


# --- Record-by-record form (the pipeline's): the same alerts as ``wear_scan``, its state carried
# from one run of records to the next, so a run split anywhere equals one uninterrupted run.
#
# Every per-record figure depends on that record and the stretch's baseline only (f, WSSR,
# C_k = f_k - rho c_k, z_k), and what carries over is exact under any grouping: the baseline's
# rows (until it is complete), running minima, latched flags, and the bank's cumulative sums
# in integer units of BANK_QUANTUM standard deviations (an integer sum does not depend on where
# it was split; a float cumsum does in its last bits).

BANK_QUANTUM = 2.0**-24  # the bank's u_k are summed as integer multiples of this

Rows = tuple[tuple[float, ...], ...]


@dataclass(frozen=True)
class WearDetector:
    """What the recursion needs besides the records: fault directions H [m, n], attribution
    weight W [m, m], the candidates [n] bool and the settings (see ``wear_scan``)."""

    H: np.ndarray
    W: np.ndarray
    candidates: np.ndarray
    settings: WearSettings = WearSettings()


@dataclass(frozen=True)
class WearState:
    """One engine's wear detector between records.

    cycle: the engine's cycle count at its last record; k: records of the current stretch so
    far; x_rows / z_rows / t_rows: the tuner baseline's rows, the bank baseline's
    matched-filter rows and the times of the stretch's records (``record_rate``) while they
    are collected; once the tuner baseline is complete: x0 [m], delta [n] (rate
    CUSUM thresholds), c_min [n] (running minimum of C_i since the baseline's last record),
    c_b (that record's cycle), mu, sd [n] (bank standardisation), bank_sum, bank_min [n]
    (the bank's cumulative sum and its running minimum, integers), crossed and bank_stat (the
    bank's latch and its largest CUSUM at the crossing), bank_h (the bank's threshold for the
    record rate measured over the baseline; None in states stored before it was: the
    nominal rate's), recent (best fault, confident) of the
    last hold - 1 records; alerted: the stretch has had its alert (x0 kept). direction: the
    fleet direction [n] the stretch adopted at its first record (``learnt_direction``; None:
    no fleet CUSUM this stretch), its CUSUM the bank's last column (z_rows, mu, sd,
    bank_sum, bank_min then have n + 1 entries), fleet_h its threshold, fleet_crossed its
    latch; drift: the engine's latest change in fault magnitudes (``latest_drift``), what
    the fleet learns from."""

    cycle: float = 0.0
    k: int = 0
    x_rows: Rows = ()
    z_rows: Rows = ()
    t_rows: tuple[float, ...] = ()
    x0: tuple[float, ...] | None = None
    delta: tuple[float, ...] = ()
    c_min: tuple[float, ...] = ()
    c_b: float = 0.0
    mu: tuple[float, ...] = ()
    sd: tuple[float, ...] = ()
    bank_sum: tuple[int, ...] = ()
    bank_min: tuple[int, ...] = ()
    crossed: bool = False
    bank_stat: float = 0.0
    bank_top: int = -1
    recent: tuple[tuple[int, bool], ...] = ()
    alerted: bool = False
    bank_h: float | None = None
    direction: tuple[float, ...] | None = None
    fleet_h: float | None = None
    fleet_crossed: bool = False
    drift: tuple[float, ...] | None = None


@dataclass(frozen=True)
class WearRun:
    """A run of records through ``wear_steps``: the alerts (``index`` into the run's
    records), the state after each record asked for (index, state) and the state after
    the last."""

    alerts: tuple[WearAlert, ...]
    states: tuple[tuple[int, WearState], ...]
    state: WearState


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a [K, m] times b [m, n] -> [K, n], each element summed over m in the same order
    whatever K (einsum's own loop; BLAS blocking may depend on the number of rows; the
    split-invariance test in tests/estimation/test_wear.py holds it to that)."""
    return np.einsum("km,mn->kn", a, b)


def _rowsum(a: np.ndarray) -> np.ndarray:
    """Sum over the last axis, term by term in order (see ``_rowdot``)."""
    out = np.zeros(a.shape[:-1])
    for j in range(a.shape[-1]):
        out += a[..., j]
    return out


def _attribute_rows(d: np.ndarray, W: np.ndarray, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``attribute`` with every row's sums independent of the other rows."""
    WH = W @ H
    a = (H * WH).sum(axis=0)
    b = _rowdot(d, WH)
    c = _rowsum(_rowdot(d, W) * d)
    ok = a > 0
    f = np.where(ok, b / np.where(ok, a, 1.0), 0.0)
    return np.maximum(c[:, None] - b * f, 0.0), f


def matched_rows(dy: np.ndarray, var: np.ndarray, signatures: np.ndarray) -> np.ndarray:
    """``matched_filter`` with every record's sums independent of the other records: dy [S, ny]
    (NaN = missing), var [S, ny], signatures [ny, n] or [S, ny, n] -> z [S, n]
    (``matched_sums``)."""
    sig = np.asarray(signatures, float)
    return matched_sums(dy, var, _record_last(sig), np.zeros(sig.shape[-1], bool))[0]


def _record_last(signatures: np.ndarray) -> np.ndarray:
    """Signatures [ny, n] (one for all records) or [S, ny, n] laid out as ``matched_sums``
    takes them: [ny, n, 1] or [ny, n, S]."""
    sig = np.asarray(signatures, float)
    return sig[..., None] if sig.ndim == 2 else np.ascontiguousarray(sig.transpose(1, 2, 0))


def _complete(det: WearDetector, st: WearState) -> WearState:
    """The tuner baseline just completed (``st.x_rows`` full): x0, thresholds, the rate
    CUSUM's zero at this record, the bank's standardisation, and the confidence of the
    baseline's last hold - 1 records (``confident_fault`` looks back over them)."""
    cfg = det.settings
    xb = np.asarray(st.x_rows, float)
    x0 = xb.mean(axis=0)
    wssr, f = _attribute_rows(xb - x0, det.W, det.H)
    sigma = f.std(axis=0, ddof=1)
    delta = np.maximum(cfg.margin * sigma, cfg.margin_floor)
    c_last = f[-1] - cfg.rate * st.cycle
    zb = np.asarray(st.z_rows, float)
    mu = zb.mean(axis=0) if len(zb) else np.zeros(0)
    sd = zb.std(axis=0, ddof=1) if len(zb) > 1 else np.zeros(0)
    lag = max(cfg.hold, 1) - 1
    recent: tuple[tuple[int, bool], ...] = ()
    if lag:
        best, ok = _confident_rows(det, wssr[-lag:], f[-lag:])
        recent = tuple(zip(best.tolist(), ok.tolist(), strict=True))
    n = det.H.shape[1] + (st.direction is not None)
    rate = record_rate(np.asarray(st.t_rows, float)) if len(st.t_rows) else None
    bank_cfg, fleet_cfg = _budgets(cfg, st.direction is not None)
    h = bank_design(bank_cfg, int(np.sum(det.candidates)), rate).threshold
    fleet_h = None if fleet_cfg is None else bank_design(fleet_cfg, 1, rate).threshold
    return WearState(
        cycle=st.cycle, k=st.k, x0=tuple(x0.tolist()), delta=tuple(delta.tolist()),
        c_min=tuple(c_last.tolist()), c_b=st.cycle, mu=tuple(mu.tolist()),
        sd=tuple(sd.tolist()), bank_sum=(0,) * n, bank_min=(0,) * n, recent=recent,
        bank_h=h, direction=st.direction, fleet_h=fleet_h,
    )


def _budgets(cfg: WearSettings, fleet: bool) -> tuple[WearSettings, WearSettings | None]:
    """The bank's settings and the fleet CUSUM's (None without it): with the fleet CUSUM the
    false-alert budget is split, ``fleet_share`` of it to the fleet CUSUM, the rest to the
    bank (the two together within the budget at every horizon, a union bound)."""
    if not fleet:
        return cfg, None

    def part(share: float) -> WearSettings:
        return replace(cfg, false_alerts_per_year=cfg.false_alerts_per_year * share,
                       bank_arl=None if cfg.bank_arl is None else cfg.bank_arl / share)

    return part(1.0 - cfg.fleet_share), part(cfg.fleet_share)


def _confident_rows(
    det: WearDetector, wssr: np.ndarray, f: np.ndarray, best: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per row: the best fault (``best_fault``, given or computed) and whether it beats every
    other candidate by the ratio (``confident_fault`` before its hold)."""
    cand = det.candidates
    if best is None:
        best = best_fault(wssr, f, cand)
    if det.settings.confidence <= 0:
        return best, np.ones(len(best), bool)
    rows = np.arange(len(best))
    w_best = np.where(best >= 0, wssr[rows, np.maximum(best, 0)], np.inf)
    others = cand[None, :] & (np.arange(wssr.shape[1])[None, :] != best[:, None])
    runner_up = np.where(others, wssr, np.inf).min(axis=1)
    return best, (best >= 0) & (runner_up >= det.settings.confidence * w_best)


def _active(
    det: WearDetector, st: WearState, x: np.ndarray, cycles: np.ndarray,
    z: np.ndarray | None, offset: int, b0: int, hold: np.ndarray | None = None,
) -> tuple[WearState, WearAlert | None]:
    """Records of a stretch after its baseline (armed; ``st`` holds the baseline): the
    state after them, or after the first alert and that alert; no alert on a record
    ``hold`` marks (an alert due there waits for the first record after)."""
    cfg = det.settings
    cand = det.candidates
    x0 = np.asarray(st.x0, float)
    d = x - x0
    wssr, f = _attribute_rows(d, det.W, det.H)
    C = f - cfg.rate * cycles[:, None]  # f_i = a_i^T d
    c_min = np.minimum(np.minimum.accumulate(C, axis=0), np.asarray(st.c_min)[None, :])
    g = C - c_min
    delta = np.asarray(st.delta, float)
    best = best_fault(wssr, f, cand)
    rows = np.arange(len(best))
    at = (rows, np.maximum(best, 0))
    mag = np.where(best >= 0, f[at], 0.0)
    share = np.where(best >= 0, explained(wssr, change_energy(wssr, f, det.W, det.H))[at], 0.0)
    limit_hit = (mag >= cfg.limit) & (share >= cfg.limit_share)
    rate_hit = np.any((g > delta) & cand, axis=1)
    use_bank = z is not None
    if use_bank and not cfg.rate_with_bank:
        rate_hit[:] = False
    bank_hit = np.zeros(len(x), bool)
    fleet_hit = np.zeros(len(x), bool)
    fleet_stat = np.zeros(len(x))
    fleet_over = np.full(len(x), st.fleet_crossed)
    crossed = np.full(len(x), st.crossed)
    bank_sum = np.asarray(st.bank_sum, np.int64)
    bank_min = np.asarray(st.bank_min, np.int64)
    G = np.zeros_like(C)
    named = best
    if z is not None:
        design = bank_design(cfg, int(np.sum(cand)))
        if st.bank_h is not None:
            design = replace(design, threshold=st.bank_h)
        sd = np.asarray(st.sd, float)
        u = (z - np.asarray(st.mu)) / np.where(sd > 0, design.scale * sd, np.inf)
        u -= design.reference + cfg.bank_rate * (cycles[:, None] - st.c_b)
        steps = np.rint(u / BANK_QUANTUM).astype(np.int64)
        csum = bank_sum[None, :] + np.cumsum(steps, axis=0)
        cmin = np.minimum(np.minimum.accumulate(csum, axis=0), bank_min[None, :])
        G = (csum - cmin) * BANK_QUANTUM
        bank_sum, bank_min = csum[-1], cmin[-1]
        over = np.any((G[:, : len(cand)] > design.threshold) & cand, axis=1)
        if st.direction is not None and st.fleet_h is not None:
            fleet_stat = G[:, len(cand)]
            fleet_over = st.fleet_crossed | np.logical_or.accumulate(fleet_stat > st.fleet_h)
            named_fleet = fleet_fault(det, np.asarray(st.direction))
            fleet_hit = fleet_over & _fleet_like(det, st.direction, d, wssr, f, best,
                                                 named_fleet) & (named_fleet >= 0)
        G = G[:, : len(cand)]
        crossed = st.crossed | np.logical_or.accumulate(over)
        lag = max(cfg.hold, 1) - 1
        named, ok = _confident_rows(det, wssr, f, best)
        prev_best = np.array([b for b, _ in st.recent], dtype=np.int64)
        prev_ok = np.array([o for _, o in st.recent], dtype=bool)
        all_best = np.concatenate([prev_best, named])
        all_ok = np.concatenate([prev_ok, ok])
        held = all_ok.copy()
        P = len(prev_best)
        for j in range(1, lag + 1):
            held[j:] &= all_ok[:-j] & (all_best[:-j] == all_best[j:])
            held[:j] = False
        bank_hit = crossed & held[P:]
    hit = limit_hit | rate_hit | bank_hit | fleet_hit
    if hold is not None:
        hit &= ~hold
    if not hit.any():
        new_cross = crossed[-1] and not st.crossed
        kc = int(np.argmax(crossed)) if new_cross else -1
        return replace(_carry(det, st, cycles[-1], len(x), c_min[-1], bank_sum, bank_min,
                              crossed[-1], G, kc, named, ok if z is not None else None),
                       fleet_crossed=bool(fleet_over[-1])), None
    k = int(np.argmax(hit))
    kinds = [kind for kind, h in ((DIRECTIONAL, bank_hit), (LIMIT, limit_hit), (RATE, rate_hit))
             if h[k]]
    kind = FLEET if fleet_hit[k] else min(kinds)
    if kind == FLEET:
        assert st.direction is not None and st.fleet_h is not None
        fault = fleet_fault(det, np.asarray(st.direction))
        alert = WearAlert(
            index=offset + k, kind=kind, fault=fault, wssr=wssr[k], f=f[k],
            magnitude=float(f[k, fault]), statistic=float(fleet_stat[k]), threshold=st.fleet_h,
            baseline_start=b0, change=d[k],
        )
    elif kind == DIRECTIONAL:
        if st.crossed:
            stat = st.bank_stat
            top_fault = st.bank_top
        else:
            kc = int(np.argmax(crossed))
            top = np.where(cand, G[kc], -np.inf)
            stat, top_fault = float(np.max(top)), int(np.argmax(top))
        fault = int(named[k]) if named[k] >= 0 else top_fault
        alert = WearAlert(
            index=offset + k, kind=kind, fault=fault, wssr=wssr[k], f=f[k],
            magnitude=float(f[k, fault]), statistic=stat,
            threshold=_bank_threshold(det, st),
            baseline_start=b0, change=d[k],
        )
    else:
        gk = g[k]
        i = int(np.argmax(np.where(cand, gk - delta, -np.inf)))
        alert = WearAlert(
            index=offset + k, kind=kind, fault=int(best[k]) if best[k] >= 0 else None,
            wssr=wssr[k], f=f[k], magnitude=float(mag[k]), statistic=float(gk[i]),
            threshold=float(delta[i]), baseline_start=b0, change=d[k],
        )
    return WearState(cycle=float(cycles[-1]), k=st.k + len(x), alerted=True, x0=st.x0,
                     direction=st.direction), alert


def _fleet_like(
    det: WearDetector, direction: tuple[float, ...], d: np.ndarray, wssr: np.ndarray,
    f: np.ndarray, best: np.ndarray, named: int,
) -> np.ndarray:
    """Per record: whether the engine's own change d [K, m] is the fleet's kind of wear: it
    is attributed to the fleet's fault, or the fleet direction's tuner change H v fits it
    (f > 0) with a WSSR within ``fleet_fit`` times the best candidate's (f > 0)."""
    ratio = det.settings.fleet_fit
    if ratio <= 0:
        return np.ones(len(d), bool)
    w_v, f_v = attribute(d, det.W, (det.H @ np.asarray(direction, float))[:, None])
    allowed = det.candidates[None, :] & (f > 0)
    w_best = np.where(allowed, wssr, np.inf).min(axis=1)
    return (best == named) | ((f_v[:, 0] > 0) & (w_v[:, 0] <= ratio * w_best))


def _bank_threshold(det: WearDetector, st: WearState) -> float:
    """The bank's threshold of the stretch: the state's, else the nominal rate's."""
    if st.bank_h is not None:
        return st.bank_h
    return bank_design(det.settings, int(np.sum(det.candidates))).threshold


def _carry(
    det: WearDetector, st: WearState, cycle: float, n: int, c_min: np.ndarray,
    bank_sum: np.ndarray, bank_min: np.ndarray, crossed: bool, G: np.ndarray, kc: int,
    named: np.ndarray, ok: np.ndarray | None,
) -> WearState:
    """The state after an armed run of n records without an alert."""
    stat, top = st.bank_stat, st.bank_top
    if kc >= 0:
        row = np.where(det.candidates, G[kc], -np.inf)
        stat, top = float(np.max(row)), int(np.argmax(row))
    recent = st.recent
    lag = max(det.settings.hold, 1) - 1
    if ok is not None and lag:
        recent = (*st.recent, *zip(named.tolist(), ok.tolist(), strict=True))[-lag:]
    return WearState(
        cycle=float(cycle), k=st.k + n, x0=st.x0, delta=st.delta,
        c_min=tuple(c_min.tolist()), c_b=st.c_b, mu=st.mu, sd=st.sd,
        bank_sum=tuple(int(v) for v in bank_sum), bank_min=tuple(int(v) for v in bank_min),
        crossed=bool(crossed), bank_stat=stat, bank_top=top, recent=recent, bank_h=st.bank_h,
        direction=st.direction, fleet_h=st.fleet_h,
    )


def _stretch_steps(
    det: WearDetector, st: WearState, x: np.ndarray, cycles: np.ndarray,
    z: np.ndarray | None, offset: int, t: np.ndarray | None = None,
    hold: np.ndarray | None = None,
) -> tuple[WearState, WearAlert | None]:
    """Records of one stretch (no reset among them but perhaps at the first, already
    applied to ``st``): collect the baselines, complete them, scan the armed records (no
    alert on those ``hold`` marks)."""
    cfg = det.settings
    n = len(x)
    if st.alerted or n == 0:
        last = cycles[-1] if n else st.cycle
        return replace_state(st, cycle=float(last), k=st.k + n), None
    b1 = cfg.settle + cfg.n_base
    kk = st.k + np.arange(n)
    b0 = offset - st.k + cfg.settle  # the baseline's first record, as an index of this run
    if st.x0 is None:
        take = (kk >= cfg.settle) & (kk < b1)
        x_rows = st.x_rows + tuple(map(tuple, x[take].tolist()))
        z_rows = st.z_rows
        if z is not None:
            z_rows = z_rows + tuple(map(tuple, z[kk < cfg.n_base].tolist()))
        t_rows = st.t_rows
        if t is not None:
            t_rows = t_rows + tuple(t[kk < b1].tolist())
        done = np.flatnonzero(kk == b1 - 1)
        if not len(done):
            return WearState(cycle=float(cycles[-1]), k=st.k + n, x_rows=x_rows,
                             z_rows=z_rows, t_rows=t_rows, direction=st.direction), None
        j = int(done[0])
        st = _complete(det, WearState(cycle=float(cycles[j]), k=st.k + j + 1, x_rows=x_rows,
                                      z_rows=z_rows, t_rows=t_rows, direction=st.direction))
        x, cycles = x[j + 1 :], cycles[j + 1 :]
        z = None if z is None else z[j + 1 :]
        hold = None if hold is None else hold[j + 1 :]
        offset += j + 1
        if not len(x):
            return st, None
    return _active(det, st, x, cycles, z, offset, b0, hold)


def replace_state(st: WearState, **changes: object) -> WearState:
    return replace(st, **changes)  # type: ignore[arg-type]


def wear_steps(
    det: WearDetector, state: WearState, x: np.ndarray, new_cycle: np.ndarray,
    resets: np.ndarray, z: np.ndarray | None = None, keep: Sequence[int] = (),
    epoch: np.ndarray | None = None, direction: np.ndarray | None = None,
    zf: np.ndarray | None = None, hold: np.ndarray | None = None,
) -> WearRun:
    """Continue one engine's wear detector over a run of records.

    x [S, m] tuner estimates; new_cycle [S] bool, True where a record starts a new cycle
    (flight: the cycle count advances by one); resets [S] bool (a maintenance action before
    the record: a new stretch); z [S, n] the records' matched-filter projections
    (``matched_rows``; None: no directional bank). The states after the records ``keep``
    (indices) are returned too; epoch [S] the records' times (seconds: the bank's threshold
    designed for the record rate over each stretch's baseline; None: the nominal rate).
    Alerts are ``wear_scan``'s for the same records when the
    first record is the engine's first (cycles as counted here; tests/estimation/test_wear.py).
    With a fleet ``direction`` [n] (``fleet_direction``) and the records' projections zf [S]
    on its signature (``along``), a stretch that starts in this run (a reset, or an engine's
    first record) adopts it and runs the fleet CUSUM as the bank's last column, the budget
    split (``_budgets``); a stretch under way keeps what it adopted at its start.
    hold [S] bool (None: none): records on which no alert is raised, the CUSUMs going on (the
    pipeline holds wear alerts while the shift detector confirms an alarm, and restarts the
    stretch where that alarm becomes an event).
    """
    if direction is not None and zf is not None and z is not None:
        fleet = tuple(np.asarray(direction, float).tolist())
        z_f: np.ndarray | None = np.column_stack([np.asarray(z, float), np.asarray(zf, float)])
    else:
        fleet, z_f = None, None
    x = np.asarray(x, float)
    cycles = state.cycle + np.cumsum(np.asarray(new_cycle, bool)).astype(float)
    resets = np.asarray(resets, bool)
    S = len(x)
    if det.H.shape[1] == 0:  # an empty fault library: no wear to attribute, cycles counted
        return WearRun((), tuple((j, replace(state, cycle=float(cycles[j]))) for j in keep),
                       replace(state, cycle=float(cycles[-1])) if S else state)
    cuts = sorted({0, S, *np.flatnonzero(resets).tolist(), *(j + 1 for j in keep)})
    alerts: list[WearAlert] = []
    states: list[tuple[int, WearState]] = []
    want = set(keep)
    st = state
    if st == WearState(cycle=st.cycle, drift=st.drift):  # an engine's first record
        st = replace(st, direction=fleet)
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        if b <= a:
            continue
        if resets[a]:
            st = WearState(cycle=st.cycle, direction=fleet)
        if st.direction is not None and st.direction != fleet and z is not None:
            raise ValueError("a stretch under way keeps its fleet direction: give it, with zf")
        zs = z if st.direction is None else z_f
        st, alert = _stretch_steps(det, st, x[a:b], cycles[a:b],
                                   None if zs is None else zs[a:b], a,
                                   None if epoch is None else np.asarray(epoch, float)[a:b],
                                   None if hold is None else np.asarray(hold, bool)[a:b])
        if alert is not None:
            alerts.append(alert)
        if b - 1 in want:
            states.append((b - 1, st))
    return WearRun(tuple(alerts), tuple(states), st)


# --- The fleet direction: what the engines of a design have worn along, learnt from the
# other engines' own estimates (docs/math.md, wear: the fleet CUSUM).


def fault_drift(det: WearDetector, change: np.ndarray) -> np.ndarray:
    """A tuner change [m] as candidate-fault magnitudes [n] (zero for the others): the
    weighted least-squares fit theta = (H_c^T W H_c)^-1 H_c^T W d on the candidates'
    directions together (the change split over the modules, not one fault at a time)."""
    Hc = det.H[:, det.candidates]
    theta = np.linalg.lstsq(Hc.T @ det.W @ Hc, Hc.T @ det.W @ np.asarray(change, float),
                            rcond=None)[0]
    out = np.zeros(det.H.shape[1])
    out[det.candidates] = theta
    return out


def latest_drift(
    det: WearDetector, state: WearState, x: np.ndarray, resets: np.ndarray
) -> tuple[float, ...] | None:
    """An engine's drift after a run of records x [S, m] from ``state`` (resets [S]): the
    change of its latest stretch in fault magnitudes (``fault_drift``), the mean of its last
    ``drift_tail`` armed records less the stretch's baseline x_0. Fewer armed records in
    the run: the state's drift if the stretch goes on (else None)."""
    cfg = det.settings
    b1 = cfg.settle + cfg.n_base
    x = np.asarray(x, float)
    cut = np.flatnonzero(np.asarray(resets, bool))
    kept = state.drift
    if len(cut):
        state, x, kept = WearState(), x[cut[-1] :], None
    k = state.k + np.arange(len(x))
    if state.x0 is not None:
        x0 = np.asarray(state.x0, float)
    else:
        rows = [*state.x_rows, *x[(k >= cfg.settle) & (k < b1)]]
        if len(rows) < cfg.n_base:
            return kept
        x0 = np.mean(rows, axis=0)
    armed = x[k >= b1]
    if len(armed) < cfg.drift_tail:
        return kept
    return tuple(fault_drift(det, armed[-cfg.drift_tail :].mean(axis=0) - x0).tolist())


def fleet_direction(
    drifts: Sequence[np.ndarray | tuple[float, ...]], least: int = 1
) -> np.ndarray | None:
    """The fleet's wear direction [n] from other engines' drifts: the mean of their unit
    drifts (each engine counted alike, however far it has worn), itself of unit length; None
    with fewer than ``least`` drifts (``WearSettings.fleet_min``) or drifts that cancel."""
    units = [d / np.linalg.norm(d) for d in (np.asarray(v, float) for v in drifts)
             if np.linalg.norm(d) > 0]
    if not units or len(units) < least:
        return None
    v = np.mean(units, axis=0)
    size = float(np.linalg.norm(v))
    return v / size if size > 0 else None


def learnt_direction(
    det: WearDetector, drifts: Sequence[np.ndarray | tuple[float, ...]]
) -> tuple[float, ...] | None:
    """The fleet direction a stretch adopts from the other engines' drifts: the
    ``fleet_direction`` of at least ``fleet_min`` of them, if it is attributed to a fault
    (``fleet_fault``); None otherwise (the bank then keeps the whole budget)."""
    v = fleet_direction(drifts, det.settings.fleet_min)
    if v is None or fleet_fault(det, v) < 0:
        return None
    return tuple(v.tolist())


def fleet_fault(det: WearDetector, direction: np.ndarray) -> int:
    """The fault the fleet direction is attributed to: the WSSR attribution (``attribute``)
    of its tuner change H v against the library, if confident (the runner-up's WSSR at least
    ``confidence`` times the best's); -1 otherwise (its crossing then waits, as the bank's,
    for the engine's own change to be attributed)."""
    wssr, f = attribute(det.H @ np.asarray(direction, float), det.W, det.H)
    best, ok = _confident_rows(det, wssr, f)
    return int(best[0]) if ok[0] else -1


@dataclass(frozen=True)
class MatchedParts:
    """A run's records' matched-filter sums on the candidate faults, from which the projection
    along any direction of them follows (``along``): num [S, c] = G_c^T R^-1 dy and gram
    [S, c, c] = G_c^T R^-1 G_c (present sensors only)."""

    num: np.ndarray
    gram: np.ndarray


def matched_parts(
    dy: np.ndarray, var: np.ndarray, signatures: np.ndarray, candidates: np.ndarray
) -> MatchedParts:
    """``MatchedParts`` of dy [S, ny] (NaN = missing), var [S, ny] and the signatures [ny, n]
    or [S, ny, n], each record's sums independent of the others (``matched_sums``)."""
    return matched_sums(dy, var, _record_last(signatures), candidates)[1]


def matched_sums(
    dy: np.ndarray, var: np.ndarray, signatures_t: np.ndarray, candidates: np.ndarray
) -> tuple[np.ndarray, MatchedParts]:
    """``matched_rows`` and ``matched_parts`` of the same records in one pass, bit for bit,
    from signatures laid out record-last: dy [S, ny] (NaN = missing), var [S, ny] (or [ny]) and
    signatures_t [ny, n, S] (each record's own) or [ny, n, 1] (one for all) -> (z [S, n],
    parts). Every record's sums are taken with the same operations in the same order as
    there, but sensor by sensor over contiguous runs of records rather than over a fault
    axis of a few numbers per record; the gram's lower triangle is its upper's (the same
    products)."""
    dy_t = np.asarray(dy, float).T
    w = 1.0 / np.broadcast_to(np.asarray(var, float), dy_t.T.shape).T
    present = np.isfinite(dy_t)
    wd = np.where(present, w * np.where(present, dy_t, 0.0), 0.0)  # [ny, S]
    wp = np.where(present, w, 0.0)
    ny, n = signatures_t.shape[:2]
    S = dy_t.shape[1]
    cand = np.flatnonzero(candidates)
    ia, ib = np.triu_indices(len(cand))
    num, den = np.zeros((n, S)), np.zeros((n, S))
    gram_u = np.zeros((len(ia), S))
    term, pair = np.empty((n, S)), np.empty((len(ia), S))
    for j in range(ny):
        s_j = signatures_t[j]  # [n, S or 1]
        num += np.multiply(wd[j], s_j, out=term)
        den += np.multiply(wp[j], np.multiply(s_j, s_j, out=term), out=term)
        s_c = s_j[cand]
        gram_u += np.multiply(wp[j], np.multiply(s_c[ia], s_c[ib], out=pair), out=pair)
    z = (num / np.sqrt(np.maximum(den, 1e-300))).T
    gram = np.empty((S, len(cand), len(cand)))
    gram[:, ia, ib] = gram_u.T
    gram[:, ib, ia] = gram_u.T
    return z, MatchedParts(num[cand].T, gram)


def along(parts: MatchedParts, direction: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """The matched filter along a direction of fault magnitudes v [n] (signature G v):
    z_k = v^T G^T R^-1 dy_k / sqrt(v^T G^T R^-1 G v) [S]."""
    v = np.asarray(direction, float)[candidates]
    num = np.zeros(len(parts.num))
    den = np.zeros(len(parts.num))
    for i in range(len(v)):
        num += v[i] * parts.num[:, i]
        for j in range(len(v)):
            den += v[i] * v[j] * parts.gram[:, i, j]
    return num / np.sqrt(np.maximum(den, 1e-300))
