"""Replay a simulated fleet through the pipeline's detector and score it against the truth.

The fleet simulator (``estimation.engine.fleet``) knows every injected fault: which engine,
from which flight, which library fault. This module runs the pipeline's own estimation
functions (``pipeline.run_filters``, the same arithmetic as after an upload) over the
simulated snapshots of every engine, without a database, and compares the events it drafts
with that truth:

- a fault is *detected* when an event of its engine is dated between the fault's flight and
  the engine's removal (or the end of the data); the first such event is the detection, and it
  is *correctly isolated* when it is an ``isolated_fault`` naming the injected fault;
- the detection delay counts the engine's flights from the fault's flight to the event's
  (1 = the fault's own flight);
- any other event is a *false alarm* (events after the first in a fault's window are counted
  apart, as repeats).

Used by ``bench/bench_detection.py`` (the demo fleet and larger ones) and by the tests.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from app.services.designs.calibration import (  # noqa: F401  (re-exported)
    ACTUATOR_NAMES,
    EngineData,
    engine_runs,
)
from app.services.snapshots import detector, estimator
from app.services.snapshots import run as snapshots_run
from estimation.engine.fleet import FleetPlan

NONE = "-"  # confusion-table label: no event, or an event that names no fault


@dataclass(frozen=True)
class FaultOutcome:
    """What the detector made of one injected fault."""

    esn: str
    fault: str
    scale: float
    occurred_at: float
    flights_observed: int  # the engine's flights with data from the fault's on
    records_before: int  # the engine's records between its last start or maintenance and the fault
    noncentrality: float  # sum over the fault's first records of g^T R^-1 g (its visibility)
    concurrent: bool  # another fault was on the same engine (before repair) at the same time
    detected: bool
    isolated: str  # fault named by the first event, NONE for a shift or no event
    kind: str | None  # the first event's kind
    delay_flights: int | None


@dataclass
class Score:
    """Confusion of true vs isolated fault, delays and false alarms over a replay."""

    faults: list[FaultOutcome]
    false_alarms: list[tuple[str, float, str, str | None]]  # esn, epoch, kind, fault
    repeats: int
    engine_flights: int
    library: tuple[str, ...]
    events_by_kind: Counter[str] = field(default_factory=Counter)

    @property
    def scored(self) -> list[FaultOutcome]:
        """Faults the engine flew with for at least one flight (the others cannot be seen)."""
        return [f for f in self.faults if f.flights_observed > 0]

    def detectable(
        self, min_flights: int, min_records_before: int, min_noncentrality: float
    ) -> list[FaultOutcome]:
        """Faults a detector could be asked to find: alone on their engine, flown with for
        ``min_flights``, striking ``min_records_before`` records after the engine's last start
        or maintenance (its baseline exists), with a sensor signature of at least
        ``min_noncentrality`` over the first ``VISIBILITY_RECORDS`` records."""
        return [
            f for f in self.scored
            if not f.concurrent and f.flights_observed >= min_flights
            and f.records_before >= min_records_before and f.noncentrality >= min_noncentrality
        ]

    @property
    def n_detected(self) -> int:
        return sum(f.detected for f in self.scored)

    @property
    def n_correct(self) -> int:
        return sum(f.isolated == f.fault for f in self.scored)

    @property
    def false_alarms_per_1000(self) -> float:
        return 1000.0 * len(self.false_alarms) / max(self.engine_flights, 1)

    def confusion(self) -> tuple[list[str], np.ndarray]:
        """Rows: true fault (library order); columns: library faults then NONE."""
        cols = [*self.library, NONE]
        table = np.zeros((len(self.library), len(cols)), dtype=int)
        for f in self.scored:
            table[self.library.index(f.fault), cols.index(f.isolated)] += 1
        return cols, table

    def report(self) -> str:
        cols, table = self.confusion()
        width = max(6, *(len(c) + 1 for c in cols))
        lines = ["true \\ isolated".ljust(16) + "".join(c.rjust(width) for c in cols)]
        for name, row in zip(self.library, table, strict=True):
            lines.append(name.ljust(16) + "".join(str(v).rjust(width) for v in row))
        delays = [f.delay_flights for f in self.scored if f.delay_flights is not None]
        n = len(self.scored)
        lines.append(
            f"faults scored {n} (of {len(self.faults)} injected): detected {self.n_detected}, "
            f"correctly isolated {self.n_correct}"
            + (f" ({100.0 * self.n_correct / n:.0f} %)" if n else "")
        )
        if delays:
            lines.append(
                f"detection delay [flights]: median {np.median(delays):.0f}, "
                f"mean {np.mean(delays):.1f}, max {max(delays)}"
            )
        lines.append(
            f"false alarms: {len(self.false_alarms)} in {self.engine_flights} engine-flights "
            f"({self.false_alarms_per_1000:.2f} per 1000); repeats in a fault window: "
            f"{self.repeats}; events by kind: {dict(self.events_by_kind)}"
        )
        return "\n".join(lines)


def replay(
    est: estimator.SnapshotEstimator, engines: Sequence[EngineData], batch: int = 64
) -> list[list[detector.EventDraft]]:
    """The pipeline's events per engine (``pipeline.run_filters`` in batches, as stored)."""
    events: list[list[detector.EventDraft]] = []
    for start in range(0, len(engines), batch):
        runs = [e.run for e in engines[start : start + batch]]
        for out in snapshots_run.run_filters(est, runs):
            drafts = list(out.events)
            pending = out.state.detector.pending
            if pending is not None:
                # An alarm still awaiting its isolation when the data ends: detected, unnamed.
                drafts.append(detector.EventDraft(
                    pending.seq, pending.epoch, "pending", None, None, pending.statistic, {}, {},
                ))
            events.append(drafts)
    return events


