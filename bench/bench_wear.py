"""Wear (gradual deterioration) detection on NASA C-MAPSS FD001 and on the demo fleet.

FD001 train (100 engines, HPC degradation run to failure): the product's filter
(``pipeline.run_filters`` on the design of tests/app/test_fd001.py) and the wear detector
(``estimation.wear.wear_scan``) on its tuner estimates, next to a naive per-engine signature
CUSUM on the sensor deviations (``estimation.wear.signature_cusum``, HPC signature, no alarm
before cycle 50) computed in the same run: engines alerted before failure, median lead (cycles
before failure), share of alerts attributed to HPC; the product's own shift detector too.
Demo fleet (``app.services.demo.fleet``, simulated, built-in engine): wear alerts outside the
injected faults' windows per engine-year.

Next to the detector's own figures (``wear_scan`` on the filter's estimates, cycles as C-MAPSS
counts them, default settings unless given), the product path's: the ``wear`` events
``run_filters`` raises itself (``estimation.wear.wear_steps`` record by record, cycles counted
in flights, default settings), on FD001 with the design ``fleethealth import-cmapss`` creates
(the built-in engine's default schedule grid, as a server builds it).

The wear detector gets the records' sensor deviations too (its directional CUSUM bank);
``--no-bank`` scans the tuner estimates alone (limit and rate alerts).

Experiment ``--learnt TAIL`` (bench only, not in the product): the fleet's wear direction
learnt from the other engines (leave-one-out): each engine's accumulated change in the
candidate faults' magnitudes (``wear_drift``: the weighted least-squares fit of each record's
sensor deviation on the signatures, its mean over the last TAIL records less its mean over
the bank's baseline), the mean of the engines' unit changes (``fleet_direction``), and ONE
matched-filter CUSUM along it (signature G_k v) standardised as the bank is, its threshold
calibrated for a single CUSUM at ``--learnt-per-year`` false alerts per engine-year (the
bank's at ``--per-year``: give the two a split of the budget). Its alert names, at the
crossing, the fault the fleet's mean tuner change is attributed to by the WSSR if that is
confident ("tuner"; "sensor": the nearest signature to G v; "wssr": the usual wait), and is
printed alone and as the earlier of it and the detector's own alert ("+bank"), with the
direction learnt from all other engines and from the first 20 and 10 units only; white
sensor noise gives the false crossings of the bank, the learnt CUSUM and either at each
horizon, and the demo fleet (its direction learnt from its own other engines' stretches)
the false alerts per engine-year.

The acceptance block prints the product's wear events and the naive CUSUM side by side with
PASS/FAIL. The frontier (``frontier``; ``--skip-frontier``) asks how early the bank could
cross at all at its stated false-alarm rate: the threshold set by a seeded Monte Carlo on
white matched-filter outputs so that a healthy engine crosses within ``--horizon`` armed
records with the design's probability 1 - exp(-horizon / bank_arl) (met at that horizon
only; the product's calibration meets the rate at every horizon up to an engine-year, and
its shorter horizons bind), beside the product's and Siegmund's thresholds, and the naive
CUSUM's own probability on the same noise.

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_wear.py [--rate 1.5e-3 --margin 6]
        [--floor 0.03 --limit 1]
        [--kappa 0.25 --alpha 0.05 --per-year 1 | --arl 365 | --h 3] [--siegmund]
        [--bank-rate 1e-3] [--confidence 1.3 --hold 1] [--no-bank]
        [--horizon 350 --runs 2000 | --skip-frontier]
        [--learnt 20 --per-year 0.1 --learnt-per-year 0.9]

(The bank's threshold is set from its designed false alerts per engine-year --per-year and
each engine's record rate over its baseline, by the bank's Monte Carlo calibration
(``estimation.wear.calibrated_threshold``; --siegmund: Siegmund's ARL with Bonferroni); --arl
gives the family-wise ARL in records instead, --h the threshold itself; --alpha 0 takes the
bank's baseline as exact.)
"""

from __future__ import annotations

import argparse
import itertools
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path

import _common  # (import path)
import numpy as np

from app.engine_cache import engine_schedule
from app.services.demo import fleet
from app.services.snapshots import run
from estimation import wear
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from tests.support import detection_replay, fd001_replay

FD001 = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmapss" / "train_FD001.txt"
YEAR_S = 365.25 * 86400.0


def health_candidates(S_full: np.ndarray, p: int) -> np.ndarray:
    """Library faults that are module deteriorations (no actuator-bias rows): wear candidates."""
    return np.all(S_full[p:] == 0.0, axis=0)


