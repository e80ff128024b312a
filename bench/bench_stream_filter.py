"""Stream filter throughput on the product's path: the demo's active design, per-engine
operating conditions, against the minimal numpy loop that computes the same rows.

Data: ``fleethealth simulate --mode stream``'s whole-flight CSV files of the built-in engine
(the first ``--seconds`` of the flight at 20 Hz: ground idle, take-off, climb), parsed as an
upload parses them (``uploads.parse.parse_body``). Each bench engine filters its own stretch
of one of these recordings (a random flight and start), so engines do not share operating
conditions and each schedules its own gains.

The estimator: the demo's active design (``demo.ACTIVE_DESIGN``), made by the product's design
service in a throw-away SQLite database and loaded as the service loads it
(``streams.estimator.estimator_for``).

The product's path, timed in two parts:

- ``inputs``: ``streams.run.filter_inputs`` (the trims at every sample's condition, the
  sensor and actuator deviations), once over the pool of flights;
- ``filter``: ``streams.run.filter_piece`` over each engine's samples, one recording after
  another, as ``streams.store.estimate_one`` calls it: the segments re-scheduled when the
  condition leaves the ``TOLERANCE`` box, one steady-state gain per anchor (cached; the DAREs
  are computed in an untimed first pass), ``estimation.stream_filter.filter_run`` and the rows
  (q, h, z with their 1-sigma, innovations).

The bound, in the same run on the same arrays and gains: the minimal numpy loop per engine
(``x_hat[k] = Phi x_hat[k-1] + drive[k]`` per segment, drive formed by one product per
segment, then the same rows), given each engine's segments and gains found beforehand (the
product finds them itself, inside its time). Beside it, what a loop batched over engines
would give: the same recursion time-major over all engines at once, every engine with its
own gain at every sample (the products grouped by gain, the recursion through a gather of
Phi). All three give the same rows (the largest difference is printed).

BLAS and OpenMP run one thread (``bench/_common.py``, before numpy loads); the load is printed
first and last. Engines 10 / 1,000 / 10,000 / 100,000, with fewer samples each as the fleet
grows (9e4, 1e6, 1e6 and 1e6 samples).

    .venv/bin/python bench/bench_stream_filter.py [--sizes 10x9000,1000x1000,10000x100,100000x10]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import NamedTuple

import _common
import numpy as np

from app.db import make_engine, make_sessionmaker
from app.migrate import upgrade
from app.services.demo import fleet as demo
from app.services.streams.estimator import StreamEstimator, estimator_for
from app.services.streams.run import Carry, _first_outside, filter_inputs, filter_piece
from app.services.tenancy.service import create_operator
from app.services.uploads.parse import parse_body
from estimation.stream_filter import SegmentGain

SIZES = "10x9000,1000x1000,10000x100,100000x10"
TARGET = 1.5  # the product's filter within 1.5x of the minimal loop (issue 17)


class Gain(NamedTuple):
    """One segment gain in the forms the bounds use (transposed for row-vector products)."""

    PhiT: np.ndarray  # ((I - K C) A)^T
    KT: np.ndarray
    KDT: np.ndarray  # (K D)^T
    IKCBT: np.ndarray  # ((I - K C) B)^T
    AT: np.ndarray
    BT: np.ndarray
    CT: np.ndarray
    DT: np.ndarray
    FT: np.ndarray
    GT: np.ndarray
    sigma: np.ndarray


def bound_gain(g: SegmentGain) -> Gain:
    IKC = np.eye(g.A.shape[0]) - g.K @ g.C

    def c(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a)

    return Gain(c((IKC @ g.A).T), c(g.K.T), c((g.K @ g.D).T), c((IKC @ g.B).T), c(g.A.T),
                c(g.B.T), c(g.C.T), c(g.D.T), c(g.F.T), c(g.G.T), g.sigma)


def product_estimator(signals: list[str]) -> StreamEstimator:
    """The demo's active design, made and loaded by the product in a throw-away database."""
    with _common.throwaway_database("sqlite") as (url, _label):
        upgrade(url)
        engine = make_engine(url)
        with make_sessionmaker(engine)() as session, session.begin():
            operator = create_operator(session, name="Bench Air")
            _kind, design = _common.demo_design(session, operator.id)
            est = estimator_for(session, design, signals)
        engine.dispose()
    return est


