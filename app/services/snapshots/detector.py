"""The shift detector's app edge: its state as stored (JSON in ``FilterState.state`` and the
checkpoints) and its isolations as event drafts.

The detector itself (baseline, CUSUM, sensor-space isolation, record by record and batched)
is ``estimation.shift_detector``; here its frozen state is written and read (``document``,
``from_document``; states written before, with the history as lists of numbers, still read)
and an ``Isolation`` becomes an ``EventDraft`` with the design's fault, tuner and health names.
The wear detector (``estimation.wear``, record by record) is the second kind: its state is
written and read here too (``wear_document``, ``wear_from_document``) and its alerts become
``wear`` events (``wear_event``).
"""

from __future__ import annotations

import base64
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from app.services.snapshots.estimator import SnapshotEstimator
from estimation.shift_detector import Isolation, PendingAlarm, Rows, SensorFit, ShiftState
from estimation.wear import WearAlert, WearState, attributable

HISTORY_FORMAT = "float64-le-base64"


def document(state: ShiftState) -> dict[str, Any]:
    """The detector state as stored.

    The history (N_BASE + GAP estimates of m tuners) goes as its float64 bytes in base64
    (``HISTORY_FORMAT``), exact and a third of the JSON numbers' length: PostgreSQL parses
    a filter state per engine and job, and 270 numbers were most of it."""
    return {"history": _history_document(state.history), "S": state.S,
            "pending": None if state.pending is None else _pending_document(state.pending),
            "s_mean": state.s_mean, "s_count": state.s_count, "warm": state.warm}


def from_document(d: Mapping[str, Any]) -> ShiftState:
    """A stored detector state (``document``, or the formats written before)."""
    s_mean = d.get("s_mean")
    pending = d.get("pending")
    return ShiftState(_history_from(d["history"]), float(d["S"]),
                      None if pending is None else _pending_from(pending),
                      None if s_mean is None else float(s_mean), int(d.get("s_count", 0)),
                      int(d.get("warm", 0)))


def _pending_document(p: PendingAlarm) -> dict[str, Any]:
    out: dict[str, Any] = {"seq": p.seq, "epoch": p.epoch, "statistic": p.statistic,
                           "wait": p.wait, "baseline": list(p.baseline)}
    if p.P is not None:
        out["P"] = [list(row) for row in p.P]
    if p.fit is not None:
        out["fit"] = {"a": list(p.fit.a), "b": list(p.fit.b), "c": p.fit.c, "n": p.fit.n}
    return out


def _pending_from(d: Mapping[str, Any]) -> PendingAlarm:
    P, fit = d.get("P"), d.get("fit")
    return PendingAlarm(
        int(d["seq"]), float(d["epoch"]), float(d["statistic"]), int(d["wait"]),
        tuple(map(float, d["baseline"])), None if P is None else _rows(P),
        None if fit is None else SensorFit(tuple(map(float, fit["a"])),
                                           tuple(map(float, fit["b"])), float(fit["c"]),
                                           int(fit["n"])),
    )


def _rows(values: Any) -> Rows:
    return tuple(tuple(map(float, row)) for row in values)


def _history_document(history: Rows) -> dict[str, Any]:
    rows = np.asarray(history, dtype="<f8")
    return {"format": HISTORY_FORMAT, "rows": len(history),
            "data": base64.b64encode(rows.tobytes()).decode("ascii")}


def _history_from(document: Any) -> Rows:
    """A stored history: the base64 document, or the lists of numbers states held before."""
    if isinstance(document, Mapping):
        if document.get("format") != HISTORY_FORMAT:
            raise ValueError(f"detector history: unknown format {document.get('format')!r}")
        values = np.frombuffer(base64.b64decode(document["data"]), dtype="<f8")
        rows = int(document["rows"])
        return _rows(values.reshape(rows, -1).tolist()) if rows else ()
    return _rows(document)


class EventDraft(NamedTuple):
    seq: int
    epoch: float
    kind: str
    fault: str | None
    magnitude: float | None
    statistic: float
    wssr: dict[str, float]
    shift: dict[str, Any]


def event(est: SnapshotEstimator, iso: Isolation) -> EventDraft | None:
    """The event of an alarm's isolation, or None when it was dropped.

    An ``isolated_fault`` when the smallest WSSR is consistent with its fault, the fitted
    magnitude is plausible and the fault explains enough of the change
    (``shift_detector.Isolation.isolated``); an unexplained ``shift`` when the change is still
    large (its Mahalanobis distance exceeds the isolation's threshold); otherwise the alarm is
    dropped (model error, not a fault).
    """
    if iso.dropped:
        return None
    names = est.layout.faults
    best, isolated = iso.nearest, iso.isolated
    f, change = iso.f, iso.change
    h_change = est.Vp @ change
    fault_shift = {}
    if isolated and best is not None:
        fault_shift = {k: round(float(v * f[best]), 4) for k, v in est.fault_shifts[best].items()}
    return EventDraft(
        seq=int(iso.alarm.seq),
        epoch=float(iso.alarm.epoch),
        kind="isolated_fault" if isolated else "shift",
        fault=names[best] if isolated and best is not None else None,
        magnitude=float(f[best]) if isolated and best is not None else None,
        statistic=float(iso.alarm.statistic),
        wssr={n: float(w) for n, w in zip(names, iso.wssr, strict=True)},
        shift={
            "tuners": {n: float(v) for n, v in zip(est.layout.tuners, change, strict=True)},
            "health": {n: float(v) for n, v in zip(est.layout.health, h_change, strict=True)},
            "fault": fault_shift,
            "wssr_threshold": iso.wssr_threshold,
            "wssr_dof": iso.wssr_dof,
            "wssr_scale": iso.wssr_scale,
            "nearest": names[best] if best is not None else None,
            "distance": iso.distance,
        },
    )