def fd001(path: Path, cfg: wear.WearSettings, units: int | None, use_sensors: bool,
          cache: Path, learnt_tail: int | None = None,
          learnt_cfg: wear.WearSettings | None = None,
          learnt_metric: bool = False) -> Fd001Figures:
    t0 = time.perf_counter()
    est = fd001_replay.fd001_estimator(fd001_replay.fd001_schedule())
    engines = fd001_replay.fd001_runs(path, est, units)
    tracks = fd001_replay.filter_tracks(est, [e.run for e in engines])
    W = wear.health_weight(est.Vp)
    cand = health_candidates(est.S_full, len(est.layout.health))
    hpc = est.layout.faults.index("HPC")
    ours, naive, product, kinds = [], [], [], []
    hpc_hits = 0
    zs: list[tuple[np.ndarray, np.ndarray]] = []
    rates = []
    learnt: list[LearntEngine] = []
    for e, tr in zip(engines, tracks, strict=True):
        dy, var, sig = fd001_replay.sensor_deviations(est, e.run)
        zs.append((wear.matched_filter(dy, var, sig)[:, cand], e.cycle.astype(float)))
        sensors = {"dy": dy, "var": var, "signatures": sig} if use_sensors else {}
        b1 = cfg.settle + cfg.n_base
        rates.append(wear.record_rate(e.run.epoch[:b1]))
        scan = wear.wear_scan(tr.q, est.H, W, e.cycle.astype(float), candidates=cand,
                              settings=cfg, epoch=e.run.epoch, **sensors)
        if scan.alerts:
            a = scan.alerts[0]
            ours.append(int(e.cycle[-1] - e.cycle[a.index]))
            hpc_hits += a.fault == hpc
            kinds.append(a.kind)
        k = wear.signature_cusum(dy, var, sig[0, :, hpc])
        if k is not None:
            naive.append(int(e.cycle[-1] - e.cycle[k]))
        if learnt_tail is not None:
            a0 = scan.alerts[0] if scan.alerts else None
            learnt.append(LearntEngine(
                dy, np.asarray(var), sig, e.cycle.astype(float), rates[-1], scan.wssr, scan.f,
                (a0.index, -1 if a0.fault is None else a0.fault) if a0 else None, k, tr.q))
        shifts = [ev for ev in tr.events if ev.kind != "wear"]
        if shifts:
            product.append((shifts[0], int(e.cycle[-1]) - _cycle_at(e, shifts[0].epoch)))
    # The product path: the design import-cmapss makes, its pipeline's own wear events.
    t1 = time.perf_counter()
    est_p = fd001_replay.fd001_estimator(engine_schedule(cache))
    engines_p = fd001_replay.fd001_runs(path, est_p, units)
    wear_events = []
    for e, tr in zip(engines_p, fd001_replay.filter_tracks(est_p, [e.run for e in engines_p]),
                     strict=True):
        first = next((ev for ev in tr.events if ev.kind == "wear"), None)
        if first is not None and _cycle_at(e, first.epoch) < int(e.cycle[-1]):
            wear_events.append((first, int(e.cycle[-1]) - _cycle_at(e, first.epoch)))
    t_product = time.perf_counter() - t1
    n = len(engines)
    rate = float(np.median([r for r in rates if r is not None]))
    design = wear.bank_design(cfg, int(cand.sum()), rate)
    print(f"FD001 train, {n} engines ({time.perf_counter() - t0:.1f} s); settings {cfg}")
    print(f"bank design: {rate:.1f} records per engine-year (one cycle a day, as imported), "
          f"{cfg.false_alerts_per_year:g} false alerts per engine-year -> family-wise ARL "
          f"{wear.bank_arl(cfg, rate):.0f} records, h = {design.threshold:.2f} "
          f"(reference {design.reference:.3f}, scale {design.scale:.3f})")
    print(f"{'':34s}{'alerted':>10s}{'median lead':>13s}{'HPC share':>11s}")
    print(f"{'target':34s}{n:>7d}/{n:<3d}{'>= naive':>13s}{'>= 90 %':>11s}")
    print(f"{'filter + wear detector':34s}{len(ours):>7d}/{n:<3d}"
          f"{_median(ours):>13s}{_share(hpc_hits, len(ours)):>11s}")
    hpc_wear = sum(ev.fault == "HPC" for ev, _ in wear_events)
    print(f"{'product wear events':34s}{len(wear_events):>7d}/{n:<3d}"
          f"{_median([lead for _, lead in wear_events]):>13s}"
          f"{_share(hpc_wear, len(wear_events)):>11s}   ({t_product:.1f} s)")
    print(f"{'naive signature CUSUM (HPC)':34s}{len(naive):>7d}/{n:<3d}{_median(naive):>13s}"
          f"{'(given)':>11s}")
    hpc_product = sum(ev.fault == "HPC" for ev, _ in product)
    print(f"{'product shift detector':34s}{len(product):>7d}/{n:<3d}"
          f"{_median([lead for _, lead in product]):>13s}{_share(hpc_product, len(product)):>11s}")
    print(f"wear alert kinds: {dict(zip(*np.unique(kinds, return_counts=True), strict=True))}")
    leads = [lead for _, lead in wear_events]
    print("\nacceptance, the product's wear events against the naive CUSUM (same records):")
    print(f"{'':34s}{'target':>12s}{'product':>10s}{'naive':>10s}   verdict")
    rows = [
        ("engines alerted before failure", f"{n}/{n}", f"{len(leads)}/{n}", f"{len(naive)}/{n}",
         len(leads) == n),
        ("median lead, cycles", ">= naive", _median(leads), _median(naive),
         bool(leads) and bool(naive) and np.median(leads) >= np.median(naive)),
        ("alerts attributed to HPC", ">= 90 %", _share(hpc_wear, len(wear_events)), "-",
         bool(wear_events) and hpc_wear >= 0.9 * len(wear_events)),
    ]
    for name, target, ours_s, naive_s, ok in rows:
        print(f"{name:34s}{target:>12s}{ours_s:>10s}{naive_s:>10s}   {'PASS' if ok else 'FAIL'}")
    if learnt_tail is not None:
        cfg_l = learnt_cfg or cfg
        fd001_learnt(learnt, cfg_l, cand, hpc, list(est.layout.faults), learnt_tail, W, est.H,
                     learnt_metric)
        M = (np.mean([signature_metric(e.sig, e.var, cand) for e in learnt], axis=0)
             if learnt_metric else None)
        v = fleet_direction([wear_drift(e.dy, e.var, e.sig, cand, cfg.n_base, learnt_tail)
                             for e in learnt], M)
        white_learnt(learnt[0], v, cfg, cfg_l, cand, 1000, 365)
    return Fd001Figures(zs, naive, cfg, rate)


