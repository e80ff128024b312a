"""Shift detection and fault isolation on one engine's tuner estimates, record by record.

Detection (MATH.md section 4, last paragraph): a chi-squared CUSUM (``estimation.detection``
design) runs on the tuner estimate against its baseline, s = (q_hat - q_0)^T P^-1 (q_hat - q_0)
with the filter covariance P; q_0 is the mean of ``N_BASE`` tuner estimates ending ``GAP``
records before the current one. The estimates are correlated from record to record, so the
run-length theory only orders the settings; the statistic is rescaled by its running
in-control mean (model error raises it above m) and the false-alarm rate is measured on
simulated fleets (bench/bench_detection.py, tests/support/test_detection_replay.py). After an
alarm the ``N_CONFIRM`` records that follow are fitted in sensor space: each record against
the baseline tuners, r_j = dy_j - G_y,j V*^+ q_0, and each library fault's signature at the
record's own condition (health columns through G_y, actuator biases through G_u, so a fuel-flow
or variable-geometry bias is a fault like any other) give f_i and WSSR_i of seed 002 eq. 21-23
over all those records (``accumulate_sensor_fit``: four sums a fault). The event is an
``isolated_fault`` when the smallest WSSR is below the chi-squared quantile (times
``SENSOR_WSSR_MARGIN`` for the linearisation error) and the fitted magnitude is plausible, a
``shift`` when the change is still improbable under no change, else dropped. Then the
baseline restarts. A maintenance action restarts the baseline too and widens the filter
covariance (the health may jump at a shop visit or wash); an alarm pending then is isolated on
the records there are, with the covariance from before the action.
"""

from __future__ import annotations

import base64
import copy
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from scipy import stats

from app.services.snapshots.estimator import SHIFT_LEVEL, SnapshotEstimator
from estimation.shift_scan import level_scan
from estimation.snapshot import SnapshotState

# Detector settings (records are snapshots; a flight gives one to three).
N_BASE = 30  # records averaged into the baseline
GAP = 15  # the baseline ends this many records before the alarm (the fault's onset)
N_CONFIRM = 20  # records between an alarm and its isolation (fitted in sensor space)
N_AVG = 10  # records averaged for the tuner change shown with an event
WARMUP = 60  # records after a start, maintenance or event before the detector arms
S_MEAN_RATE = 1.0 / 200.0  # memory of the in-control mean of the detector statistic
S_MEAN_CAP = 30.0  # samples above this many times m count as this much
DETECTOR_INPUT = "level"  # "level": q_hat against the baseline; "update": q_hat[k] - q_hat[k-1]
MAGNITUDE_RANGE = (0.5, 3.0)  # fitted fault magnitudes that count as that fault (x nominal)
ISOLATE_IN = "sensors"  # "sensors": records after the alarm fitted in sensor space; "tuners"
SENSOR_ISOLATION_LEVEL = 0.999  # WSSR quantile (sensor space) below which a fault explains it
# Linearisation error (health several percent from the trim) leaves a WSSR per sensor value
# above 1 even for the right fault: the quantile is scaled by this much.
SENSOR_WSSR_MARGIN = 1.5


def initial_state(est: SnapshotEstimator) -> dict[str, Any]:
    """Pipeline state before an engine's first record."""
    return {
        "filter": SnapshotState.initial(1, est.P0).to_dict(),
        "detector": {"history": [], "S": 0.0, "pending": None},
        "last_epoch": None,
    }


@dataclass
class Detector:
    """Sequential baseline, CUSUM and isolation state of one engine (JSON round trip).

    history: the last N_BASE + GAP tuner estimates, oldest first.
    """

    history: list[list[float]]
    S: float
    pending: dict[str, Any] | None
    s_mean: float | None = None
    s_count: int = 0
    warm: int = 0

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Detector:
        s_mean = d.get("s_mean")
        return cls(_history_from(d["history"]), float(d["S"]), copy.deepcopy(d.get("pending")),
                   None if s_mean is None else float(s_mean), int(d.get("s_count", 0)),
                   int(d.get("warm", 0)))

    def to_dict(self) -> dict[str, Any]:
        """A snapshot of the state, not a view: a pending alarm's fit and wait change in place
        as records arrive (a checkpoint taken during an alarm must keep the values it had).

        The history (N_BASE + GAP estimates of m tuners) goes as its float64 bytes in base64
        (``HISTORY_FORMAT``), exact and a third of the JSON numbers' length: PostgreSQL parses
        a filter state per engine and job, and 270 numbers were most of it."""
        return {"history": _history_document(self.history), "S": self.S,
                "pending": copy.deepcopy(self.pending),
                "s_mean": self.s_mean, "s_count": self.s_count, "warm": self.warm}

    def reset(self) -> None:
        self.history, self.S, self.pending, self.warm = [], 0.0, None, 0

    def baseline(self) -> np.ndarray | None:
        if len(self.history) < N_BASE + GAP:
            return None
        return np.mean(np.asarray(self.history[:N_BASE]), axis=0)


HISTORY_FORMAT = "float64-le-base64"