def segments(est: StreamEstimator, cond: np.ndarray, keys: dict[tuple[float, ...], int]
             ) -> list[tuple[int, int, int]]:
    """(start, end, gain index) of one recording's segments, as ``filter_piece`` finds them."""
    out, i = [], 0
    while i < cond.shape[0]:
        j = _first_outside(cond, i, cond[i])
        out.append((i, j, keys.setdefault(est.snapped(cond[i]), len(keys))))
        i = j
    return out


def filterable(est: StreamEstimator, cond: np.ndarray, dt: float) -> int:
    """First sample after the last one whose condition, taken as a segment's anchor, has no
    measurement update (every sample can anchor a segment of a stretch starting there). At
    ground idle (the simulated flight's first 120 s, power 0 %) the design's reduced model is
    unobservable, so ``filter_piece`` runs the model's prediction alone there (K = 0, 1-sigma
    not estimated); the bench times what follows, where the filter updates."""
    keys = [est.snapped(c) for c in cond]
    bad = {key for key in set(keys) if not est.gain(key, dt).K.any()}
    return max((i + 1 for i, k in enumerate(keys) if k in bad), default=0)


def minimal_engine(segs: list[tuple[int, int, int]], dy: np.ndarray, du: np.ndarray,
                   gains: list[Gain], VpT: np.ndarray, sl: dict[str, slice], width: int,
                   n: int) -> np.ndarray:
    """One engine's rows [S, width] by the plainest numpy loop with the given segments."""
    S = dy.shape[0]
    rows = np.empty((S, width))
    x_prev, u_prev = np.zeros(n), np.zeros(du.shape[1])
    nx = n - VpT.shape[0]
    for i, j, gi in segs:
        g = gains[gi]
        ys, us = dy[i:j], du[i:j]
        drive = ys @ g.KT - us @ g.KDT
        drive[0] += u_prev @ g.IKCBT
        drive[1:] += us[:-1] @ g.IKCBT
        x = drive
        x[0] += x_prev @ g.PhiT
        for k in range(1, j - i):
            x[k] += x[k - 1] @ g.PhiT
        xp = np.vstack([x_prev[None, :], x[:-1]])
        up = np.vstack([u_prev[None, :], us[:-1]])
        q = x[:, nx:]
        rows[i:j, sl["q"]] = q
        rows[i:j, sl["h"]] = q @ VpT
        rows[i:j, sl["z"]] = x @ g.FT + us @ g.GT
        rows[i:j, sl["residual"]] = ys - (xp @ g.AT + up @ g.BT) @ g.CT - us @ g.DT
        m, p = q.shape[1], VpT.shape[1]
        rows[i:j, sl["q_sigma"]] = g.sigma[:m]
        rows[i:j, sl["h_sigma"]] = g.sigma[m:m + p]
        rows[i:j, sl["z_sigma"]] = g.sigma[m + p:]
        x_prev, u_prev = x[-1], us[-1]
    return rows