@dataclass(frozen=True)
class Fd001Figures:
    """What the frontier needs from the FD001 run: each engine's matched-filter outputs of
    the candidate faults [S, n] with its cycles, and the naive CUSUM's leads."""

    z: list[tuple[np.ndarray, np.ndarray]]
    naive: list[int]
    cfg: wear.WearSettings
    records_per_year: float


def _bank_max(z: np.ndarray, cycles: np.ndarray, cfg: wear.WearSettings, reference: float,
              scale: float) -> np.ndarray:
    """The bank's largest CUSUM over its candidates so far [S] (-inf before it is armed),
    standardised as ``wear_scan`` does, without the attribution condition."""
    b1 = cfg.settle + cfg.n_base
    base = z[: cfg.n_base]
    u = (z - base.mean(axis=0)) / (scale * base.std(axis=0, ddof=1))
    u -= reference + cfg.bank_rate * (cycles[:, None] - cycles[b1 - 1])
    top = np.full(len(z), -np.inf)
    if len(z) > b1:
        top[b1:] = np.maximum.accumulate(wear._cusum(u[b1:]).max(axis=1))
    return top


def frontier(fig: Fd001Figures, horizon: int, runs: int) -> None:
    """How early a bank can cross at the designed false-alarm rate. On white matched-filter
    outputs (n independent candidates, seeded), each bank's threshold h is set so that a
    healthy engine crosses within ``horizon`` armed records with the design's probability
    1 - exp(-horizon / bank_arl), its baseline's own errors included (Monte Carlo quantile):
    the least conservative threshold that still meets the stated rate at that horizon (the
    product's threshold meets it at every horizon up to an engine-year). The crossing's lead
    on FD001 is then an upper bound on any alert that also waits for an attribution. The
    naive CUSUM's own false-alarm probability on the same noise is shown."""
    cfg = fig.cfg
    n = fig.z[0][0].shape[1]
    b1 = cfg.settle + cfg.n_base
    arl = wear.bank_arl(cfg, fig.records_per_year)
    p = 1.0 - np.exp(-horizon / arl)
    rng = np.random.default_rng(20261124)
    white = [rng.normal(size=(b1 + horizon, n)) for _ in range(runs)]
    cyc = np.arange(1.0, b1 + horizon + 1.0)
    naive_hits = sum(wear.signature_cusum(w[:, :1], np.ones(1), np.ones(1)) is not None
                     for w in white)
    print(f"\nfrontier: bank crossings (no attribution condition) with h calibrated on {runs} "
          f"white engines to P(false crossing within {horizon} armed records) = {p:.3f}")
    print(f"{'standardisation':44s}{'h':>7s}{'P(false crossing)':>20s}{'median lead':>13s}")
    design = wear.bank_design(cfg, n, fig.records_per_year)
    siegmund = wear.bank_design(replace(cfg, bank_calibrated=False), n, fig.records_per_year)
    variants = [
        (f"allowances at alpha {cfg.bank_alpha:g}, h as designed", design.reference,
         design.scale, design.threshold),
        (f"allowances at alpha {cfg.bank_alpha:g}, h Siegmund's", siegmund.reference,
         siegmund.scale, siegmund.threshold),
        (f"allowances at alpha {cfg.bank_alpha:g}, h by MC at {horizon}", design.reference,
         design.scale, None),
        (f"none (alpha 0), h by MC at {horizon}", cfg.bank_reference, 1.0, None),
        (f"none, reference 0.5, h by MC at {horizon}", 0.5, 1.0, None),
    ]
    for name, ref, scale, h in variants:
        tops = np.array([_bank_max(w, cyc, cfg, ref, scale)[-1] for w in white])
        h = float(np.quantile(tops, 1.0 - p)) if h is None else h
        leads = []
        for z, cycles in fig.z:
            k = np.flatnonzero(_bank_max(z, cycles, cfg, ref, scale) > h)
            leads.append(int(cycles[-1] - cycles[k[0]]) if len(k) else 0)
        print(f"{name:44s}{h:>7.2f}{np.mean(tops > h):>20.3f}{_median(leads):>13s}")
    print(f"{'naive signature CUSUM':44s}{5.0:>7.2f}{naive_hits / runs:>20.3f}"
          f"{_median(fig.naive):>13s}   (one direction; its baseline taken as exact)")


