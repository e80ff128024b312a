"""The filter run: snapshots -> tuner filter -> estimates, shift detection, isolation, for
a batch of engines in memory (``estimation_runs`` reads their records and stores what it
computes).

Per record the pipeline stores q_hat, h_hat = V*^+ q_hat and z_hat = G_z V*^+ q_hat + G_zu du
(the aux outputs at the record's inputs: on the built-in engine along the power setting's
fan-speed loop, ``estimator.ScheduledGains``) with their 1-sigma (from the filter covariance
P), the innovation per sensor, and the WSSR of every library fault (seed 002 eq. 21-23) for
the tuner change against the baseline.

Between a reset and an alarm the detector's baselines, level statistics and WSSR are computed
for a run of records at once (``estimation.shift_scan``, the same sums as one record alone),
and only the CUSUM and its running mean go record by record (``estimation.shift_detector``'s
``shift_scan``; byte for byte its ``shift_step`` record by record,
tests/support/test_detection_replay.py).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from app.models.estimates import VALUE_DTYPE, Event
from app.services.snapshots import detector, rows
from app.services.snapshots.detector import EventDraft
from app.services.snapshots.estimator import FLEET_STD, MODEL_ERROR, WALK_STD, SnapshotEstimator
from estimation.shift_detector import (
    RecordObservation,
    ShiftRun,
    ShiftState,
    shift_scan,
    shift_steps,
)
from estimation.snapshot import (
    SnapshotState,
    snapshot_deviation,
    snapshot_filter,
    tuner_measurement_matrix,
)
from estimation.wear import (
    MatchedParts,
    WearDetector,
    WearSettings,
    WearState,
    along,
    health_candidates,
    health_weight,
    latest_drift,
    learnt_direction,
    matched_sums,
    wear_steps,
)

NEW_FLIGHT_S = 3600.0  # records further apart than this are different flights
# A checkpoint (the whole pipeline state, a few kB of JSON) every this many records of an
# engine: a re-run redoes at most this many records before the late one.
CHECKPOINT_EVERY = 1024
# Bytes of per-record arrays per filter call: a call takes max(64, CHUNK_BYTES // (engines x
# bytes per record)) records of each engine (``_record_bytes``: 2.3 kB a record for a six-tuner
# design of the reference model, about 29,000 records a call; larger calls measured no faster).
CHUNK_BYTES = 64 * 2**20
SIGNATURE_BLOCK = 2048  # records per block of ``_matched`` (its terms stay in cache)
# Bytes of wear input kept per call until its filters are done (``WearInput``, about 400 a
# record for the demo's design: some 330,000 records); a larger run goes in parts of whole
# engines, each part's fleet directions learning from the earlier parts' drifts too.
WEAR_BYTES = 128 * 2**20


@dataclass(frozen=True, eq=False)
class PipelineState:
    """One engine's pipeline state between records: the snapshot filter's, the shift
    detector's, the time of its last record (None before the first) and the wear detector's.
    Stored as JSON by ``store`` (``state_document``)."""

    filter: SnapshotState
    detector: ShiftState
    last_epoch: float | None
    wear: WearState = WearState()

    @classmethod
    def initial(cls, est: SnapshotEstimator) -> PipelineState:
        """Before an engine's first record."""
        return cls(SnapshotState.initial(1, est.P0), ShiftState(), None, WearState())


@dataclass
class EngineRun:
    """One engine's records to process and where it starts."""

    engine_id: int
    operator_id: int
    seq0: int
    state: PipelineState
    epoch: np.ndarray  # [S]
    phase: list[str]
    conditions: np.ndarray  # [S, 4]
    y: np.ndarray  # [S, ny] stored units, NaN = missing
    u: np.ndarray  # [S, nu]
    maintenance: np.ndarray  # epochs of the engine's maintenance actions
    redo: dict[tuple[float, str], Event] = field(default_factory=dict)  # events the run recomputes
    # What each maintenance action can move the health by (percent, ``estimator.RESET_STD``
    # of its kind); None: the fleet's spread for every one.
    maintenance_std: np.ndarray | None = None


class Checkpoint(NamedTuple):
    """The pipeline state after ``seq`` records of an engine, the last at
    ``epoch``."""

    seq: int
    epoch: float
    state: PipelineState