def batched(gid: np.ndarray, dy: np.ndarray, du: np.ndarray, gains: list[Gain],
            VpT: np.ndarray, sl: dict[str, slice], width: int, n: int) -> np.ndarray:
    """All engines' rows [E, S, width] by one time-major loop over the engines at once, each
    engine with its own gain at each sample (the products per gain over the samples sorted by
    gain, the recursion through a gather of Phi)."""
    E, S, ny = dy.shape
    N, nx, p = E * S, n - VpT.shape[0], VpT.shape[1]
    m = n - nx
    order = np.argsort(gid.ravel(), kind="stable")
    sorted_gid = gid.ravel()[order]
    cuts = np.searchsorted(sorted_gid, np.arange(len(gains) + 1))
    du_prev = np.concatenate([np.zeros((E, 1, du.shape[2])), du[:, :-1]], axis=1)
    ys, us, ups = (a.reshape(N, -1)[order] for a in (dy, du, du_prev))
    part = np.empty((N, n))
    for g, a in enumerate(gains):
        lo, hi = cuts[g], cuts[g + 1]
        if hi > lo:
            part[lo:hi] = ys[lo:hi] @ a.KT - us[lo:hi] @ a.KDT + ups[lo:hi] @ a.IKCBT
    x = np.empty((N, n))
    x[order] = part
    x = x.reshape(E, S, n)  # in place: x[:, k] = Phi x[:, k - 1] + drive[:, k]
    PhiT = np.stack([a.PhiT for a in gains])
    for k in range(1, S):
        x[:, k] += np.matmul(x[:, k - 1, None, :], PhiT[gid[:, k]])[:, 0]
    xp = np.concatenate([np.zeros((E, 1, n)), x[:, :-1]], axis=1).reshape(N, n)[order]
    xs = x.reshape(N, n)[order]
    sorted_rows = np.empty((N, width))
    for g, a in enumerate(gains):
        lo, hi = cuts[g], cuts[g + 1]
        if hi == lo:
            continue
        r = sorted_rows[lo:hi]
        r[:, sl["z"]] = xs[lo:hi] @ a.FT + us[lo:hi] @ a.GT
        r[:, sl["residual"]] = (ys[lo:hi] - (xp[lo:hi] @ a.AT + ups[lo:hi] @ a.BT) @ a.CT
                                - us[lo:hi] @ a.DT)
        r[:, sl["q_sigma"]] = a.sigma[:m]
        r[:, sl["h_sigma"]] = a.sigma[m:m + p]
        r[:, sl["z_sigma"]] = a.sigma[m + p:]
    rows = np.empty((N, width))
    rows[order] = sorted_rows
    rows = rows.reshape(E, S, width)
    rows[..., sl["q"]] = x[..., nx:]
    rows[..., sl["h"]] = x[..., nx:] @ VpT
    return rows