def _cycle_at(e: fd001_replay.Fd001Engine, epoch: float) -> int:
    return int(e.cycle[np.searchsorted(e.run.epoch, epoch)])


def _median(values: list[int]) -> str:
    return f"{np.median(values):.1f}" if values else "-"


def _share(k: int, n: int) -> str:
    return f"{100.0 * k / n:.0f} %" if n else "-"


def demo(cfg: wear.WearSettings, cache: Path, use_sensors: bool,
         learnt_tail: int | None = None, learnt_cfg: wear.WearSettings | None = None,
         learnt_metric: bool = False) -> None:
    t0 = time.perf_counter()
    est = fleet.design_estimator(engine_schedule(cache), *fleet.ACTIVE_DESIGN)
    size = fleet.DemoSize()
    plan_rng, snap_rng = np.random.default_rng(fleet.SEED).spawn(2)
    plan = plan_fleet(fleet.fleet_config(size), plan_rng)
    snaps = fleet_snapshots(plan, snap_rng)
    engines = detection_replay.engine_runs(plan, snaps, est)
    W = wear.health_weight(est.Vp)
    cand = health_candidates(est.S_full, len(est.layout.health))
    s = est.layout.slices()
    false, in_fault, years = [], 0, 0.0
    rates = []
    product_false, product_in_fault = 0, 0
    demo_runs: list[DemoEngine] = []
    outs = run.run_filters(est, [e.run for e in engines])
    for data, out in zip(engines, outs, strict=True):
        q = out.packed.astype(np.float64)[:, s["q"]]
        t = data.run.epoch
        fid = data.flight_id
        cycles = np.cumsum(np.r_[True, fid[1:] != fid[:-1]]).astype(float)
        prev = np.r_[-np.inf, t[:-1]]
        resets = np.zeros(len(t), bool)
        for m in data.run.maintenance:
            resets |= (m <= t) & (m > prev)
        # Faulty windows: from a fault's flight to its engine's removal (or the data's end).
        windows = [(f.occurred_at, detection_replay._removal_after(plan, f.esn, f.occurred_at))
                   for f in plan.faults if f.esn == data.esn]
        faulty = np.zeros(len(t), bool)
        for a, b in windows:
            faulty |= (t >= a) & (t <= b)
        healthy_t = t[~faulty]
        if len(healthy_t) > 1:
            gaps = np.diff(healthy_t)
            years += float(np.sum(gaps[gaps < 30 * 86400.0])) / YEAR_S  # time flown healthy
        sensors = {}
        if use_sensors:
            dy, var, sig = fd001_replay.sensor_deviations(est, data.run)
            sensors = {"dy": dy, "var": var, "signatures": sig}
        for ev in out.events:
            if ev.kind == "wear":
                if faulty[np.searchsorted(t, ev.epoch)]:
                    product_in_fault += 1
                else:
                    product_false += 1
        rates.append(wear.record_rate(t[: cfg.settle + cfg.n_base]))
        scan = wear.wear_scan(q, est.H, W, cycles, resets, cand, cfg, epoch=t, **sensors)
        if learnt_tail is not None and sensors:
            demo_runs.append(DemoEngine(sensors["dy"], np.asarray(sensors["var"]),
                                        sensors["signatures"], cycles, t, resets, faulty, q,
                                        scan))
        for a in scan.alerts:
            if faulty[a.index]:
                in_fault += 1
            else:
                false.append((data.esn, a.kind, est.layout.faults[a.fault]
                              if a.fault is not None else None, round(a.magnitude, 2)))
    rate = len(false) / years if years else float("nan")
    r = float(np.median([v for v in rates if v is not None]))
    print(f"demo bank design: median {r:.0f} records per engine-year over the first baselines "
          f"-> ARL {wear.bank_arl(cfg, r):.0f} records, "
          f"h = {wear.bank_design(cfg, int(cand.sum()), r).threshold:.2f}")
    print(f"demo fleet ({len(engines)} engines, {time.perf_counter() - t0:.1f} s): "
          f"{len(false)} false wear alerts in {years:.1f} healthy engine-years = "
          f"{rate:.2f} per engine-year (target <= 1); {in_fault} alerts in fault windows")
    product_rate = product_false / years if years else float("nan")
    print(f"  product wear events (run_filters, default settings): {product_false} false = "
          f"{product_rate:.2f} per engine-year (target <= 1: "
          f"{'PASS' if product_rate <= 1.0 else 'FAIL'}); {product_in_fault} in fault windows")
    for item in false[:10]:
        print("  ", item)
    if learnt_tail is not None:
        demo_learnt(demo_runs, learnt_cfg or cfg, cand, W, est.H, learnt_tail, years,
                    learnt_metric)


# --- Experiment (``--learnt``): the fleet's wear direction learnt from other engines.


