"""Shift detection and fault isolation on one engine's tuner estimates.

Detection (docs/math.md section 4, last paragraph): a chi-squared CUSUM (``estimation.detection``)
runs on the tuner estimate against its baseline, s = (q_hat - q_0)^T P^-1 (q_hat - q_0) with
the filter covariance P; q_0 is the mean of ``N_BASE`` tuner estimates ending ``GAP`` records
before the current one. The estimates are correlated from record to record, so the run-length
theory only orders the settings; the statistic is rescaled by its running in-control mean
(model error raises it above m) and the false-alarm rate is measured on simulated fleets
(bench/bench_detection.py, tests/support/test_detection_replay.py). After an alarm the
``N_CONFIRM`` records that follow are fitted in sensor space: each record against the
baseline tuners, r_j = dy_j - G_y,j V*^+ q_0, and each library fault's signature at the
record's own condition (health columns through G_y, actuator biases through G_u, so a
fuel-flow or variable-geometry bias is a fault like any other) give f_i and WSSR_i of seed 002
eq. 21-23 over all those records (``SensorFit``: four sums a fault), each fault's magnitude
held to the plausible ``MAGNITUDE_RANGE`` of its nominal shift (``isolation.bounded_fit``):
a free fit lets a fault of weak signature win by being scaled up and reversed (a 4 % LPC
fault taken for the VBV bias at -270 times its shift) or a strong one by being scaled down
(the VSV bias taken for 0.01-0.4 of a fuel-flow, Fan, HPC or LPT fault); held to the range,
the demo design isolates 90.5 % of the seed 002 library on the built-in engine where the free
fit isolated 76.2 % (bench/bench_isolation.py, the fault's onset given). The alarm's
``Isolation`` names the fault of smallest WSSR when that is below the chi-squared quantile
(times ``SENSOR_WSSR_MARGIN`` for the linearisation error) and the fault explains
``EVIDENCE_THRESHOLD`` of the change (so a fault of no signature, which fits an unchanged
engine at any magnitude, is never named by elimination), is an unexplained shift when the
change is still improbable under no change, else is dropped.
Then the baseline restarts. A reset (a maintenance action) restarts the baseline too; an
alarm pending then is isolated on the records there are, with the covariance from before the
reset.

Two implementations of the same detector, equal bit for bit: ``shift_step`` takes one record,
``shift_scan`` a run of records (between a reset and an alarm the baselines, level statistics
and WSSR are computed at once with ``estimation.shift_scan``; only the CUSUM and its running
mean go record by record). States are frozen values (``ShiftState``, ``PendingAlarm``,
``SensorFit``); storing them is the caller's business.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import NamedTuple, Protocol

import numpy as np
from scipy import optimize, stats

from estimation.detection import CusumDesign, cusum_step
from estimation.isolation import bounded_fit
from estimation.shift_scan import level_scan, sliding_baselines

# Detector settings (records are snapshots; a flight gives one to three).
N_BASE = 30  # records averaged into the baseline
GAP = 15  # the baseline ends this many records before the alarm (the fault's onset)
N_CONFIRM = 20  # records between an alarm and its isolation (fitted in sensor space)
N_AVG = 10  # records averaged for the tuner change shown with an event
WARMUP = 60  # records after a start, maintenance or event before the detector arms
S_MEAN_RATE = 1.0 / 200.0  # memory of the in-control mean of the detector statistic
S_MEAN_CAP = 30.0  # samples above this many times m count as this much
MAGNITUDE_RANGE = (0.5, 3.0)  # fitted fault magnitudes that count as that fault (x nominal)
SENSOR_ISOLATION_LEVEL = 0.999  # WSSR quantile (sensor space) below which a fault explains it
# Linearisation error (health several percent from the trim) leaves a WSSR per sensor value
# above 1 even for the right fault: the quantile is scaled by this much.
SENSOR_WSSR_MARGIN = 1.5
SHIFT_LEVEL = 1e-6  # an unexplained change must be this improbable under no change
# The part of an alarm's sensor-space distance a named fault must explain (c - WSSR_i, one
# degree of freedom under no change): its chi-squared quantile at the isolation level.
EVIDENCE_THRESHOLD = float(stats.chi2.ppf(SENSOR_ISOLATION_LEVEL, 1))

Rows = tuple[tuple[float, ...], ...]


class ShiftModel(Protocol):
    """What the detector needs of an estimator design."""

    @property
    def H(self) -> np.ndarray: ...  # [m, n_faults] tuner change per library fault

    @property
    def Vp(self) -> np.ndarray: ...  # V*^+ [p, m]

    @property
    def m(self) -> int: ...

    @property
    def cusum(self) -> CusumDesign: ...

    @property
    def wssr_threshold(self) -> float: ...  # tuner-space WSSR quantile

    @property
    def shift_threshold(self) -> float: ...  # tuner-space distance of an unexplained shift


class RecordObservation(NamedTuple):
    """One record's measurement, for isolation in sensor space.

    dy [ny] (percent of trim, NaN = missing), G_y [ny, p], signatures [ny, n_faults] (the
    sensor change of each library fault at nominal magnitude, health and actuator-bias
    columns of the record's own gains), var [ny] (noise variance, percent^2).
    """

    dy: np.ndarray
    G_y: np.ndarray
    signatures: np.ndarray
    var: np.ndarray


@dataclass(frozen=True)
class SensorFit:
    """A pending alarm's least-squares fit of each fault in sensor space, as its sums.

    With r_j = dy_j - G_y,j V*^+ q_0 (the record against the baseline tuners q_0) and g_ij the
    signature of fault i at record j, the weighted fit over the records j after the alarm is
    f_i = b_i / a_i and WSSR_i = c - b_i^2 / a_i (seed 002 eq. 21-23 with H_i the stacked
    g_ij and the noise covariance diagonal), from a_i = sum g^T W g, b_i = sum g^T W r,
    c = sum r^T W r and the count n of sensor values.
    """

    a: tuple[float, ...]
    b: tuple[float, ...]
    c: float
    n: int

    @classmethod
    def zero(cls, n_faults: int) -> SensorFit:
        return cls((0.0,) * n_faults, (0.0,) * n_faults, 0.0, 0)

    def solve(self) -> tuple[np.ndarray, np.ndarray]:
        """WSSR_i and f_i of every fault, the magnitude held to ``MAGNITUDE_RANGE``
        (``isolation.bounded_fit``; a fault without signature: f = 0, WSSR = c)."""
        return bounded_fit(np.asarray(self.a), np.asarray(self.b), float(self.c),
                           MAGNITUDE_RANGE)


@dataclass(frozen=True)
class PendingAlarm:
    """An alarm awaiting its isolation: where it was raised, the CUSUM there, the records
    still to wait for, the baseline tuners, the latest filter covariance (None in states
    stored before it was kept) and the sensor-space fit so far (None until a record had a
    sensor value)."""

    seq: int
    epoch: float
    statistic: float
    wait: int
    baseline: tuple[float, ...]
    P: Rows | None = None
    fit: SensorFit | None = None

    def with_record(self, model: ShiftModel, obs: RecordObservation) -> PendingAlarm:
        """The alarm with one more record in its sensor-space fit."""
        base = np.asarray(self.baseline, float)
        r = obs.dy - obs.G_y @ (model.Vp @ base)
        present = np.isfinite(r)
        if not present.any():
            return self
        w = np.where(present, 1.0 / obs.var, 0.0)
        r = np.where(present, r, 0.0)
        g = np.where(present[:, None], obs.signatures, 0.0)
        a = np.einsum("i,if,if->f", w, g, g)
        b = np.einsum("i,if,i->f", w, g, r)
        fit = self.fit if self.fit is not None else SensorFit.zero(len(a))
        return replace(self, fit=SensorFit(
            tuple((np.asarray(fit.a) + a).tolist()), tuple((np.asarray(fit.b) + b).tolist()),
            float(fit.c + np.sum(w * r * r)), int(fit.n + present.sum()),
        ))


@dataclass(frozen=True)
class ShiftState:
    """The detector's state between two records.

    history: the last N_BASE + GAP tuner estimates, oldest first; S: the CUSUM; s_mean and
    s_count: the statistic's running in-control mean (None before the first baseline) and its
    sample count; warm: records since the last start, reset or event.
    """

    history: Rows = ()
    S: float = 0.0
    pending: PendingAlarm | None = None
    s_mean: float | None = None
    s_count: int = 0
    warm: int = 0

    def restarted(self) -> ShiftState:
        """After a reset or an event: no baseline, no alarm; the running mean is kept."""
        return replace(self, history=(), S=0.0, pending=None, warm=0)

    def baseline(self) -> np.ndarray | None:
        if len(self.history) < N_BASE + GAP:
            return None
        return np.mean(np.asarray(self.history[:N_BASE]), axis=0)


@dataclass(frozen=True, eq=False)
class Isolation:
    """An alarm's outcome: the tuner change since its baseline, WSSR_i and f_i of every fault
    with the threshold they are held to, the change's distance with its threshold, the least
    part of the distance a named fault must explain (``evidence_threshold``), and how a right
    fault's WSSR is distributed: chi-squared with ``wssr_dof`` degrees of freedom once divided
    by ``wssr_scale`` (the model-error margin of a sensor-space fit; what an event's
    confidence judges the fit with)."""

    alarm: PendingAlarm
    change: np.ndarray
    wssr: np.ndarray
    f: np.ndarray
    wssr_threshold: float
    distance: float
    shift_threshold: float
    evidence_threshold: float = 0.0
    wssr_dof: int = 1
    wssr_scale: float = 1.0

    @property
    def nearest(self) -> int | None:
        """The fault of smallest WSSR (None without faults)."""
        return int(np.argmin(self.wssr)) if len(self.wssr) else None

    @property
    def isolated(self) -> bool:
        """The nearest fault explains the change with a plausible magnitude
        (``MAGNITUDE_RANGE`` times the library's nominal shift), and explains a part of it
        (distance - WSSR) that noise would not: a fault of no signature fits an unchanged
        engine at any magnitude, so it is named only on evidence, never by elimination."""
        best = self.nearest
        lo, hi = MAGNITUDE_RANGE
        return bool(best is not None and self.wssr[best] <= self.wssr_threshold
                    and lo <= self.f[best] <= hi
                    and self.distance - self.wssr[best] >= self.evidence_threshold)

    @property
    def dropped(self) -> bool:
        """Neither isolated nor a change still improbable under no change (model error)."""
        return not self.isolated and self.distance < self.shift_threshold


class ShiftRun(NamedTuple):
    """A run of records through the detector: the state after it, the alarms isolated (in
    order), the states after the records at which a checkpoint is due (record index) and the
    record at which each isolation was made (index into the run, ``isolations``' order)."""

    state: ShiftState
    isolations: list[Isolation]
    checkpoints: list[tuple[int, ShiftState]]
    isolated_at: list[int]


def wssr_all(shift: np.ndarray, P: np.ndarray, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """WSSR_i and f_i of every fault for one shift (seed 002 eq. 21-23), solving with P."""
    wssr, f, _ = wssr_and_distance(shift, P, H)
    return wssr, f


def wssr_and_distance(
    shift: np.ndarray, P: np.ndarray, H: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """``wssr_all`` and the shift's squared Mahalanobis distance shift^T P^-1 shift (the
    detector's level statistic): ``level_scan`` of one record, so the record-by-record
    detector and the batched one compute the same numbers."""
    scan = level_scan(np.asarray(shift, float)[None], np.asarray(P, float)[None], H)
    return scan.wssr[0], scan.f[0], float(scan.distance[0])


def isolate(
    model: ShiftModel, alarm: PendingAlarm, change: np.ndarray, P: np.ndarray
) -> Isolation:
    """The alarm's outcome: in sensor space when the records after the alarm gave a fit of
    more than one sensor value, else on the tuner change."""
    fit = alarm.fit
    if fit is not None and fit.n > 1:
        wssr, f = fit.solve()
        n = fit.n
        return Isolation(
            alarm, change, wssr, f,
            SENSOR_WSSR_MARGIN * float(stats.chi2.ppf(SENSOR_ISOLATION_LEVEL, n - 1)),
            float(fit.c), float(stats.chi2.isf(SHIFT_LEVEL, n)), EVIDENCE_THRESHOLD,
            n - 1, SENSOR_WSSR_MARGIN,
        )
    wssr, f = wssr_all(change, P, model.H)
    distance = float(change @ np.linalg.solve(P, change))
    return Isolation(alarm, change, wssr, f, model.wssr_threshold, distance,
                     model.shift_threshold, wssr_dof=max(model.m - 1, 1))


def sensor_fit_dof(threshold: float) -> int:
    """The n - 1 degrees of freedom of a sensor-space isolation's WSSR threshold
    (``isolate``: SENSOR_WSSR_MARGIN chi2_0.999(n - 1)), read back from the threshold, for
    events stored before they were stored themselves."""
    q = threshold / SENSOR_WSSR_MARGIN
    if q <= float(stats.chi2.ppf(SENSOR_ISOLATION_LEVEL, 1)):
        return 1
    hi = 2.0
    while float(stats.chi2.ppf(SENSOR_ISOLATION_LEVEL, hi)) < q:
        hi *= 2.0
    dof = optimize.brentq(lambda d: float(stats.chi2.ppf(SENSOR_ISOLATION_LEVEL, d)) - q,
                          1.0, hi)
    return max(int(round(dof)), 1)


def _rows(a: np.ndarray) -> Rows:
    return tuple(tuple(row) for row in a.tolist())


def _kept(
    series: np.ndarray, L: int, warm0: int, i: int, S: float, s_mean: float | None,
    s_count: int, pending: PendingAlarm | None = None,
) -> ShiftState:
    """The state after record i of a run of ``shift_scan`` (its history: the last
    N_BASE + GAP estimates up to ``series[L + i]``; L history records came before the run)."""
    return ShiftState(_rows(series[max(L + i + 1 - N_BASE - GAP, 0) : L + i + 1]), S, pending,
                      s_mean, s_count, warm0 + i + 1)


def shift_step(
    model: ShiftModel, state: ShiftState, seq: int, epoch: float, q: np.ndarray,
    P: np.ndarray, reset: bool, obs: RecordObservation | None = None,
) -> tuple[ShiftState, np.ndarray, Isolation | None]:
    """One record through the detector: the state after it, the WSSR per fault against the
    baseline (NaN without one, or while the detector warms up) and the isolation of an alarm
    when one is due."""
    nan = np.full(model.H.shape[1], np.nan)
    early: Isolation | None = None
    if reset:
        if state.pending is not None and state.history:
            # The engine left service (or was maintained) before the alarm's isolation was
            # due: isolate on the records there are.
            pending = state.pending
            recent = state.history[-min(N_AVG, len(state.history)) :]
            change = np.mean(np.asarray(recent), axis=0) - np.asarray(pending.baseline)
            # This record's P is already widened by the maintenance action: isolate with the
            # covariance of the records the change comes from.
            P_last = np.asarray(P if pending.P is None else pending.P, float)
            early = isolate(model, pending, change, P_last)
        state = state.restarted()
    base_before = state.baseline()
    history = (*state.history, tuple(q.tolist()))[-(N_BASE + GAP) :]
    state = replace(state, history=history, warm=state.warm + 1)
    if state.pending is not None:
        pending = replace(state.pending, wait=state.pending.wait - 1, P=_rows(P))
        if obs is not None:
            pending = pending.with_record(model, obs)
        base = np.asarray(pending.baseline)
        wssr = wssr_all(q - base, P, model.H)[0]
        if pending.wait > 0:
            return replace(state, pending=pending), wssr, None
        change = np.mean(np.asarray(history[-N_AVG:]), axis=0) - base
        return state.restarted(), wssr, isolate(model, pending, change, P)
    if base_before is None:
        return replace(state, S=0.0), nan, early
    wssr_now, _f, s = wssr_and_distance(q - base_before, P, model.H)
    # The statistic's in-control mean is m for a perfect model; model error (interpolated
    # trims, nonlinearity) makes it larger. Its running in-control mean rescales it, so the
    # CUSUM responds to a change against the engine's own normal, not to a steady mismatch.
    m = model.m
    s_mean = float(m) if state.s_mean is None else state.s_mean
    s_count = state.s_count
    scaled = s * m / max(s_mean, m)
    if state.S == 0.0:
        # A running mean that starts as a plain average (fast) and keeps S_MEAN_RATE memory;
        # capped samples so a real change does not teach the detector to ignore it.
        s_count += 1
        rate = max(1.0 / s_count, S_MEAN_RATE)
        s_mean += (min(s, S_MEAN_CAP * m) - s_mean) * rate
    state = replace(state, s_mean=s_mean, s_count=s_count)
    if state.warm < WARMUP:
        return replace(state, S=0.0), nan, early
    S = cusum_step(state.S, scaled, m, model.cusum.reference)
    if S > model.cusum.threshold:
        alarm = PendingAlarm(seq, epoch, S, N_CONFIRM, tuple(base_before.tolist()), _rows(P))
        if obs is not None:
            alarm = alarm.with_record(model, obs)
        return replace(state, S=0.0, pending=alarm), wssr_now, early
    return replace(state, S=S), wssr_now, early


Observe = Callable[[int], RecordObservation]


def shift_steps(
    model: ShiftModel, state: ShiftState, seq0: int, epoch: np.ndarray, q: np.ndarray,
    P: np.ndarray, resets: np.ndarray, wssr: np.ndarray, observe: Observe | None = None,
    checkpoint_every: int = 0,
) -> ShiftRun:
    """n records through ``shift_step`` one at a time (the reference ``shift_scan`` equals).

    seq0: the sequence number of the first record; epoch [n], q [n, m], P [n, m, m],
    resets [n]; wssr [n, n_faults] is filled in place. observe(j): record j for the
    sensor-space fit (only called for the records an alarm fits). A checkpoint is due after
    the record whose seq + 1 is a multiple of ``checkpoint_every`` (0: none).
    """
    isolations: list[Isolation] = []
    checkpoints: list[tuple[int, ShiftState]] = []
    isolated_at: list[int] = []
    for j in range(len(q)):
        seq = seq0 + j
        obs = None if observe is None else observe(j)
        state, wssr[j], iso = shift_step(model, state, seq, float(epoch[j]), q[j], P[j],
                                         bool(resets[j]), obs)
        if iso is not None:
            isolations.append(iso)
            isolated_at.append(j)
        if checkpoint_every and (seq + 1) % checkpoint_every == 0:
            checkpoints.append((j, state))
    return ShiftRun(state, isolations, checkpoints, isolated_at)


def shift_scan(
    model: ShiftModel, state: ShiftState, seq0: int, epoch: np.ndarray, q: np.ndarray,
    P: np.ndarray, resets: np.ndarray, wssr: np.ndarray, observe: Observe | None = None,
    checkpoint_every: int = 0,
) -> ShiftRun:
    """``shift_steps`` with the same results bit for bit, batched: between a reset and an
    alarm the baselines, level statistics and WSSR of a run of records are computed at once
    (``estimation.shift_scan``) and only the CUSUM and its running mean go record by record;
    a reset or a pending alarm takes ``shift_step``."""
    n = len(q)
    depth = N_BASE + GAP
    m = model.m
    reset_at = np.flatnonzero(resets)
    isolations: list[Isolation] = []
    checkpoints: list[tuple[int, ShiftState]] = []
    isolated_at: list[int] = []
    j = 0
    while j < n:
        if state.pending is not None or resets[j]:
            seq = seq0 + j
            obs = None if observe is None else observe(j)
            state, wssr[j], iso = shift_step(model, state, seq, float(epoch[j]), q[j], P[j],
                                             bool(resets[j]), obs)
            if iso is not None:
                isolations.append(iso)
                isolated_at.append(j)
            if checkpoint_every and (seq + 1) % checkpoint_every == 0:
                checkpoints.append((j, state))
            j += 1
            continue
        # A run of records with neither reset nor pending alarm, up to the next reset or the
        # end (an alarm ends it early).
        later = reset_at[reset_at > j]
        end = int(later[0]) if len(later) else n
        L = len(state.history)
        series = np.concatenate([np.asarray(state.history, float).reshape(L, m), q[j:end]])
        first = max(depth - L, 0)  # run index of the first record with a baseline
        bases = sliding_baselines(series[: max(len(series) - GAP, 0)], N_BASE)
        # record i (run index) has history series[L + i - depth : L + i] before its append
        k0 = min(j + first, end)  # the records with a baseline: k0 ... end - 1
        with_base = bases[L + first - depth : L + first - depth + end - k0]
        scan = level_scan(q[k0:end] - with_base, P[k0:end], model.H) if end > k0 else None
        stop = end
        # The CUSUM and its running mean, record by record on Python floats, with the same
        # operations as ``shift_step`` (``b if b > a else a`` is ``max(a, b)``, NaN
        # included), in three stretches of the run (run index i): no baseline yet (the CUSUM
        # rests at 0), a baseline while the detector warms up (the running mean learns, the
        # CUSUM rests), armed (both run; from ``armed`` on, records carry their WSSR). Run
        # index i is a checkpoint when its seq + 1 is a multiple of ``checkpoint_every``.
        distance = scan.distance.tolist() if scan is not None else []
        S, s_mean0, s_count, warm0 = state.S, state.s_mean, state.s_count, state.warm
        s_mean = float(m) if s_mean0 is None else s_mean0  # set at the first baseline
        threshold, reference = model.cusum.threshold, model.cusum.reference
        cap = S_MEAN_CAP * m
        count = end - j
        learning = min(first, count)  # first record with a baseline
        armed = min(count, max(first, WARMUP - warm0 - 1))  # first with warm >= WARMUP
        next_checkpoint = (-(seq0 + j + 1) % checkpoint_every if checkpoint_every
                           else count)

        if learning > 0:
            S = 0.0
            while next_checkpoint < learning:
                at = next_checkpoint
                checkpoints.append((j + at, _kept(series, L, warm0, at, S, s_mean0, s_count)))
                next_checkpoint += checkpoint_every
        mean_rate = S_MEAN_RATE
        for i in range(learning, armed):
            if S == 0.0:
                s_k = distance[i - first]
                s_count += 1
                inverse = 1.0 / s_count
                rate = mean_rate if mean_rate > inverse else inverse
                s_mean += ((cap if cap < s_k else s_k) - s_mean) * rate
            S = 0.0
            if i == next_checkpoint:
                checkpoints.append((j + i, _kept(series, L, warm0, i, S, s_mean, s_count)))
                next_checkpoint += checkpoint_every
        pending: PendingAlarm | None = None
        for i in range(armed, count):
            s_k = distance[i - first]
            scaled = s_k * m / (m if m > s_mean else s_mean)
            if S == 0.0:
                s_count += 1
                inverse = 1.0 / s_count
                rate = mean_rate if mean_rate > inverse else inverse
                s_mean += ((cap if cap < s_k else s_k) - s_mean) * rate
            S = S + scaled - m - reference  # ``cusum_step``, inline: the same operations
            S = S if S > 0.0 else 0.0
            if S > threshold:
                jj = j + i
                pending = PendingAlarm(seq0 + jj, float(epoch[jj]), S, N_CONFIRM,
                                       tuple(with_base[i - first].tolist()), _rows(P[jj]))
                if observe is not None:
                    pending = pending.with_record(model, observe(jj))
                S = 0.0
                stop = jj + 1
                if i == next_checkpoint:
                    checkpoints.append(
                        (jj, _kept(series, L, warm0, i, S, s_mean, s_count, pending)))
                break
            if i == next_checkpoint:
                checkpoints.append((j + i, _kept(series, L, warm0, i, S, s_mean, s_count)))
                next_checkpoint += checkpoint_every
        last = stop - j - 1
        state = _kept(series, L, warm0, last, S, s_mean if last >= learning else s_mean0,
                      s_count, pending)
        wssr[j:stop] = np.nan
        if scan is not None and j + armed < stop:
            wssr[j + armed : stop] = scan.wssr[armed - first : stop - j - first]
        j = stop
    return ShiftRun(state, isolations, checkpoints, isolated_at)