def _history_document(history: list[list[float]]) -> dict[str, Any]:
    rows = np.asarray(history, dtype="<f8")
    return {"format": HISTORY_FORMAT, "rows": len(history),
            "data": base64.b64encode(rows.tobytes()).decode("ascii")}


def _history_from(document: Any) -> list[list[float]]:
    """A stored history: the base64 document, or the lists of numbers states held before."""
    if isinstance(document, Mapping):
        if document.get("format") != HISTORY_FORMAT:
            raise ValueError(f"detector history: unknown format {document.get('format')!r}")
        values = np.frombuffer(base64.b64decode(document["data"]), dtype="<f8")
        rows = int(document["rows"])
        return values.reshape(rows, -1).tolist() if rows else []
    return [list(map(float, q)) for q in document]


class EventDraft(NamedTuple):
    seq: int
    epoch: float
    kind: str
    fault: str | None
    magnitude: float | None
    statistic: float
    wssr: dict[str, float]
    shift: dict[str, Any]


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


def tuner_update_statistic(
    q: np.ndarray, q_prev: np.ndarray, P: np.ndarray, P_prior: np.ndarray
) -> float:
    """s = dq^T (P_prior - P)^-1 dq for the tuner update dq = q - q_prev = K nu.

    Under no change the innovations nu are white, so dq ~ N(0, K S K^T) = N(0, P_prior - P)
    independently from record to record: chi-squared with m degrees of freedom, the
    independent samples the CUSUM's run-length theory assumes (estimation/detection.py).
    """
    C = P_prior - P
    C = 0.5 * (C + C.T)
    dq = q - q_prev
    try:
        return float(dq @ np.linalg.solve(C, dq))
    except np.linalg.LinAlgError:
        return 0.0


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


def accumulate_sensor_fit(
    est: SnapshotEstimator, pending: dict[str, Any], obs: RecordObservation
) -> None:
    """Add one record to the pending alarm's least-squares fit of each fault in sensor space.

    With r_j = dy_j - G_y,j V*^+ q_0 (the record against the baseline tuners q_0) and g_ij the
    signature of fault i at record j, the weighted fit over the records j after the alarm is
    f_i = b_i / a_i and WSSR_i = c - b_i^2 / a_i (seed 002 eq. 21-23 with H_i the stacked
    g_ij and the noise covariance diagonal), from the sums a_i = sum g^T W g,
    b_i = sum g^T W r, c = sum r^T W r and the count n of sensor values: four numbers a fault
    carry the fit, so the detector state stays small.
    """
    base = np.asarray(pending["baseline"], float)
    r = obs.dy - obs.G_y @ (est.Vp @ base)
    present = np.isfinite(r)
    if not present.any():
        return
    w = np.where(present, 1.0 / obs.var, 0.0)
    r = np.where(present, r, 0.0)
    g = np.where(present[:, None], obs.signatures, 0.0)
    a = np.einsum("i,if,if->f", w, g, g)
    b = np.einsum("i,if,i->f", w, g, r)
    fit = pending.setdefault("fit", {"a": [0.0] * len(a), "b": [0.0] * len(b), "c": 0.0,
                                     "n": 0})
    fit["a"] = (np.asarray(fit["a"]) + a).tolist()
    fit["b"] = (np.asarray(fit["b"]) + b).tolist()
    fit["c"] = float(fit["c"] + np.sum(w * r * r))
    fit["n"] = int(fit["n"] + present.sum())


def _isolate(
    est: SnapshotEstimator, pending: Mapping[str, Any], change: np.ndarray, P: np.ndarray
) -> EventDraft | None:
    """The pending alarm's event: isolated in sensor space when the records after the alarm
    were accumulated (``accumulate_sensor_fit``), else on the tuner change."""
    fit = pending.get("fit")
    if ISOLATE_IN == "sensors" and fit is not None and fit["n"] > 1:
        a, b, c, n = np.asarray(fit["a"]), np.asarray(fit["b"]), float(fit["c"]), fit["n"]
        ok = a > 0
        f = np.where(ok, b / np.where(ok, a, 1.0), 0.0)
        wssr = np.where(ok, np.maximum(c - b * f, 0.0), c)
        return _event(est, pending, change, wssr, f, P,
                      SENSOR_WSSR_MARGIN * float(stats.chi2.ppf(SENSOR_ISOLATION_LEVEL, n - 1)),
                      c, float(stats.chi2.isf(SHIFT_LEVEL, n)))
    wssr, f = wssr_all(change, P, est.H)
    distance = float(change @ np.linalg.solve(P, change))
    return _event(est, pending, change, wssr, f, P, est.wssr_threshold, distance,
                  est.shift_threshold)