def wear_drift(dy: np.ndarray, var: np.ndarray, sig: np.ndarray, cand: np.ndarray,
               n_base: int, tail: int) -> np.ndarray:
    """One stretch's accumulated change in candidate-fault magnitudes [n_cand]: the weighted
    least-squares fit theta_k = (G_k^T R^-1 G_k)^-1 G_k^T R^-1 dy_k of each record's sensor
    deviation on the candidates' signatures, its mean over the last ``tail`` records less its
    mean over the first ``n_base`` (the bank's baseline)."""
    G = sig[:, :, cand]
    present = np.isfinite(dy)
    w = np.where(present, 1.0 / var, 0.0)
    A = np.einsum("sjn,sj,sjm->snm", G, w, G) + 1e-9 * np.eye(G.shape[2])
    b = np.einsum("sjn,sj,sj->sn", G, w, np.where(present, dy, 0.0))
    theta = np.linalg.solve(A, b[:, :, None])[:, :, 0]
    return theta[-tail:].mean(axis=0) - theta[:n_base].mean(axis=0)


def signature_metric(sig: np.ndarray, var: np.ndarray, cand: np.ndarray) -> np.ndarray:
    """M = mean over records of G_k^T R_k^-1 G_k [n_cand, n_cand]: a change theta in fault
    magnitudes measured by the size of its sensor signature (|G theta| in noise units)."""
    G = sig[:, :, cand]
    return np.einsum("sjn,sj,sjm->nm", G, 1.0 / var, G) / len(G)


def fleet_direction(drifts: list[np.ndarray], M: np.ndarray | None = None) -> np.ndarray:
    """The fleet's wear direction in candidate-fault magnitudes [n_cand]: the mean of the
    engines' unit drifts (each engine counted alike, however far it has worn), unit in the
    metric M (None: the magnitudes' own)."""
    M = np.eye(len(drifts[0])) if M is None else M
    units = [d / np.sqrt(d @ M @ d) for d in drifts if d @ M @ d > 0]
    v = np.mean(units, axis=0)
    return v / np.linalg.norm(v)


def nearest_fault(v: np.ndarray, sig: np.ndarray, var: np.ndarray, cand: np.ndarray,
                  ratio: float) -> tuple[int, bool, float]:
    """The candidate (index into the candidates) whose signature best explains the learnt
    direction's signature G v (WSSR in whitened sensor space at the mean condition), whether
    the runner-up's WSSR is at least ``ratio`` times its, and that WSSR ratio."""
    G = np.nanmean(sig[:, :, cand], axis=0)
    w = 1.0 / np.nanmean(var, axis=0)
    g = G @ v
    num = (G * w[:, None]).T @ g
    den = np.einsum("jn,j,jn->n", G, w, G)
    wssr = np.where(num > 0, g @ (w * g) - num**2 / den, np.inf)
    order = np.argsort(wssr)
    r = float(wssr[order[1]] / max(wssr[order[0]], 1e-300))
    return int(order[0]), r >= ratio, r


def direction_alert(z: np.ndarray, cycles: np.ndarray, cfg: wear.WearSettings,
                    rate: float | None, wssr: np.ndarray, f: np.ndarray, cand: np.ndarray,
                    named: tuple[int, bool, float]) -> tuple[int, int, int] | None:
    """One matched-filter CUSUM along the learnt direction on one stretch (z [S], the bank's
    standardisation and allowances, its threshold calibrated for a single CUSUM at the same
    budget): (crossing record, alert record, fault index among all faults) or None. The
    alert names the learnt direction's nearest fault at the crossing if that is confident,
    else waits for the usual WSSR attribution of the tuner change."""
    d = wear.bank_design(cfg, 1, rate)
    top = _bank_max(z[:, None], cycles, cfg, d.reference, d.scale)
    hit = np.flatnonzero(top > d.threshold)
    if not len(hit):
        return None
    kc = int(hit[0])
    fault, sure, _ = named
    if sure:
        return kc, kc, int(np.flatnonzero(cand)[fault])
    best, ok = wear.confident_fault(wssr, f, cand, cfg.confidence, cfg.hold)
    later = np.flatnonzero(ok[kc:])
    if not len(later):
        return None
    k = kc + int(later[0])
    return kc, k, int(best[k])


@dataclass(frozen=True)
class LearntEngine:
    """What the learnt-direction experiment needs of one FD001 engine."""

    dy: np.ndarray
    var: np.ndarray
    sig: np.ndarray
    cycles: np.ndarray
    rate: float | None
    wssr: np.ndarray
    f: np.ndarray
    bank: tuple[int, int] | None  # the product detector's first alert: (record, fault)
    naive: int | None  # the naive CUSUM's alarm record
    q: np.ndarray  # the filter's tuner estimates [S, m]


def tuner_name(drifts: list[np.ndarray], W: np.ndarray, H: np.ndarray, cand: np.ndarray,
               ratio: float) -> tuple[int, bool, float]:
    """The fault the fleet's mean unit tuner change (W norm) is attributed to by the usual
    WSSR (index among the candidates), whether confidently at ``ratio``, and the ratio."""
    units = [d / np.sqrt(d @ W @ d) for d in drifts if d @ W @ d > 0]
    wssr, f = wear.attribute(np.mean(units, axis=0), W, H)
    best, _ = wear.confident_fault(wssr, f, cand, ratio, 1)
    others = np.where(cand & (np.arange(len(cand)) != best[0]), wssr[0], np.inf)
    r = float(others.min() / max(wssr[0, best[0]], 1e-300))
    return int(np.flatnonzero(np.flatnonzero(cand) == best[0])[0]), r >= ratio, r