def run_size(est: StreamEstimator, pool: tuple[np.ndarray, ...], dt: float, E: int, S: int,
             rng: np.random.Generator) -> float:
    """Time the product and the bounds on E engines x S samples; the product's ratio."""
    cond_all, dy_all, du_all, starts, lengths = pool
    flights = rng.integers(0, len(starts), size=E)
    first = starts[flights] + (rng.random(E) * (lengths[flights] - S + 1)).astype(int)
    idx = first[:, None] + np.arange(S)
    cond, dy, du = cond_all[idx], dy_all[idx], du_all[idx]
    n, nu = est.n, est.model.n_inputs
    layout = est.layout
    sl, width = layout.slices(), layout.width
    VpT = np.ascontiguousarray(est.Vp.T)

    def product() -> None:
        for e in range(E):
            filter_piece(est, dt, cond[e], dy[e], du[e], Carry(np.zeros(n), np.zeros(nu), None, 0))

    # Untimed first pass: the gains (DAREs), each engine's segments, the rows compared.
    t0 = time.perf_counter()
    keys: dict[tuple[float, ...], int] = {}
    segs = [segments(est, cond[e], keys) for e in range(E)]
    gains = [bound_gain(est.gain(k, dt)) for k in keys]
    t_gains = time.perf_counter() - t0
    gid = np.empty((E, S), dtype=np.intp)
    for e, s in enumerate(segs):
        for i, j, g in s:
            gid[e, i:j] = g
    rows_b = batched(gid, dy, du, gains, VpT, sl, width, n)
    diff_min = diff_b = 0.0
    for e in range(E):
        ours, _carry, _ = filter_piece(est, dt, cond[e], dy[e], du[e],
                                       Carry(np.zeros(n), np.zeros(nu), None, 0))
        plain = minimal_engine(segs[e], dy[e], du[e], gains, VpT, sl, width, n)
        diff_min = max(diff_min, float(np.max(np.abs(ours - plain))))
        diff_b = max(diff_b, float(np.max(np.abs(ours - rows_b[e]))))
    del rows_b
    t_seg = _common.best_time(
        lambda: [segments(est, cond[e], dict(keys)) for e in range(E)], repeat=1)

    t_ours = _common.best_time(product, repeat=2)
    t_min = _common.best_time(
        lambda: [minimal_engine(segs[e], dy[e], du[e], gains, VpT, sl, width, n)
                 for e in range(E)], repeat=2)
    t_bat = _common.best_time(lambda: batched(gid, dy, du, gains, VpT, sl, width, n), repeat=2)
    N = E * S
    n_segs = sum(len(s) for s in segs)
    print(f"\n{E:,} engines x {S:,} samples ({N:,} samples, {len(np.unique(first)):,} distinct "
          f"stretches of {len(starts)} flights), {n_segs:,} segments ({n_segs / E:.1f} an "
          f"engine), {len(gains)} gains (segments and gains found untimed in {t_gains:.1f} s)")
    print(f"  {'filter_piece per engine':<26} {t_ours:8.3f} s  {N / t_ours:11,.0f} samples/s  "
          f"{1e6 * t_ours / E:9.1f} us an engine  {t_ours / t_min:5.2f}x the bound  the product")
    print(f"  {'minimal loop per engine':<26} {t_min:8.3f} s  {N / t_min:11,.0f} samples/s  "
          f"{1e6 * t_min / E:9.1f} us an engine  {1:5.2f}x the bound  "
          f"max |diff| {diff_min:.1e} (segments given: finding them alone {t_seg:.3f} s)")
    print(f"  {'batched over engines':<26} {t_bat:8.3f} s  {N / t_bat:11,.0f} samples/s  "
          f"{1e6 * t_bat / E:9.1f} us an engine  {t_bat / t_min:5.2f}x the bound  "
          f"max |diff| {diff_b:.1e}")
    return t_ours / t_min


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=SIZES, help="engines x samples, comma-separated")
    ap.add_argument("--aircraft", type=int, default=8, help="simulated aircraft (2 flights each)")
    ap.add_argument("--seconds", type=float, default=600.0, help="simulated seconds of flight")
    ap.add_argument("--seed", type=int, default=20260101)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"),
                    help="the built-in engine's schedule cache")
    args = ap.parse_args()
    print(_common.load_line())
    files = _common.simulated_streams(args.aircraft, args.seconds, args.seed)
    parsed = [parse_body(path.read_bytes(), "csv", kind="stream") for path, _entry in files]
    with _common.schedule_cache(args.cache):
        t0 = time.perf_counter()
        est = product_estimator(sorted(set().union(*(p.signals for p in parsed))))
        print(f"the demo's active design {demo.ACTIVE_DESIGN}: {est.nx} states + "
              f"{est.vstar.shape[0]} tuners, sensors {list(est.model.sensor_names)} "
              f"(designed and loaded in {time.perf_counter() - t0:.0f} s)")
        tables = [p.table for p in parsed]
        dt = float(np.median(np.diff(tables[0]["time_s"].to_numpy())))
        t0 = time.perf_counter()
        inputs = [filter_inputs(est, t) for t in tables]
        t_in = time.perf_counter() - t0
        total = sum(t.num_rows for t in tables)
        print(f"pool: {len(tables)} simulated flights of {args.seconds:g} s at {1 / dt:g} Hz, "
              f"{total:,} samples; filter_inputs (trims, deviations) {total / t_in:,.0f} "
              "samples/s")
        kept = [tuple(a[filterable(est, i[0], dt):] for a in i) for i in inputs]
        lengths = np.array([i[0].shape[0] for i in kept])
        print(f"  kept {lengths.sum():,} samples: {total - lengths.sum():,} at ground idle cut "
              "(power 0 %: its gain is unobservable, see filterable)")
        pool = (*(np.concatenate([i[k] for i in kept]) for k in range(3)),
                np.concatenate([[0], np.cumsum(lengths)[:-1]]), lengths)
        rng = np.random.default_rng(args.seed)
        ratios = {}
        for item in args.sizes.split(","):
            E, S = (int(v) for v in item.split("x"))
            ratios[E] = run_size(est, pool, dt, E, S, rng)
    print(f"\nload average at the end {os.getloadavg()[0]:.2f}")
    worst = max(ratios.values())
    print(f"target: the product's filter within {TARGET}x of the minimal loop per engine: worst "
          f"{worst:.2f}x -> {'PASS' if worst <= TARGET else 'FAIL'}")


if __name__ == "__main__":
    main()