def detect_step(
    est: SnapshotEstimator, det: Detector, seq: int, epoch: float, q: np.ndarray,
    P: np.ndarray, q_prev: np.ndarray, P_prior: np.ndarray, reset: bool,
    obs: RecordObservation | None = None,
) -> tuple[np.ndarray, EventDraft | None]:
    """One record through the detector: WSSR per fault against the baseline (NaN without one),
    and the event when an alarm's isolation is due."""
    nan = np.full(est.H.shape[1], np.nan)
    early: EventDraft | None = None
    if reset:
        if det.pending is not None and det.history:
            # The engine left service (or was maintained) before the alarm's isolation was
            # due: isolate on the records there are.
            pending = det.pending
            recent = det.history[-min(N_AVG, len(det.history)) :]
            change = np.mean(np.asarray(recent), axis=0) - np.asarray(pending["baseline"])
            # This record's P is already widened by the maintenance action: isolate with the
            # covariance of the records the change comes from.
            P_last = np.asarray(pending.get("P", P), float)
            early = _isolate(est, pending, change, P_last)
        det.reset()
    base_before = det.baseline()
    det.warm += 1
    det.history.append(q.tolist())
    if len(det.history) > N_BASE + GAP:
        del det.history[0]
    if det.pending is not None:
        pending = det.pending
        pending["wait"] -= 1
        pending["P"] = P.tolist()
        if obs is not None:
            accumulate_sensor_fit(est, pending, obs)
        base = np.asarray(pending["baseline"])
        wssr = wssr_all(q - base, P, est.H)[0]
        if pending["wait"] > 0:
            return wssr, None
        change = np.mean(np.asarray(det.history[-N_AVG:]), axis=0) - base
        draft = _isolate(est, pending, change, P)
        det.reset()
        return wssr, draft
    if DETECTOR_INPUT == "level":
        if base_before is None:
            det.S = 0.0
            return nan, early
        wssr_now, _f, s = wssr_and_distance(q - base_before, P, est.H)
    else:
        s = tuner_update_statistic(q, q_prev, P, P_prior)
        wssr_now = None
    # The statistic's in-control mean is m for a perfect model; model error (interpolated
    # trims, nonlinearity) makes it larger. Its running in-control mean rescales it, so the
    # CUSUM responds to a change against the engine's own normal, not to a steady mismatch.
    m = est.m
    if det.s_mean is None:
        det.s_mean = float(m)
    scaled = s * m / max(det.s_mean, m)
    if det.S == 0.0:
        # A running mean that starts as a plain average (fast) and keeps S_MEAN_RATE memory;
        # capped samples so a real change does not teach the detector to ignore it.
        det.s_count += 1
        rate = max(1.0 / det.s_count, S_MEAN_RATE)
        det.s_mean += (min(s, S_MEAN_CAP * m) - det.s_mean) * rate
    if base_before is None or det.warm < WARMUP:
        det.S = 0.0  # no baseline yet (start-up, or after a reset): nothing to compare with
        return nan, early
    det.S = max(0.0, det.S + scaled - m - est.cusum.reference)
    if det.S > est.cusum.threshold:
        det.pending = {"seq": seq, "epoch": epoch, "statistic": det.S, "wait": N_CONFIRM,
                       "baseline": base_before.tolist(), "P": P.tolist()}
        if obs is not None:
            accumulate_sensor_fit(est, det.pending, obs)
        det.S = 0.0
    if wssr_now is None:
        wssr_now = wssr_all(q - base_before, P, est.H)[0]
    return wssr_now, early


def _event(
    est: SnapshotEstimator, pending: Mapping[str, Any], change: np.ndarray, wssr: np.ndarray,
    f: np.ndarray, P: np.ndarray, wssr_threshold: float, distance: float,
    shift_threshold: float,
) -> EventDraft | None:
    """The event of an alarm, or None when the change is too small to matter.

    Isolated when the smallest WSSR is consistent with its fault and the fitted magnitude is
    a plausible fault (MAGNITUDE_RANGE times the library's nominal shift); an unexplained
    shift when the change is still large (its Mahalanobis distance under P exceeds
    ``est.shift_threshold``); otherwise the alarm is dropped (model error, not a fault).
    """
    names = est.layout.faults
    best = int(np.argmin(wssr)) if len(names) else None
    lo, hi = MAGNITUDE_RANGE
    isolated = (
        best is not None and wssr[best] <= wssr_threshold and lo <= f[best] <= hi
    )
    if not isolated and distance < shift_threshold:
        return None
    h_change = est.Vp @ change
    fault_shift = {}
    if isolated and best is not None:
        fault_shift = {k: round(float(v * f[best]), 4) for k, v in est.fault_shifts[best].items()}
    return EventDraft(
        seq=int(pending["seq"]),
        epoch=float(pending["epoch"]),
        kind="isolated_fault" if isolated else "shift",
        fault=names[best] if isolated and best is not None else None,
        magnitude=float(f[best]) if isolated and best is not None else None,
        statistic=float(pending["statistic"]),
        wssr={n: float(w) for n, w in zip(names, wssr, strict=True)},
        shift={
            "tuners": {n: float(v) for n, v in zip(est.layout.tuners, change, strict=True)},
            "health": {n: float(v) for n, v in zip(est.layout.health, h_change, strict=True)},
            "fault": fault_shift,
            "wssr_threshold": wssr_threshold,
            "nearest": names[best] if best is not None else None,
            "distance": distance,
        },
    )