def _learnt_leads(eng: list[LearntEngine], cfg: wear.WearSettings, cand: np.ndarray,
                  drifts: list[np.ndarray], pool: list[int] | np.ndarray, naming: str,
                  tuner_drifts: list[np.ndarray], W: np.ndarray, H: np.ndarray,
                  M: np.ndarray | None = None) -> dict[str, object]:
    """The learnt CUSUM's figures with the direction learnt from the engines ``pool`` (each
    engine's own left out), or given (``pool`` an array: the direction itself)."""
    full = fleet_direction(drifts, M)
    given = isinstance(pool, np.ndarray)
    cross, alert, faults, both, both_faults, cos, sure, ratios = [], [], [], [], [], [], 0, []
    for i, e in enumerate(eng):
        v = pool if given else fleet_direction([drifts[j] for j in pool if j != i], M)
        cos.append(float(v @ full))
        if naming == "sensor":
            named = nearest_fault(v, e.sig, e.var, cand, cfg.confidence)
        elif naming == "tuner":
            named = tuner_name([tuner_drifts[j] for j in range(len(eng)) if j != i] if given
                               else [tuner_drifts[j] for j in pool if j != i], W, H, cand,
                               cfg.confidence)
        else:
            named = (0, False, 0.0)
        sure += named[1]
        ratios.append(named[2])
        z = wear.matched_filter(e.dy, e.var, e.sig[:, :, cand] @ v[:, None])[:, 0]
        res = direction_alert(z, e.cycles, cfg, e.rate, e.wssr, e.f, cand, named)
        end = e.cycles[-1]
        firsts = []
        if res is not None:
            cross.append(int(end - e.cycles[res[0]]))
            alert.append(int(end - e.cycles[res[1]]))
            faults.append(res[2])
            firsts.append((res[1], res[2]))
        if e.bank is not None:
            firsts.append(e.bank)
        if firsts:
            k, fault = min(firsts)
            both.append(int(end - e.cycles[k]))
            both_faults.append(fault)
    v = pool if given else fleet_direction([drifts[j] for j in pool], M)
    return dict(v=v, cross=cross, alert=alert, faults=faults, both=both,
                both_faults=both_faults, cos=cos, sure=sure, ratios=ratios)


def fd001_learnt(eng: list[LearntEngine], cfg: wear.WearSettings, cand: np.ndarray, hpc: int,
                 names: list[str], tail: int, W: np.ndarray, H: np.ndarray,
                 metric: bool = False) -> None:
    """The fleet-direction CUSUM on FD001, leave-one-out, learnt from the whole fleet and from
    its first 20 and 10 units only (a fleet starting out), beside the product detector."""
    n = len(eng)
    drifts = [wear_drift(e.dy, e.var, e.sig, cand, cfg.n_base, tail) for e in eng]
    M = np.mean([signature_metric(e.sig, e.var, cand) for e in eng], axis=0) if metric else None
    b0 = cfg.settle
    tuner_drifts = [e.q[-tail:].mean(axis=0) - e.q[b0 : b0 + cfg.n_base].mean(axis=0)
                    for e in eng]
    naive = [int(e.cycles[-1] - e.cycles[e.naive]) for e in eng if e.naive is not None]
    d1 = wear.bank_design(cfg, 1, float(np.median([e.rate for e in eng if e.rate])))
    print(f"\nlearnt fleet direction (leave-one-out; drift = fault-magnitude fit, last {tail} "
          f"records less the first {cfg.n_base}); one CUSUM, h = {d1.threshold:.2f}; naive "
          f"{_median(naive)} cycles")
    cn = [names[j] for j in np.flatnonzero(cand)]
    print("named: the learnt direction's fault named at the crossing (sensor: nearest signature;"
          " tuner: the fleet's mean tuner change by the WSSR; wssr: never, the usual wait)")
    print(f"{'learnt from':20s}{'direction (' + ' '.join(cn) + ')':>40s}{'cos min':>9s}"
          f"{'named':>7s}{'crossing':>10s}{'alert':>8s}{'HPC':>6s}{'n':>5s}"
          f"{'+bank':>8s}{'HPC':>6s}{'n':>5s}")
    hpc_given = (np.flatnonzero(cand) == hpc).astype(float)
    pools: tuple[tuple[str, list[int] | np.ndarray], ...] = (
        ("all (n-1)", list(range(n))), ("first 20", list(range(min(20, n)))),
        ("first 10", list(range(min(10, n)))), ("HPC given", hpc_given))
    for (label, pool), naming in itertools.product(pools, ("sensor", "tuner", "wssr")):
        r = _learnt_leads(eng, cfg, cand, drifts, pool, naming, tuner_drifts, W, H, M)
        label = f"{label} {naming}"
        v = r["v"]
        print(f"{label:20s}{' '.join(f'{x:+.2f}' for x in v):>40s}{min(r['cos']):>9.3f}"
              f"{r['sure']:>7d}{_median(r['cross']):>10s}{_median(r['alert']):>8s}"
              f"{_share(sum(f == hpc for f in r['faults']), len(r['faults'])):>6s}"
              f"{len(r['alert']):>5d}{_median(r['both']):>8s}"
              f"{_share(sum(f == hpc for f in r['both_faults']), len(r['both_faults'])):>6s}"
              f"{len(r['both']):>5d}")
        print(f"{'':14s}naming WSSR ratio median {np.median(r['ratios']):.2f} "
              f"(min {min(r['ratios']):.2f})")


