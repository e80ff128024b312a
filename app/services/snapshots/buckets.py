"""Per-engine weekly and monthly sums of the health and auxiliary estimates, kept as the
estimates are stored, so that the fleet deterioration reads one row per engine and period
instead of every estimate (``deterioration_buckets``; read by ``app.services.fleet.status``).

An estimation run writes an engine's estimates from its first (re)computed record on. Every
period from the one holding that record is therefore rewritten: its rows are deleted, the
estimates the run kept before its first record in that period are read back (at most one
period's worth), and the new estimates, taken from the writer's blocks as they go to the
database, are added. The sums are those of the stored float32 values, so the fleet figures
equal those of a full scan of the estimates.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from datetime import UTC, datetime
from typing import cast

import numpy as np
from sqlalchemy import Table, and_, delete, func, insert, or_, select, text
from sqlalchemy.orm import Session

from app.models.estimates import DeteriorationBucket, Estimate, EstimateLayout, FleetPeriod
from app.services.encoding.pgcopy import HEADER, PG_EPOCH_US, TRAILER, fixed_copy_rows
from app.services.snapshots.rows import Block
from estimation.uncertainty import pair_products

PERIODS = ("week", "month")
FLEET_PERIOD_LOCK = 0x46480012  # first key of a design's fleet-period advisory lock
_MONDAY = np.datetime64("1969-12-29")  # 1970-01-01 was a Thursday


def period_starts(epoch: np.ndarray, period: str) -> np.ndarray:
    """Start (epoch seconds) of the week (Monday 00:00 UTC) or calendar month of each time."""
    days = np.floor(np.asarray(epoch, float) / 86400.0).astype("datetime64[D]")
    if period == "week":
        starts = _MONDAY + ((days - _MONDAY).astype(np.int64) // 7) * 7
    elif period == "month":
        starts = days.astype("datetime64[M]").astype("datetime64[D]")
    else:
        raise ValueError(f"unknown period {period!r}")
    return starts.astype("datetime64[s]").astype(np.int64).astype(float)


def value_columns(layout: EstimateLayout) -> np.ndarray:
    """Indices of the health (h) then auxiliary (z) values in an estimate's packed row."""
    s = layout.slices()
    return np.r_[np.arange(s["h"].start, s["h"].stop), np.arange(s["z"].start, s["z"].stop)]


class BucketCollector:
    """What the periods need of the estimates a run stores: each engine's record times and
    health and auxiliary values as stored. The writer hands over each batch it encodes
    (``stored``, its ``EstimateWriter`` sink), so the numbers are those its rows decode to,
    at the cost of a decode and no second encoding."""

    def __init__(self, layout: EstimateLayout) -> None:
        self.layout = layout
        self.columns = value_columns(layout)
        self.epoch: dict[int, list[np.ndarray]] = {}
        self.values: dict[int, list[np.ndarray]] = {}
        self.first_seq: dict[int, int] = {}  # each engine's first (re)computed record

    def stored(self, blocks: Sequence[Block], rows: np.ndarray) -> None:
        """Blocks and their stored rows ((n, ``layout.stored_bytes``) uint8, block after
        block)."""
        values = self.layout.decode(rows).values[:, self.columns]
        at = 0
        for engine_id, seq, epoch, _phase, _packed in blocks:
            n = len(epoch)
            if n:
                self._keep(engine_id, seq, np.asarray(epoch, float), values[at : at + n])
            at += n

    def add(self, block: Block) -> None:
        """A block of numbers, taken as their stored form gives them back
        (``EstimateLayout.as_stored``)."""
        engine_id, seq, epoch, _phase, packed = block
        if len(epoch):
            self._keep(engine_id, seq, np.asarray(epoch, float),
                       self.layout.as_stored(np.asarray(packed, np.float64))[:, self.columns])

    def _keep(self, engine_id: int, seq: int, epoch: np.ndarray, values: np.ndarray) -> None:
        # The numbers as stored: a period summed partly from stored rows and partly from a
        # run's new ones equals one summed from a single run.
        self.first_seq[engine_id] = min(seq, self.first_seq.get(engine_id, seq))
        self.epoch.setdefault(engine_id, []).append(epoch)
        self.values.setdefault(engine_id, []).append(values)