VISIBILITY_RECORDS = 20


def fault_noncentrality(
    est: estimator.SnapshotEstimator, run: snapshots_run.EngineRun, at: float, fault: str,
    scale: float,
) -> float:
    """Visibility of a fault: sum_j g_j^T R_j^-1 g_j over the engine's first
    ``VISIBILITY_RECORDS`` records from ``at``, g_j the sensor change of the library fault
    (times ``scale``) through the record's scheduled gains (health through G_y, actuator
    biases through G_u) and R_j the pipeline's noise: the chi-squared noncentrality of the
    fault in those records (0 for a fault outside the estimator's library)."""
    k = np.flatnonzero(run.epoch >= at)[:VISIBILITY_RECORDS]
    if len(k) == 0 or fault not in est.layout.faults:
        return 0.0
    g = est.schedule(run.conditions[k])
    dy = est.fault_signatures(g.G_y, g.G_u)[..., est.layout.faults.index(fault)] * scale
    noise = est.noise_std if g.noise_std is None else np.sqrt(
        g.noise_std**2 + estimator.MODEL_ERROR**2)
    present = np.isfinite(run.y[k])
    return float(np.sum(np.where(present, (dy / noise) ** 2, 0.0)))


def _removal_after(plan: FleetPlan, esn: str, at: float) -> float:
    """When the engine carrying a fault from ``at`` left the wing (inf: it never did)."""
    ends = [
        i.removed_at for i in plan.installations
        if i.esn == esn and i.installed_at <= at and i.removed_at is not None and i.removed_at > at
    ]
    return min(ends) if ends else np.inf


def score(
    plan: FleetPlan, engines: Sequence[EngineData],
    events: Sequence[Sequence[detector.EventDraft]],
    library: Sequence[str], est: estimator.SnapshotEstimator | None = None,
) -> Score:
    """Compare drafted events with the plan's injected faults (see the module docstring)."""
    by_esn = {e.esn: (e, ev) for e, ev in zip(engines, events, strict=True)}
    used: set[tuple[str, float]] = set()
    outcomes = []
    repeats = 0
    windows = [
        (f.esn, f.occurred_at, _removal_after(plan, f.esn, f.occurred_at)) for f in plan.faults
    ]
    for k, fault in enumerate(plan.faults):
        data, evs = by_esn.get(fault.esn, (None, []))
        end = windows[k][2]
        concurrent = any(
            j != k and esn == fault.esn and t0 < end and fault.occurred_at < t1
            for j, (esn, t0, t1) in enumerate(windows)
        )
        in_window = [d for d in evs if fault.occurred_at <= d.epoch <= end]
        observed = 0
        before = 0
        lam = 0.0
        delay = None
        if data is not None:
            t0 = data.run.epoch
            m = data.run.maintenance
            start = max([t0[0], *m[m <= fault.occurred_at]])
            before = int(np.sum((t0 >= start) & (t0 < fault.occurred_at)))
            if est is not None:
                lam = fault_noncentrality(est, data.run, fault.occurred_at, fault.fault,
                                          fault.scale)
            t = data.run.epoch
            after = (t >= fault.occurred_at) & (t <= end)
            observed = len(np.unique(data.flight_id[after]))
            if in_window:
                first = min(in_window, key=lambda d: d.epoch)
                upto = after & (t <= first.epoch)
                delay = len(np.unique(data.flight_id[upto]))
        first_event = min(in_window, key=lambda d: d.epoch) if in_window else None
        for d in in_window:
            used.add((fault.esn, d.epoch))
        repeats += max(0, len(in_window) - 1)
        isolated = NONE
        if first_event is not None and first_event.kind == "isolated_fault" and first_event.fault:
            isolated = first_event.fault
        outcomes.append(
            FaultOutcome(
                fault.esn, fault.fault, fault.scale, fault.occurred_at, observed, before, lam,
                concurrent, first_event is not None, isolated,
                None if first_event is None else first_event.kind, delay,
            )
        )
    false_alarms = []
    kinds: Counter[str] = Counter()
    flights = 0
    for data, evs in zip(engines, events, strict=True):
        flights += len(np.unique(data.flight_id))
        for d in evs:
            kinds[d.kind] += 1
            if (data.esn, d.epoch) not in used:
                false_alarms.append((data.esn, d.epoch, d.kind, d.fault))
    return Score(outcomes, false_alarms, repeats, flights, tuple(library), kinds)