def white_learnt(eng: LearntEngine, v: np.ndarray, cfg: wear.WearSettings,
                 cfg_l: wear.WearSettings, cand: np.ndarray, runs: int, horizon: int) -> None:
    """White sensor noise at an FD001 engine's noise and signatures (seeded): the share of
    healthy engines whose bank (the candidates), learnt-direction CUSUM, or either, crosses
    within ``horizon`` armed records, against the design's 1 - exp(-horizon / ARL)."""
    rng = np.random.default_rng(20261125)
    b1 = cfg.settle + cfg.n_base
    S = b1 + horizon
    sig = np.broadcast_to(eng.sig[:1], (S, *eng.sig.shape[1:]))
    var = np.broadcast_to(eng.var[:1], (S, eng.var.shape[1]))
    cyc = np.arange(1.0, S + 1.0)
    arl = wear.bank_arl(cfg, eng.rate)
    db = wear.bank_design(cfg, int(cand.sum()), eng.rate)
    d1 = wear.bank_design(cfg_l, 1, eng.rate)
    g = sig[:, :, cand]
    horizons = np.array([8, 16, 24, 50, 100, 200, horizon])
    hits = np.zeros((runs, 2, len(horizons)), bool)
    for r in range(runs):
        dy = rng.normal(size=var.shape) * np.sqrt(var)
        zb = wear.matched_filter(dy, var, g)
        zl = wear.matched_filter(dy, var, g @ v[:, None])
        at = b1 - 1 + horizons
        hits[r, 0] = _bank_max(zb, cyc, cfg, db.reference, db.scale)[at] > db.threshold
        hits[r, 1] = _bank_max(zl, cyc, cfg, d1.reference, d1.scale)[at] > d1.threshold
    both = cfg.false_alerts_per_year + cfg_l.false_alerts_per_year
    arl_both = arl * cfg.false_alerts_per_year / both
    print(f"white sensor noise ({runs} engines, seeded): share of healthy engines crossed within "
          f"T armed records; design 1 - exp(-T / ARL): the bank's (ARL {arl:.0f}, h = "
          f"{db.threshold:.2f}) and the two's together ({both:g} per engine-year, ARL "
          f"{arl_both:.0f}); learnt CUSUM at {cfg_l.false_alerts_per_year:g} per engine-year, "
          f"h = {d1.threshold:.2f}")
    print(f"{'T':>6s}{'bank design':>13s}{'bank':>8s}{'learnt':>8s}{'both design':>13s}"
          f"{'either':>8s}")
    for j, T in enumerate(horizons):
        print(f"{T:>6d}{-np.expm1(-T / arl):>13.3f}{hits[:, 0, j].mean():>8.3f}"
              f"{hits[:, 1, j].mean():>8.3f}{-np.expm1(-T / arl_both):>13.3f}"
              f"{hits[:, :, j].any(axis=1).mean():>8.3f}")



@dataclass(frozen=True)
class DemoEngine:
    """What the learnt-direction experiment needs of one demo engine."""

    dy: np.ndarray
    var: np.ndarray
    sig: np.ndarray
    cycles: np.ndarray
    epoch: np.ndarray
    resets: np.ndarray
    faulty: np.ndarray
    q: np.ndarray
    scan: wear.WearScan