@dataclass
class EngineOutput:
    """What a run computed for one engine: its records' estimate numbers (the ``packed``
    blobs' values, one row per record from ``EngineRun.seq0``), events, checkpoints and the
    state after its last record."""

    values: list[np.ndarray]  # per chunk [n, width] as VALUE_DTYPE (empty with a sink)
    events: list[EventDraft]
    checkpoints: list[Checkpoint]
    state: PipelineState
    width: int = 0
    n_records: int = 0

    @property
    def packed(self) -> np.ndarray:
        """[S, width] the numbers of every record's blob (``VALUE_DTYPE``)."""
        if not self.values:
            return np.empty((0, self.width), dtype=VALUE_DTYPE)
        return np.concatenate(self.values)

    def blobs(self) -> list[bytes]:
        """Each record's ``packed`` blob, as stored."""
        return [row.tobytes() for row in self.packed]


class ChunkRecords(NamedTuple):
    """One engine's records of a chunk, for isolation in sensor space: dy [n, ny] (percent
    of trim, NaN = missing), G_y [n, ny, p], G_u [n, ny, nu] and var [n, ny] (noise
    variance, percent^2)."""

    dy: np.ndarray
    G_y: np.ndarray
    G_u: np.ndarray
    var: np.ndarray

    def observation(self, est: SnapshotEstimator, j: int) -> RecordObservation:
        """Record ``j`` with each library fault's sensor change at its own condition (health
        columns through G_y, actuator-bias columns through G_u; docs/math.md section 4, in sensor
        space), computed only for the records an alarm fits."""
        signatures = est.fault_signatures(self.G_y[j], self.G_u[j])
        return RecordObservation(self.dy[j], self.G_y[j], signatures, self.var[j])


class WearInput(NamedTuple):
    """One engine's records of a chunk as the wear detector takes them: tuner estimates q,
    new flight and reset flags, the bank's matched-filter projections z, the sums for the
    fleet direction's (``estimation.wear.matched_sums``) and the records it holds its alerts
    on (``ShiftMarks.pending``)."""

    q: np.ndarray
    new_flight: np.ndarray
    resets: np.ndarray
    z: np.ndarray
    parts: MatchedParts
    hold: np.ndarray


class ShiftMarks(NamedTuple):
    """What the wear detector takes from the shift detector over a chunk's records of an
    engine: ``pending`` [n], the records on which an alarm awaits its isolation (wear alerts
    wait: the change is the shift detector's to judge), and ``raised`` [n], the records on
    which an alarm became an event (the wear stretch restarts there: the abrupt change
    explains the step, so wear is measured from a baseline after it, the new stretch's first
    ``settle`` records left out, rather than alerting on the same step again). Both follow
    from each record's detector state alone, so they do not depend on how the records are
    split into chunks and runs."""

    pending: np.ndarray
    raised: np.ndarray


def run_filters(
    est: SnapshotEstimator, runs: Sequence[EngineRun],
    sink: Callable[[rows.Block], None] | None = None,
    fleet: Sequence[tuple[float, ...]] = (),
    wear_settings: WearSettings | None = None,
) -> list[EngineOutput]:
    """Filter, detect and pack every engine's records; engines are batched in the filter.

    Per chunk the records of every engine are laid out [engine, record] (padding rows NaN),
    scheduled in one call, filtered in one call, and their estimates derived in one pass;
    only the detector goes engine by engine. With a ``sink`` (an ``EstimateWriter``'s
    ``add``) each engine's estimates of a chunk go there as soon as they are computed instead
    of into ``EngineOutput.values``.

    The wear detector runs once the run's filters are done (``_wear_watched``): its fleet
    CUSUM's direction for an engine is learnt from the drifts of the design's other engines,
    those outside the run (``fleet``: their stored states' drifts) and the run's others.
    ``wear_settings``: the wear detector's (None: the product's, ``WearSettings()``). The
    wear input kept for that is bounded (``WEAR_BYTES``): a larger run goes in parts of whole
    engines, each part also learning from the earlier parts' drifts.
    """
    per_record = _wear_record_bytes(est)
    outputs: list[EngineOutput] = []
    learnt = list(fleet)
    part: list[EngineRun] = []
    size = 0
    for r in [*runs, None]:
        if r is None or (part and size + len(r.epoch) * per_record > WEAR_BYTES):
            done = _run_part(est, part, sink, learnt, wear_settings)
            learnt += [o.state.wear.drift for o in done if o.state.wear.drift is not None]
            outputs += done
            part, size = [], 0
        if r is not None:
            part.append(r)
            size += len(r.epoch) * per_record
    return outputs