def period_ends(starts: np.ndarray, period: str) -> np.ndarray:
    """End (epoch seconds, the next period's start) of the periods starting at ``starts``."""
    days = (np.asarray(starts, float) // 86400.0).astype("datetime64[D]")
    if period == "week":
        ends = days + 7
    elif period == "month":
        ends = (days.astype("datetime64[M]") + 1).astype("datetime64[D]")
    else:
        raise ValueError(f"unknown period {period!r}")
    return ends.astype("datetime64[s]").astype(np.int64).astype(float)


def period_sums(epoch: np.ndarray, values: np.ndarray, period: str
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(period starts, counts, sums [k, width]) of one engine's records."""
    starts, index = np.unique(period_starts(epoch, period), return_inverse=True)
    index = np.ravel(index)
    counts = np.bincount(index, minlength=len(starts))
    if not len(index):
        return starts, counts, np.zeros((0, values.shape[1]))
    order = np.argsort(index, kind="stable")  # each period's records in their own order
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return starts, counts, np.add.reduceat(np.asarray(values, float)[order], first, axis=0)


def refresh(
    session: Session, *, operator_id: int, design_id: int, layout: EstimateLayout,
    collected: BucketCollector,
) -> None:
    """Rewrite the periods of every engine the collector saw, from its first new record on.
    Call after the estimates are written (the writer closed), in the same transaction."""
    engines = sorted(collected.epoch)
    if not engines:
        return
    epoch = {e: np.concatenate(collected.epoch[e]) for e in engines}
    values = {e: np.concatenate(collected.values[e]) for e in engines}
    first = {e: float(epoch[e].min()) for e in engines}
    # Per engine, the earliest period start over both periods: where kept estimates matter.
    b0 = {e: float(min(period_starts(np.array([first[e]]), p)[0] for p in PERIODS))
          for e in engines}
    change = FleetChange(len(layout.health))
    for period in PERIODS:
        p0 = {e: float(period_starts(np.array([first[e]]), period)[0]) for e in engines}
        rewritten = and_(
            DeteriorationBucket.design_id == design_id, DeteriorationBucket.period == period,
            or_(*(and_(DeteriorationBucket.engine_id == e,
                       DeteriorationBucket.start >= _time(p0[e])) for e in engines)),
        )
        for start, n, sums in session.execute(select(
            DeteriorationBucket.start, DeteriorationBucket.n, DeteriorationBucket.sums
        ).where(rewritten)):
            change.add(period, start.timestamp(), np.frombuffer(sums, "<f8") / n, -1)
        session.execute(delete(DeteriorationBucket).where(rewritten))
    # The kept estimates precede the run's first record, hence its sequence number too (those
    # from there on were deleted, or are the run's): bounding seq lets the key's index skip
    # the rows just written instead of reading each one's time.
    kept = session.execute(
        select(Estimate.engine_id, Estimate.recorded_at, Estimate.packed).where(
            Estimate.design_id == design_id,
            or_(*(and_(Estimate.engine_id == e, Estimate.seq < collected.first_seq[e],
                       Estimate.recorded_at >= _time(b0[e]),
                       Estimate.recorded_at < _time(first[e])) for e in engines)),
        )
    ).all()
    if kept:
        unpacked = layout.decode_blobs([row[2] for row in kept])[:, value_columns(layout)]
        kept_ids = np.array([row[0] for row in kept])
        kept_epoch = np.array([row[1].timestamp() for row in kept])
        for e in engines:
            mine = kept_ids == e
            if mine.any():
                epoch[e] = np.concatenate([kept_epoch[mine], epoch[e]])
                values[e] = np.concatenate([unpacked[mine], values[e]])
    written = PeriodRows(design_id, operator_id)
    for period in PERIODS:
        for e in engines:
            keep = epoch[e] >= float(period_starts(np.array([first[e]]), period)[0])
            starts, counts, sums = period_sums(epoch[e][keep], values[e][keep], period)
            written.add(period, e, starts, counts, sums)
            change.add_many(period, starts, sums / counts[:, None], +1)
    written.insert(session)
    change.apply(session, operator_id=operator_id, design_id=design_id)


class PeriodRows:
    """An engine group's new period rows (``DeteriorationBucket``), inserted at once: a binary
    COPY on PostgreSQL (thousands of rows a batch: one statement instead of one INSERT each,
    for the server as for the client), else one Core INSERT of many rows."""

    def __init__(self, design_id: int, operator_id: int) -> None:
        self.design_id = design_id
        self.operator_id = operator_id
        # period -> [(engine id, starts [k], counts [k], sums [k, width])]
        self.parts: dict[str, list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]] = {}

    def add(self, period: str, engine_id: int, starts: np.ndarray, counts: np.ndarray,
            sums: np.ndarray) -> None:
        if len(starts):
            self.parts.setdefault(period, []).append((engine_id, starts, counts, sums))

    def insert(self, session: Session) -> None:
        if not self.parts:
            return
        connection = session.connection()
        if connection.dialect.name != "postgresql":
            rows = [{"design_id": self.design_id, "period": period, "engine_id": e,
                     "start": _time(start), "operator_id": self.operator_id, "n": int(n),
                     "sums": np.ascontiguousarray(total, "<f8").tobytes()}
                    for period, parts in self.parts.items() for e, starts, counts, sums in parts
                    for start, n, total in zip(starts, counts, sums, strict=True)]
            session.execute(insert(cast(Table, DeteriorationBucket.__table__)), rows)
            return
        payload = [HEADER]
        for period, parts in self.parts.items():  # one text width per period
            engine = np.concatenate([np.full(len(p[1]), p[0], dtype=np.int64) for p in parts])
            starts = np.concatenate([p[1] for p in parts])
            payload.append(fixed_copy_rows([
                ("design_id", np.full(len(engine), self.design_id, dtype=">i4")),
                ("period", np.full(len(engine), period.encode(), dtype=f"S{len(period)}")),
                ("engine_id", engine.astype(">i4")),
                ("start", (np.rint(starts * 1e6).astype(np.int64) - PG_EPOCH_US).astype(">i8")),
                ("operator_id", np.full(len(engine), self.operator_id, dtype=">i4")),
                ("n", np.concatenate([p[2] for p in parts]).astype(">i4")),
                ("sums", np.ascontiguousarray(np.concatenate([p[3] for p in parts]), "<f8")
                 .view(np.uint8).reshape(len(engine), -1)),
            ]))
        payload.append(TRAILER)
        driver = connection.connection.driver_connection
        assert driver is not None
        columns = "design_id, period, engine_id, start, operator_id, n, sums"
        with driver.cursor() as cursor, cursor.copy(
            f"COPY {DeteriorationBucket.__tablename__} ({columns}) FROM STDIN (FORMAT BINARY)"
        ) as copy:
            copy.write(b"".join(payload))


class FleetChange:
    """What a rewrite of engines' periods changes in the fleet's periods: per (period, start)
    the change in the number of engines, in the sums of their means and in the sums of their
    means' second moments (``second_moments``)."""

    def __init__(self, p: int) -> None:
        self.p = p  # health values lead each mean
        self.delta: dict[tuple[str, float], tuple[int, np.ndarray, np.ndarray]] = {}

    def add(self, period: str, start: float, mean: np.ndarray, sign: int) -> None:
        """One engine's period mean going in (sign +1) or out (-1)."""
        self._add(period, start, mean, second_moments(mean, self.p), sign)

    def add_many(self, period: str, starts: np.ndarray, means: np.ndarray, sign: int) -> None:
        """``add`` of one engine's periods starting at ``starts`` [k], means [k, width], their
        second moments formed in one go (each row's products its own)."""
        for start, mean, moments in zip(starts.tolist(), means, second_moments(means, self.p),
                                        strict=True):
            self._add(period, start, mean, moments, sign)

    def _add(self, period: str, start: float, mean: np.ndarray, moments: np.ndarray,
             sign: int) -> None:
        key = (period, start)
        got = self.delta.get(key)
        if got is None:  # the zeros made only for a new key
            got = (0, 0.0 * mean, 0.0 * moments)
        n, sums, squares = got
        self.delta[key] = (n + sign, sums + sign * mean, squares + sign * moments)

    def apply(self, session: Session, *, operator_id: int, design_id: int) -> None:
        if not self.delta:
            return
        if session.get_bind().dialect.name == "postgresql":
            # Engine groups estimated in parallel change the same fleet periods: one
            # transaction at a time from here to its commit, or two could both insert a period.
            session.execute(select(func.pg_advisory_xact_lock(FLEET_PERIOD_LOCK, design_id)))
        # The rows of the changed (period, start) pairs, read with any other row of the same
        # periods and starts (a week that starts a month): a statement of two lists, not one
        # condition per pair.
        periods = sorted({p for p, _t in self.delta})
        starts = sorted({t for _p, t in self.delta})
        stored = {
            key: row
            for row in session.scalars(
                select(FleetPeriod).where(
                    FleetPeriod.design_id == design_id,
                    FleetPeriod.period.in_(periods),
                    FleetPeriod.start.in_([_time(t) for t in starts]),
                ).with_for_update()
            )
            if (key := (row.period, row.start.timestamp())) in self.delta
        }
        for key, (dn, dsums, dsquares) in self.delta.items():
            row = stored.get(key)
            if row is None:
                if dn > 0:
                    session.add(FleetPeriod(
                        design_id=design_id, period=key[0], start=_time(key[1]),
                        operator_id=operator_id, n_engines=dn,
                        sums=_blob(dsums), squares=_blob(dsquares)))
                continue
            n = row.n_engines + dn
            if n <= 0:
                session.delete(row)
                continue
            row.n_engines = n
            row.sums = _blob(np.frombuffer(row.sums, "<f8") + dsums)
            row.squares = _blob(np.frombuffer(row.squares, "<f8") + dsquares)
        session.flush()


def second_moments(mean: np.ndarray, p: int) -> np.ndarray:
    """What a fleet period sums of one engine's period mean [..., p + n_aux] besides the mean
    itself: the products of its health values (``uncertainty.pair_products``: the regressors
    of the calibrated level's curved correction and the fleet's covariance of the health
    values), the squares of its auxiliary values, then each auxiliary value times each health
    value (aux-major, [n_aux, p]: the covariance that carries the calibrated aux outputs'
    spread over engines, ``uncertainty.fleet_outputs``)."""
    mean = np.asarray(mean, float)
    h, z = mean[..., :p], mean[..., p:]
    cross = (z[..., :, None] * h[..., None, :]).reshape(mean.shape[:-1] + (-1,))
    return np.concatenate([pair_products(h), np.square(z), cross], axis=-1)


def _blob(values: np.ndarray) -> bytes:
    return np.ascontiguousarray(values, "<f8").tobytes()


def _time(epoch: float) -> datetime:
    return datetime.fromtimestamp(epoch, UTC)


def rebuild(session: Session, *, operator_id: int, design_id: int, layout: EstimateLayout,
            engine_ids: Sequence[int],
            decode: Callable[[list[bytes]], np.ndarray] | None = None) -> None:
    """Recompute the periods of ``engine_ids`` from all their estimates (migrations, repairs).
    ``decode``: the blobs' numbers (default ``layout.decode_blobs``; a migration before 0020
    passes ``layout.unpack``, the float32 blobs of its time)."""
    decode = decode or layout.decode_blobs
    collector = BucketCollector(layout)
    for engine_id in engine_ids:
        stored = session.execute(
            select(Estimate.recorded_at, Estimate.packed)
            .where(Estimate.design_id == design_id, Estimate.engine_id == engine_id)
            .order_by(Estimate.seq)
        ).all()
        if stored:
            collector.add((engine_id, 0, np.array([r[0].timestamp() for r in stored]), [],
                           decode([r[1] for r in stored])))
    refresh(session, operator_id=operator_id, design_id=design_id, layout=layout,
            collected=collector)


def rebuild_fleets(
    session: Session, moments: Callable[[np.ndarray, int], np.ndarray] = second_moments,
) -> None:
    """Recompute every design's fleet periods from its engines' periods (``rebuild_fleet``),
    each engine's mean's moments by ``moments``: a migration passes the form of its time."""
    designs = session.execute(text(
        "SELECT DISTINCT design_id FROM fleet_periods ORDER BY design_id")).scalars().all()
    for design_id in designs:
        layout = session.execute(text(
            "SELECT layout FROM filter_states WHERE design_id = :d LIMIT 1"), {"d": design_id}
        ).scalar()
        if layout is None:
            continue
        doc = layout if isinstance(layout, dict) else json.loads(layout)
        rebuild_fleet(session, design_id=design_id, p=len(EstimateLayout.from_dict(doc).health),
                      moments=moments)
    session.flush()


def rebuild_fleet(
    session: Session, *, design_id: int, p: int,
    moments: Callable[[np.ndarray, int], np.ndarray] = second_moments,
) -> None:
    """Recompute a design's fleet periods from its engines' periods (migrations, repairs): p
    health values lead each sum; ``moments`` what the squares hold of an engine's mean
    (``second_moments``; a migration back passes the form of its time)."""
    fleet: dict[tuple[str, datetime], list] = {}
    for period, start, operator_id, n, sums in session.execute(
        select(DeteriorationBucket.period, DeteriorationBucket.start,
               DeteriorationBucket.operator_id, DeteriorationBucket.n, DeteriorationBucket.sums)
        .where(DeteriorationBucket.design_id == design_id)
    ):
        mean = np.frombuffer(sums, "<f8") / n
        moment = moments(mean, p)
        got = fleet.setdefault((period, start), [operator_id, 0, 0.0 * mean, 0.0 * moment])
        got[1] += 1
        got[2] = got[2] + mean
        got[3] = got[3] + moment
    session.execute(delete(FleetPeriod).where(FleetPeriod.design_id == design_id))
    if fleet:
        session.execute(insert(cast(Table, FleetPeriod.__table__)), [
            {"design_id": design_id, "period": period, "start": start,
             "operator_id": operator_id, "n_engines": n, "sums": _blob(sums),
             "squares": _blob(squares)}
            for (period, start), (operator_id, n, sums, squares) in fleet.items()])