def demo_learnt(eng: list[DemoEngine], cfg: wear.WearSettings, cand: np.ndarray,
                W: np.ndarray, H: np.ndarray, tail: int, years: float,
                metric: bool = False) -> None:
    """The fleet-direction CUSUM on the demo fleet, its direction learnt from the fleet's own
    other engines' stretches (leave-one-out, the tuner naming): false alerts in healthy
    records, alone and with the product detector (the earlier alert of each stretch)."""
    b1 = cfg.settle + cfg.n_base
    sens: list[list[np.ndarray]] = []
    tune: list[list[np.ndarray]] = []
    for e in eng:
        sd, td = [], []
        for s0, s1 in wear._segments(len(e.q), e.resets):
            if s1 - s0 >= b1 + tail:
                sd.append(wear_drift(e.dy[s0:s1], e.var[s0:s1], e.sig[s0:s1], cand,
                                     cfg.n_base, tail))
                td.append(e.q[s1 - tail : s1].mean(axis=0)
                          - e.q[s0 + cfg.settle : s0 + b1].mean(axis=0))
        sens.append(sd)
        tune.append(td)
    M = (np.mean([signature_metric(e.sig, e.var, cand) for e in eng], axis=0)
         if metric else None)
    false_l, fault_l, false_u, fault_u = 0, 0, 0, 0
    for i, e in enumerate(eng):
        v = fleet_direction([d for j, ds in enumerate(sens) if j != i for d in ds], M)
        named = tuner_name([d for j, ds in enumerate(tune) if j != i for d in ds], W, H, cand,
                           cfg.confidence)
        z = wear.matched_filter(e.dy, e.var, e.sig[:, :, cand] @ v[:, None])[:, 0]
        bank = {a.baseline_start - cfg.settle: a.index for a in e.scan.alerts}
        for s0, s1 in wear._segments(len(e.q), e.resets):
            if s1 - s0 <= b1:
                continue
            rate = wear.record_rate(e.epoch[s0 : s0 + b1])
            res = direction_alert(z[s0:s1], e.cycles[s0:s1], cfg, rate, e.scan.wssr[s0:s1],
                                  e.scan.f[s0:s1], cand, named)
            k_l = None if res is None else s0 + res[1]
            if k_l is not None:
                false_l += not e.faulty[k_l]
                fault_l += bool(e.faulty[k_l])
            ks = [k for k in (k_l, bank.get(s0)) if k is not None]
            if ks:
                false_u += not e.faulty[min(ks)]
                fault_u += bool(e.faulty[min(ks)])
        if i == 0:
            print(f"demo learnt direction (engine 0's, leave-one-out): "
                  f"{' '.join(f'{x:+.2f}' for x in v)}; named {named}")
    print(f"demo learnt-direction CUSUM: {false_l} false = {false_l / years:.2f} per "
          f"engine-year ({fault_l} in fault windows); with the product detector (the earlier "
          f"of each stretch): {false_u} false = {false_u / years:.2f} per engine-year "
          f"({fault_u} in fault windows; target <= 1)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    d = wear.WearSettings()
    ap.add_argument("--rate", type=float, default=d.rate)
    ap.add_argument("--margin", type=float, default=d.margin)
    ap.add_argument("--floor", type=float, default=d.margin_floor)
    ap.add_argument("--limit", type=float, default=d.limit)
    ap.add_argument("--kappa", type=float, default=d.bank_reference)
    ap.add_argument("--alpha", type=float, default=d.bank_alpha)
    ap.add_argument("--per-year", type=float, default=d.false_alerts_per_year,
                    help="the bank's designed false alerts per engine-year")
    ap.add_argument("--arl", type=float, default=d.bank_arl,
                    help="the bank's family-wise ARL in records instead")
    ap.add_argument("--h", type=float, default=d.bank_threshold)
    ap.add_argument("--siegmund", action="store_true",
                    help="the bank's threshold from Siegmund's ARL with Bonferroni, not calibrated")
    ap.add_argument("--bank-rate", type=float, default=d.bank_rate)
    ap.add_argument("--confidence", type=float, default=d.confidence)
    ap.add_argument("--hold", type=int, default=d.hold)
    ap.add_argument("--no-bank", action="store_true", help="tuner estimates only")
    ap.add_argument("--units", type=int, default=None)
    ap.add_argument("--fd001", type=Path, default=FD001)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"))
    ap.add_argument("--skip-demo", action="store_true")
    ap.add_argument("--horizon", type=int, default=350,
                    help="frontier: armed records over which the false-alarm rate is met")
    ap.add_argument("--runs", type=int, default=2000, help="frontier: white engines")
    ap.add_argument("--skip-frontier", action="store_true")
    ap.add_argument("--learnt", type=int, default=None, metavar="TAIL",
                    help="experiment: the fleet's wear direction learnt from the other engines "
                    "(their drift over the last TAIL records), one CUSUM along it")
    ap.add_argument("--learnt-per-year", type=float, default=None,
                    help="the learnt CUSUM's designed false alerts per engine-year "
                    "(default --per-year)")
    ap.add_argument("--learnt-metric", action="store_true",
                    help="each engine's change counted as a unit in its sensor signature's "
                    "size (noise units), not in fault magnitudes")
    args = ap.parse_args()
    cfg = wear.WearSettings(limit=args.limit, rate=args.rate, margin=args.margin,
                            margin_floor=args.floor, bank_reference=args.kappa,
                            bank_alpha=args.alpha, false_alerts_per_year=args.per_year,
                            bank_arl=args.arl, bank_threshold=args.h,
                            bank_calibrated=not args.siegmund,
                            bank_rate=args.bank_rate,
                            confidence=args.confidence, hold=args.hold)
    print(_common.load_line())
    cfg_l = replace(cfg, false_alerts_per_year=args.learnt_per_year or args.per_year)
    fig = fd001(args.fd001, cfg, args.units, not args.no_bank, args.cache, args.learnt, cfg_l,
                args.learnt_metric)
    if not args.skip_frontier:
        frontier(fig, args.horizon, args.runs)
    if not args.skip_demo:
        demo(cfg, args.cache, not args.no_bank, args.learnt, cfg_l, args.learnt_metric)
    print(f"load average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