def _wear_record_bytes(est: SnapshotEstimator) -> int:
    """Bytes of one record's ``WearInput``: q, z, the matched-filter sums and two flags."""
    n = est.S_full.shape[1]
    c = int(np.sum(health_candidates(est.S_full, len(est.layout.health))))
    return 8 * (est.m + n + c + c * c) + 2


def _run_part(
    est: SnapshotEstimator, runs: Sequence[EngineRun],
    sink: Callable[[rows.Block], None] | None, fleet: Sequence[tuple[float, ...]],
    wear_settings: WearSettings | None,
) -> list[EngineOutput]:
    """``run_filters`` on engines whose wear input fits ``WEAR_BYTES`` together."""
    if not runs:
        return []
    outputs = [EngineOutput([], [], [], r.state, est.layout.width) for r in runs]
    filt = [r.state.filter for r in runs]
    dets = [r.state.detector for r in runs]
    wear_det = wear_detector(est)
    if wear_settings is not None:
        wear_det = dataclasses.replace(wear_det, settings=wear_settings)
    wear_in: list[list[WearInput]] = [[] for _ in runs]
    last = [r.state.last_epoch for r in runs]
    longest = max((len(r.epoch) for r in runs), default=0)
    E = len(runs)
    ny = len(est.sensor_columns)
    chunk = max(64, CHUNK_BYTES // (max(E, 1) * _record_bytes(est)))
    for c0 in range(0, longest, chunk):
        c1 = min(c0 + chunk, longest)
        S = c1 - c0
        counts = np.array([max(0, min(c1, len(r.epoch)) - c0) for r in runs], dtype=np.int64)
        # The filter's row of each engine: the engines with more records first, so that the
        # padding after the shorter ones' last records is a block the filter skips.
        row = np.empty(E, dtype=np.int64)
        row[np.argsort(-counts, kind="stable")] = np.arange(E)
        present = [(r, n) for r, n in zip(runs, counts, strict=True) if n]
        y = np.concatenate([r.y[c0 : c0 + n] for r, n in present])
        u = np.concatenate([r.u[c0 : c0 + n] for r, n in present])
        # One schedule call for the chunk's records of every engine: the steady-state trims
        # are solved in one batch (a record's trim does not depend on its batch).
        g = est.schedule(np.concatenate([r.conditions[c0 : c0 + n] for r, n in present]))
        u_dev = 100.0 * (u - g.u_trim) / g.u_trim
        u_dev = np.where(np.isfinite(u_dev), u_dev, 0.0)  # a missing actuator: at trim
        dy_rec = snapshot_deviation(y, g.y_trim, g.G_u, u_dev)
        n_rec = len(dy_rec)
        noise_rec = (np.broadcast_to(est.noise_std, (n_rec, ny)) if g.noise_std is None
                     else np.sqrt(g.noise_std**2 + MODEL_ERROR**2))
        var_rec = noise_rec**2
        # The filter's layout [row, record] (padding: no sensor, the design's noise, no gain).
        dy = _per_slot(dy_rec, S, row, counts, np.nan)
        noise = (np.broadcast_to(est.noise_std, (E, S, ny)) if g.noise_std is None
                 else _per_slot(noise_rec, S, row, counts, est.noise_std))
        # The filter's measurement matrix H V*^+ of each record, laid out (less to lay out
        # than the gains in health space, and the same products as taken laid out).
        G_y = np.broadcast_to(g.G_y[0], (E, S, *g.G_y.shape[1:])) if g.constant else None
        HV = (None if g.constant
              else _per_slot(tuner_measurement_matrix(g.G_y, est.vstar), S, row, counts, 0.0))
        resets = np.zeros((E, S), dtype=bool)
        flights = np.zeros((E, S), dtype=bool)
        scale = np.zeros((E, S))
        for e, r in enumerate(runs):
            n = int(counts[e])
            if n == 0:
                continue
            epochs = r.epoch[c0 : c0 + n]
            prev = np.concatenate([[np.nan if last[e] is None else last[e]], epochs[:-1]])
            new_flight = ~(epochs - prev < NEW_FLIGHT_S)  # NaN (first record) counts as new
            maint = np.zeros(n, dtype=bool)
            widen = np.zeros(n)
            moves = (np.full(len(r.maintenance), FLEET_STD) if r.maintenance_std is None
                     else r.maintenance_std)
            for t, std in zip(r.maintenance, moves, strict=True):
                hit = (t <= epochs) & (t > prev)  # NaN prev (first record): no reset
                maint |= hit
                widen = np.maximum(widen, hit * (std / WALK_STD) ** 2)
            resets[row[e], :n] = maint
            flights[row[e], :n] = new_flight
            # A maintenance action may move the health: widen P by what it can move.
            scale[row[e], :n] = new_flight.astype(float) + widen
            last[e] = float(epochs[-1])
        by_row = np.argsort(row)
        state = SnapshotState(np.concatenate([filt[e].q_hat for e in by_row]),
                              np.concatenate([filt[e].P for e in by_row]))
        result = snapshot_filter(
            state, dy, G_y, est.vstar, est.Qq, noise, scale, keep_covariance=True,
            tuner_gains=HV,
        )
        assert result.P is not None
        q_all, P_all = result.q_hat, result.P
        h_all = q_all @ est.Vp.T
        # The estimates' other numbers from each engine's own records (no padding rows); a
        # record's products are its own stacked matrix products, whatever the records beside.
        Gz_Vp = (np.broadcast_to(g.G_z[0] @ est.Vp, (n_rec, g.G_z.shape[1], est.m))
                 if g.constant else g.G_z @ est.Vp)  # [n_rec, nz, m]
        z_u: np.ndarray | None = None
        if g.G_zu is not None:
            G_zu = np.asarray(g.G_zu)
            # Summed input by input from zero: a record's value does not depend on its batch.
            z_u = np.zeros((n_rec, G_zu.shape[-2]))
            for k in range(u_dev.shape[1]):
                z_u = z_u + G_zu[..., k] * u_dev[:, k, None]
        # The wear detector's matched filter on every record of the chunk at once (records
        # engine by engine: each engine's rows are one stretch).
        z_rec, parts_rec = _matched(est, dy_rec, var_rec, g.G_y, g.G_u,
                                    g.constant, wear_det.candidates)
        first = np.cumsum(counts) - counts
        for e, r in enumerate(runs):
            n = int(counts[e])
            if n == 0:
                continue
            i = row[e]
            q = q_all[i, :n]
            P = P_all[i, :n]
            rec = slice(int(first[e]), int(first[e]) + n)
            values = _values(est, q, P, h_all[i, :n], result.h_std[i, :n],
                             result.innovation[i, :n], Gz_Vp[rec],
                             None if z_u is None else z_u[rec])
            out = outputs[e]
            records = ChunkRecords(dy_rec[rec], _records(g.G_y, rec, g.constant),
                                   _records(g.G_u, rec, g.constant), var_rec[rec])
            dets[e], shifts = _wssr_filled(est, dets[e], r, c0, q, P, resets[i, :n], values,
                                           out, records)
            wear_in[e].append(WearInput(
                q, flights[i, :n], resets[i, :n] | shifts.raised, z_rec[rec],
                MatchedParts(parts_rec.num[rec], parts_rec.gram[rec]), shifts.pending))
            packed = values.astype(VALUE_DTYPE)
            out.n_records += n
            if sink is None:
                out.values.append(packed)
            else:
                sink((r.engine_id, r.seq0 + c0, r.epoch[c0 : c0 + n], r.phase[c0 : c0 + n],
                      packed))
            filt[e] = SnapshotState(q[-1:], P[-1:])
            out.state = PipelineState(filt[e], dets[e], last[e], r.state.wear)
    _wear_runs(est, wear_det, runs, outputs, wear_in, fleet)
    return outputs


def _wear_runs(
    est: SnapshotEstimator, det: WearDetector, runs: Sequence[EngineRun],
    outputs: Sequence[EngineOutput], wear_in: Sequence[Sequence[WearInput]],
    fleet: Sequence[tuple[float, ...]],
) -> None:
    """Every engine's wear detector over its records of the run. First each engine's drift
    after the run (``latest_drift``); an engine's fleet direction is then its stretch's own
    (one under way keeps it) or learnt from the others' drifts, its own left out
    (``fleet_direction``: the design's engines outside the run and the run's others)."""
    joined = [_joined(w) for w in wear_in]
    drifts = [r.state.wear.drift if j is None
              else latest_drift(det, r.state.wear, j.q, j.resets)
              for r, j in zip(runs, joined, strict=True)]
    for e, (r, out, j) in enumerate(zip(runs, outputs, joined, strict=True)):
        if j is None:
            continue
        direction = r.state.wear.direction
        if direction is None:
            direction = learnt_direction(det, [*fleet, *(d for i, d in enumerate(drifts)
                                                         if i != e and d is not None)])
        zf = None if direction is None else along(j.parts, np.asarray(direction),
                                                   det.candidates)
        state = _wear_watched(det, r.state.wear, r, j, out, est, direction, zf)
        out.state = dataclasses.replace(
            out.state, wear=dataclasses.replace(state, drift=drifts[e]))


@functools.lru_cache(maxsize=16)
def _wear_detector(H: bytes, W: bytes, cand: bytes, m: int, n: int) -> WearDetector:
    return WearDetector(np.frombuffer(H).reshape(m, n), np.frombuffer(W).reshape(m, m),
                        np.frombuffer(cand, dtype=bool))


def wear_detector(est: SnapshotEstimator) -> WearDetector:
    """The design's wear detector (``estimation.wear``): the library faults' tuner directions
    H, the attribution weight W = V*^+T V*^+ (a tuner change weighed as its health change)
    and the module deteriorations as candidates (no actuator biases)."""
    H = np.ascontiguousarray(est.H, dtype=float)
    W = np.ascontiguousarray(health_weight(est.Vp))
    cand = np.ascontiguousarray(health_candidates(est.S_full, len(est.layout.health)))
    return _wear_detector(H.tobytes(), W.tobytes(), cand.tobytes(), *H.shape)


def _signatures_t(est: SnapshotEstimator, G_y: np.ndarray, G_u: np.ndarray) -> np.ndarray:
    """The fault signatures of records G_y [k, ny, p], G_u [k, ny, nu] laid out record-last,
    [ny, n_faults, k]: per record the sum over the health columns, then the actuator-bias
    columns, of G_y[:, j] S_full[j] (each term one product, added in that order to zero),
    the same numbers whatever the other records; computed over contiguous runs of records.

    A fault moves a few of the columns (S_full is mostly zeros): with finite gains a zero
    coefficient's term is a zero, and adding a zero to a sum that started at +0 leaves it
    as it is, so only the fault's own terms are summed (the same numbers bit for bit)."""
    k, ny, p = G_y.shape
    n = est.S_full.shape[1]
    out = np.zeros((ny, n, k))
    if out.size == 0:  # no record, or a design whose fault library keeps no fault
        return out
    g_y = np.ascontiguousarray(G_y.reshape(k, ny * p).T).reshape(ny, p, k)
    g_u = np.ascontiguousarray(G_u.reshape(k, -1).T).reshape(ny, G_u.shape[-1], k)
    columns = [(g_y, j, est.S_full[j]) for j in range(p)]
    columns += [(g_u, b, est.S_full[p + i]) for i, b in enumerate(est.bias_inputs)]
    if np.isfinite(g_y).all() and np.isfinite(g_u).all():
        term = np.empty((ny, k))
        for f in range(n):
            acc = out[:, f]
            for g, j, row in columns:
                if row[f] != 0.0:
                    acc += np.multiply(g[:, j], row[f], out=term)
        return out
    # A gain that is not finite makes its zero-coefficient terms NaN too: every term.
    terms = np.empty((n, k))
    for i in range(ny):
        acc = out[i]
        for g, j, row in columns:
            acc += np.multiply(g[i, j], row[:, None], out=terms)
    return out


def _matched(
    est: SnapshotEstimator, dy: np.ndarray, var: np.ndarray, G_y: np.ndarray,
    G_u: np.ndarray, constant: bool, candidates: np.ndarray,
) -> tuple[np.ndarray, MatchedParts]:
    """The wear detector's matched filter of a chunk's records (dy, var [k, ny]; gains G_y
    [k, ny, p], G_u [k, ny, nu], or one record's when ``constant``): z [k, n_faults] and
    the fleet direction's sums (``estimation.wear.matched_sums``), block by block of
    records (the terms stay in cache)."""
    if constant:
        sig = _signatures_t(est, G_y[:1], G_u[:1])
        return matched_sums(dy, var, sig, candidates)
    z, num, gram = [], [], []
    for a in range(0, len(dy), SIGNATURE_BLOCK):
        b = a + SIGNATURE_BLOCK
        z_b, parts = matched_sums(dy[a:b], var[a:b], _signatures_t(est, G_y[a:b], G_u[a:b]),
                                  candidates)
        z.append(z_b)
        num.append(parts.num)
        gram.append(parts.gram)
    if len(z) == 1:
        return z[0], MatchedParts(num[0], gram[0])
    c = int(np.sum(candidates))
    return (np.concatenate(z) if z else np.zeros((0, est.S_full.shape[1])),
            MatchedParts(np.concatenate(num) if num else np.zeros((0, c)),
                         np.concatenate(gram) if gram else np.zeros((0, c, c))))


def _joined(pieces: Sequence[WearInput]) -> WearInput | None:
    """An engine's chunks of wear input as one (None without a record)."""
    if len(pieces) <= 1:
        return pieces[0] if pieces else None
    def joined(name: str) -> np.ndarray:
        return np.concatenate([getattr(p, name) for p in pieces])

    return WearInput(joined("q"), joined("new_flight"), joined("resets"), joined("z"),
                     MatchedParts(np.concatenate([p.parts.num for p in pieces]),
                                  np.concatenate([p.parts.gram for p in pieces])),
                     joined("hold"))


def _wear_watched(
    det: WearDetector, state: WearState, r: EngineRun, wi: WearInput, out: EngineOutput,
    est: SnapshotEstimator, direction: tuple[float, ...] | None, zf: np.ndarray | None,
) -> WearState:
    """Continue the engine's wear detector over its records of the run (tuner estimates q,
    the directional bank on the matched-filter projections z of the sensor deviations, and
    the fleet CUSUM on zf along ``direction``): its alerts become events, and its state goes
    into the checkpoints the shift detector wrote. Cycles are counted in flights
    (``NEW_FLIGHT_S``)."""
    base = r.seq0
    marks = out.checkpoints
    keep = [cp.seq - base - 1 for cp in marks]
    epoch = r.epoch[: len(wi.q)]
    run = wear_steps(det, state, wi.q, wi.new_flight, wi.resets, wi.z, keep, epoch,
                     None if direction is None else np.asarray(direction), zf, wi.hold)
    kept = dict(run.states)
    for i, cp in enumerate(marks):
        out.checkpoints[i] = cp._replace(
            state=dataclasses.replace(cp.state, wear=kept[cp.seq - base - 1]))
    for alert in run.alerts:
        out.events.append(detector.wear_event(
            est, alert, base + alert.index, float(epoch[alert.index]),
            base + alert.baseline_start, det.candidates))
    return run.state


def _record_bytes(est: SnapshotEstimator) -> int:
    """Bytes of a chunk's per-record arrays for one record (float64): deviations, noise,
    q_hat, P, estimates, innovations and 1-sigma, and the gains (which a constant-gain design
    does not lay out per record: there it is an upper bound)."""
    ny, (p, m) = len(est.sensor_columns), est.Vp.shape
    nu, nz = len(est.input_columns), len(est.layout.aux)
    per_record = 3 * ny + m + m * m + est.layout.width + p + ny
    per_record += ny * p + ny * nu + nz * p + nz * m
    return 8 * per_record


def _values(
    est: SnapshotEstimator, q: np.ndarray, P: np.ndarray, h: np.ndarray, h_std: np.ndarray,
    innovation: np.ndarray, Gz_Vp: np.ndarray, z_u: np.ndarray | None,
) -> np.ndarray:
    """One engine's records' estimate numbers [n, width] (the ``values`` block of each): q,
    P [n, m, m] and its posterior h, h_std, innovations; Gz_Vp [n, nz, m] = G_z V*^+ and the
    input term z_u [n, nz] (None without one) of each record's aux estimate."""
    s = est.layout.slices()
    values = np.empty((len(q), est.layout.width))
    values[:, s["q"]] = q
    values[:, s["q_sigma"]] = np.sqrt(np.maximum(np.diagonal(P, axis1=1, axis2=2), 0.0))
    values[:, s["h"]] = h
    values[:, s["h_sigma"]] = h_std
    z_hat = (Gz_Vp @ q[..., None])[..., 0]
    if z_u is not None:
        z_hat = z_hat + z_u
    values[:, s["z"]] = z_hat
    z_var = ((Gz_Vp @ P) * Gz_Vp).sum(axis=-1)
    values[:, s["z_sigma"]] = np.sqrt(np.maximum(z_var, 0.0))
    values[:, s["residual"]] = innovation
    return values


def _records(G: np.ndarray, rec: slice, constant: bool) -> np.ndarray:
    """A schedule's gains [n, a, b] of the records ``rec``, or its one gain broadcast over
    them when the schedule is constant."""
    if constant:
        return np.broadcast_to(G[0], (rec.stop - rec.start, *G.shape[1:]))
    return G[rec]


def _per_slot(
    values: np.ndarray, S: int, row: np.ndarray, counts: np.ndarray, fill: float | np.ndarray,
) -> np.ndarray:
    """The chunk's per-record ``values`` [n, ...] (engine after engine, ``counts`` records
    each) laid out [E, S, ...]: engine e's records at the start of row ``row[e]``, the rest
    of the row ``fill``. When every engine has S records (rows in engine order, no fill)
    that is the records' own layout: ``values`` seen as [E, S, ...], not copied (the filter
    only reads it)."""
    if (len(values) == len(counts) * S and values.dtype == np.float64
            and values.flags.c_contiguous):
        return values.reshape(len(counts), S, *values.shape[1:])
    out = np.empty((len(counts), S, *values.shape[1:]))
    at = 0
    for e, n in enumerate(counts.tolist()):
        out[row[e], :n] = values[at : at + n]
        out[row[e], n:] = fill
        at += n
    return out


def _wssr_filled(
    est: SnapshotEstimator, det: ShiftState, r: EngineRun, c0: int, q: np.ndarray,
    P: np.ndarray, resets: np.ndarray, values: np.ndarray, out: EngineOutput,
    records: ChunkRecords | None = None,
) -> tuple[ShiftState, ShiftMarks]:
    """Run the detector over the engine's records of the chunk (``shift_scan``): fill the
    WSSR block of ``values``, collect events and checkpoints; the detector state after, and
    its marks for the wear detector.

    records: the chunk's records of the engine, for isolation in sensor space.
    """
    return _detected(est, shift_scan, det, r, c0, q, P, resets, values, out, records)


def _wssr_filled_per_record(
    est: SnapshotEstimator, det: ShiftState, r: EngineRun, c0: int, q: np.ndarray,
    P: np.ndarray, resets: np.ndarray, values: np.ndarray, out: EngineOutput,
    records: ChunkRecords | None = None,
) -> tuple[ShiftState, ShiftMarks]:
    """``_wssr_filled`` one record at a time (``shift_steps``, the reference the batched run
    is tested against)."""
    return _detected(est, shift_steps, det, r, c0, q, P, resets, values, out, records)


def _detected(
    est: SnapshotEstimator, scan: Callable[..., ShiftRun], det: ShiftState, r: EngineRun,
    c0: int, q: np.ndarray, P: np.ndarray, resets: np.ndarray, values: np.ndarray,
    out: EngineOutput, records: ChunkRecords | None,
) -> tuple[ShiftState, ShiftMarks]:
    n = len(q)
    epoch = r.epoch[c0 : c0 + n]
    observe = None if records is None else functools.partial(records.observation, est)
    run = scan(est, det, r.seq0 + c0, epoch, q, P, resets,
               values[:, est.layout.slices()["wssr"]], observe, CHECKPOINT_EVERY)
    seq0 = r.seq0 + c0
    marks = ShiftMarks(np.zeros(n, bool), np.zeros(n, bool))
    for iso, j in zip(run.isolations, run.isolated_at, strict=True):
        marks.pending[max(iso.alarm.seq - seq0, 0) : j] = True
        draft = detector.event(est, iso)
        if draft is not None:
            out.events.append(draft)
            marks.raised[j] = True
    if run.state.pending is not None:
        marks.pending[max(run.state.pending.seq - seq0, 0) :] = True
    for j, state in run.checkpoints:
        at = float(epoch[j])
        out.checkpoints.append(Checkpoint(
            r.seq0 + c0 + j + 1, at, PipelineState(SnapshotState(q[j : j + 1], P[j : j + 1]),
                                                   state, at),
        ))
    return run.state, marks