def wear_document(state: WearState) -> dict[str, Any]:
    """The wear detector's state as stored: its fields as JSON numbers (a float's shortest
    repr reads back to the same float; the baseline rows exist only for the first ~50
    records of a stretch)."""
    return {
        "cycle": state.cycle, "k": state.k, "x_rows": [list(r) for r in state.x_rows],
        "z_rows": [list(r) for r in state.z_rows], "t_rows": list(state.t_rows),
        "x0": None if state.x0 is None else list(state.x0), "delta": list(state.delta),
        "c_min": list(state.c_min), "c_b": state.c_b, "mu": list(state.mu),
        "sd": list(state.sd), "bank_sum": list(state.bank_sum),
        "bank_min": list(state.bank_min), "crossed": state.crossed,
        "bank_stat": state.bank_stat, "bank_top": state.bank_top,
        "recent": [[b, ok] for b, ok in state.recent], "alerted": state.alerted,
        "bank_h": state.bank_h,
        "direction": None if state.direction is None else list(state.direction),
        "fleet_h": state.fleet_h, "fleet_crossed": state.fleet_crossed,
        "drift": None if state.drift is None else list(state.drift),
    }


def wear_from_document(d: Mapping[str, Any] | None) -> WearState:
    """A stored wear state (``wear_document``); none (states written before the wear detector
    ran) is a fresh one: the engine's next records start its baseline. States stored before
    the record rate was measured (no ``t_rows``, ``bank_h``) read with none: the bank's
    threshold is then the nominal rate's; those stored before the fleet CUSUM (no
    ``direction``, ``fleet_h``, ``drift``) read without it until the engine's next stretch."""
    if d is None:
        return WearState()

    def floats(key: str) -> tuple[float, ...]:
        return tuple(float(v) for v in d[key])

    x0 = d.get("x0")
    bank_h = d.get("bank_h")

    def optional(key: str) -> tuple[float, ...] | None:
        v = d.get(key)
        return None if v is None else tuple(float(x) for x in v)

    return WearState(
        cycle=float(d["cycle"]), k=int(d["k"]), x_rows=_rows(d["x_rows"]),
        z_rows=_rows(d["z_rows"]), t_rows=tuple(float(v) for v in d.get("t_rows", ())),
        x0=None if x0 is None else tuple(map(float, x0)),
        delta=floats("delta"), c_min=floats("c_min"), c_b=float(d["c_b"]), mu=floats("mu"),
        sd=floats("sd"), bank_sum=tuple(int(v) for v in d["bank_sum"]),
        bank_min=tuple(int(v) for v in d["bank_min"]), crossed=bool(d["crossed"]),
        bank_stat=float(d["bank_stat"]), bank_top=int(d["bank_top"]),
        recent=tuple((int(b), bool(ok)) for b, ok in d["recent"]), alerted=bool(d["alerted"]),
        bank_h=None if bank_h is None else float(bank_h), direction=optional("direction"),
        fleet_h=None if d.get("fleet_h") is None else float(d["fleet_h"]),
        fleet_crossed=bool(d.get("fleet_crossed", False)),
        drift=optional("drift"),
    )


def wear_event(
    est: SnapshotEstimator, alert: WearAlert, seq: int, epoch: float, baseline_seq: int,
    candidates: np.ndarray,
) -> EventDraft:
    """The ``wear`` event of a wear alert: the attributed fault and its magnitude (times the
    library's nominal shift), the accumulated change since the baseline in tuners and health
    parameters (docs/math.md, wear), the WSSR of every fault for that change, and under
    ``wear`` the alert's kind (``limit``, ``rate``, ``directional``, ``fleet``), its CUSUM
    against its threshold, the baseline's first record and the hypotheses the attribution
    chose from: the wear ``candidates`` (module deteriorations) fitted with a positive
    magnitude, which the event's confidence ranks (``app.services.events.confidence``)."""
    names = est.layout.faults
    change = np.zeros(est.m) if alert.change is None else np.asarray(alert.change, float)
    fault_shift = {}
    if alert.fault is not None:
        fault_shift = {k: round(float(v * alert.magnitude), 4)
                       for k, v in est.fault_shifts[alert.fault].items()}
    return EventDraft(
        seq=seq, epoch=epoch, kind="wear",
        fault=None if alert.fault is None else names[alert.fault],
        magnitude=None if alert.fault is None else float(alert.magnitude),
        statistic=float(alert.statistic),
        wssr={n: float(w) for n, w in zip(names, alert.wssr, strict=True)},
        shift={
            "tuners": {n: float(v) for n, v in zip(est.layout.tuners, change, strict=True)},
            "health": {n: float(v)
                       for n, v in zip(est.layout.health, est.Vp @ change, strict=True)},
            "fault": fault_shift,
            "nearest": None if alert.fault is None else names[alert.fault],
            "wear": {"alert": alert.kind, "statistic": float(alert.statistic),
                     "threshold": float(alert.threshold), "baseline_seq": baseline_seq,
                     "hypotheses": [names[i] for i in np.flatnonzero(
                         attributable(alert.f, candidates))]},
        },
    )
