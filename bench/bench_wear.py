"""Wear (gradual deterioration) detection on NASA C-MAPSS FD001 and on the demo fleet.

FD001 train (100 engines, HPC degradation run to failure): the product's filter
(``pipeline.run_filters`` on the design of tests/app/test_fd001.py) and the wear detector
(``estimation.wear.wear_scan``) on its tuner estimates, next to a naive per-engine signature
CUSUM on the sensor deviations (``estimation.wear.signature_cusum``, HPC signature, no alarm
before cycle 50) computed in the same run: engines alerted before failure, median lead (cycles
before failure), share of alerts attributed to HPC; the product's own shift detector too.
Demo fleet (``app.services.demo.fleet``, simulated, built-in engine): wear alerts outside the
injected faults' windows per engine-year.

Next to the bank alone (``wear_scan`` on the filter's estimates, cycles as C-MAPSS counts them,
default settings unless given: no fleet direction), the product path's: the ``wear`` events
``run_filters`` raises itself (``estimation.wear.wear_steps`` record by record, cycles counted
in flights, default settings: the bank and the fleet CUSUM), on FD001 with the design
``fleethealth import-cmapss`` creates (the built-in engine's default schedule grid, as a
server builds it), all units in one batch as a job estimates them after the import. The
fleet CUSUM (``estimation.wear``: ``fleet_direction``) runs along the wear direction learnt
from the other engines' drifts (each engine's own left out); the false-alert budget is split
0.9 / 0.1 between it and the bank. Printed too: the fleet direction of unit 1, the false
crossings of the bank, the fleet CUSUM and either on seeded white sensor noise at each
horizon against the budget, and the product under other fleet-CUSUM settings
(``fleet_variants``; ``--skip-variants``).

The wear detector gets the records' sensor deviations too (its directional CUSUM bank);
``--no-bank`` scans the tuner estimates alone (limit and rate alerts).

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
        [--horizon 350 --runs 2000 | --skip-frontier] [--white 1000] [--skip-variants]

(The bank's threshold is set from its designed false alerts per engine-year --per-year and
each engine's record rate over its baseline, by the bank's Monte Carlo calibration
(``estimation.wear.calibrated_threshold``; --siegmund: Siegmund's ARL with Bonferroni); --arl
gives the family-wise ARL in records instead, --h the threshold itself; --alpha 0 takes the
bank's baseline as exact.)
"""

from __future__ import annotations

import argparse
import os
import time
from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path

import _common  # (import path)
import numpy as np

from app.engine_cache import engine_schedule
from app.services.demo import fleet
from app.services.snapshots import estimator, run
from estimation import wear
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from estimation.shift_detector import N_CONFIRM
from tests.support import detection_replay, fd001_replay

FD001 = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmapss" / "train_FD001.txt"
YEAR_S = 365.25 * 86400.0


def health_candidates(S_full: np.ndarray, p: int) -> np.ndarray:
    """Library faults that are module deteriorations (no actuator-bias rows): wear candidates."""
    return np.all(S_full[p:] == 0.0, axis=0)


def fd001(path: Path, cfg: wear.WearSettings, units: int | None, use_sensors: bool,
          cache: Path, white_runs: int = 1000) -> Fd001Figures:
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
        shifts = [ev for ev in tr.events if ev.kind != "wear"]
        if shifts:
            product.append((shifts[0], int(e.cycle[-1]) - _cycle_at(e, shifts[0].epoch)))
    # The product path: the design import-cmapss makes, its pipeline's own wear events.
    t1 = time.perf_counter()
    est_p = fd001_replay.fd001_estimator(engine_schedule(cache))
    engines_p = fd001_replay.fd001_runs(path, est_p, units)
    wear_events = []
    tracks_p = fd001_replay.filter_tracks(est_p, [e.run for e in engines_p], batch=256)
    for e, tr in zip(engines_p, tracks_p, strict=True):
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
    print(f"{'bank alone (wear_scan)':34s}{len(ours):>7d}/{n:<3d}"
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
    product_kinds = [ev.shift["wear"]["alert"] for ev, _ in wear_events]
    print(f"bank-alone alert kinds: "
          f"{dict(Counter(map(str, kinds)))}; product's: "
          f"{dict(Counter(product_kinds))}")
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
    # The fleet direction of the first engine (learnt from the 99 others' drifts) and the
    # false crossings of the bank and the fleet CUSUM on white noise at its budget split.
    det_p = run.wear_detector(est_p)
    drifts = [tr.drift for tr in tracks_p]
    v = wear.fleet_direction([d for d in drifts[1:] if d is not None])
    if v is not None:
        named = wear.fleet_fault(det_p, v)
        print(f"fleet direction of unit 1 (learnt from the other {n - 1}): "
              + " ".join(f"{f} {x:+.2f}" for f, x, c in zip(est_p.layout.faults, v,
                                                           det_p.candidates, strict=True) if c)
              + f"; attributed to {est_p.layout.faults[named] if named >= 0 else 'none'}")
        white_fleet(est_p, engines_p[0].run, v, wear.WearSettings(), rate, white_runs, 365)
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


def demo(cfg: wear.WearSettings, cache: Path, use_sensors: bool) -> None:
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
    product_false, product_in_fault, product_twice = 0, 0, 0
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
        # Wear events on a step the shift detector raised an event on: from its alarm to the
        # end of the wear baseline after its isolation (the same change alerted twice).
        steps = [ev.seq for ev in out.events if ev.kind != "wear"]
        product_twice += sum(1 for ev in out.events if ev.kind == "wear" and any(
            s <= ev.seq < s + N_CONFIRM + cfg.settle + cfg.n_base for s in steps))
        rates.append(wear.record_rate(t[: cfg.settle + cfg.n_base]))
        scan = wear.wear_scan(q, est.H, W, cycles, resets, cand, cfg, epoch=t, **sensors)
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
          f"{'PASS' if product_rate <= 1.0 else 'FAIL'}); {product_in_fault} in fault windows, "
          f"{product_twice} on a step the shift detector raised an event on")
    for item in false[:10]:
        print("  ", item)
    kinds = [ev.shift["wear"]["alert"] for out in outs for ev in out.events
             if ev.kind == "wear"]
    directions = sum(out.state.wear.direction is not None for out in outs)
    print(f"  product wear events by kind: "
          f"{dict(Counter(map(str, kinds)))}; engines whose "
          f"latest stretch runs the fleet CUSUM: {directions} of {len(outs)}")


# --- The product's fleet CUSUM (``estimation.wear``: ``fleet_direction``, ``FLEET`` alerts).


def fleet_variants(path: Path, cache: Path, units: int | None, naive: list[int]) -> None:
    """The product path (``run_filters`` on the design import-cmapss makes, the fleet
    direction learnt from the other engines of the run and of earlier batches) under other
    settings of the fleet CUSUM, beside the naive CUSUM's median on the same records."""
    est = fd001_replay.fd001_estimator(engine_schedule(cache))
    engines = fd001_replay.fd001_runs(path, est, units)
    d = wear.WearSettings()
    variants: list[tuple[str, wear.WearSettings, int]] = [
        ("product (share 0.9, fit 1.3, min 5)", d, 256),
        ("fleet alert without the change-kind condition", replace(d, fleet_fit=0.0), 256),
        ("fleet fit 1.0 (at least as good as the best)", replace(d, fleet_fit=1.0), 256),
        ("fleet share 0.75", replace(d, fleet_share=0.75), 256),
        ("fleet share 0.5", replace(d, fleet_share=0.5), 256),
        ("batches of 20 engines (earlier batches' drifts)", d, 20),
        ("no fleet direction (the bank alone)", replace(d, fleet_min=10**9), 256),
    ]
    print(f"\nthe product's wear events under other fleet-CUSUM settings (naive "
          f"{_median(naive)} cycles on the same records)")
    print(f"{'':50s}{'alerted':>10s}{'median lead':>13s}{'HPC':>7s}  kinds")
    for name, cfg, batch in variants:
        tracks = fd001_replay.filter_tracks(est, [e.run for e in engines], batch, cfg)
        leads, hpc, kinds = [], 0, []
        for e, tr in zip(engines, tracks, strict=True):
            first = next((ev for ev in tr.events if ev.kind == "wear"), None)
            if first is not None and _cycle_at(e, first.epoch) < int(e.cycle[-1]):
                leads.append(int(e.cycle[-1]) - _cycle_at(e, first.epoch))
                hpc += first.fault == "HPC"
                kinds.append(first.shift["wear"]["alert"])
        counts = dict(Counter(map(str, kinds)))
        print(f"{name:50s}{len(leads):>7d}/{len(engines):<3d}{_median(leads):>13s}"
              f"{_share(hpc, len(leads)):>7s}  {counts}")


def white_fleet(est: estimator.SnapshotEstimator, run0: run.EngineRun, v: np.ndarray,
                cfg: wear.WearSettings, rate: float | None, runs: int, horizon: int) -> None:
    """White sensor noise at an FD001 engine's noise and signatures (seeded): the share of
    healthy engines whose bank, fleet CUSUM (along v, standardised as the bank), or either
    crosses within T armed records, each at its share of the budget (``wear._budgets``),
    against the design's 1 - exp(-T / ARL) for the whole budget."""
    rng = np.random.default_rng(20261125)
    b1 = cfg.settle + cfg.n_base
    S = b1 + horizon
    _dy, var0, sig0 = fd001_replay.sensor_deviations(est, run0)
    cand = wear.health_candidates(est.S_full, len(est.layout.health))
    sig = np.broadcast_to(sig0[:1], (S, *sig0.shape[1:]))
    var = np.broadcast_to(var0[:1], (S, var0.shape[1]))
    cyc = np.arange(1.0, S + 1.0)
    arl = wear.bank_arl(cfg, rate)
    bank_cfg, fleet_cfg = wear._budgets(cfg, True)
    assert fleet_cfg is not None
    db = wear.bank_design(bank_cfg, int(cand.sum()), rate)
    d1 = wear.bank_design(fleet_cfg, 1, rate)
    horizons = np.array([8, 16, 24, 50, 100, 200, horizon])
    hits = np.zeros((runs, 2, len(horizons)), bool)
    for r in range(runs):
        dy = rng.normal(size=var.shape) * np.sqrt(var)
        zb = wear.matched_filter(dy, var, sig[:, :, cand])
        zl = wear.matched_filter(dy, var, sig @ v[:, None])
        at = b1 - 1 + horizons
        hits[r, 0] = _bank_max(zb, cyc, cfg, db.reference, db.scale)[at] > db.threshold
        hits[r, 1] = _bank_max(zl, cyc, cfg, d1.reference, d1.scale)[at] > d1.threshold
    print(f"white sensor noise ({runs} engines, seeded): share of healthy engines crossed within "
          f"T armed records; design 1 - exp(-T / ARL), ARL {arl:.0f} records (the whole budget); "
          f"the bank at {bank_cfg.false_alerts_per_year:g} per engine-year (h = "
          f"{db.threshold:.2f}), the fleet CUSUM at {fleet_cfg.false_alerts_per_year:g} "
          f"(h = {d1.threshold:.2f})")
    print(f"{'T':>6s}{'design':>9s}{'bank':>8s}{'fleet':>8s}{'either':>8s}")
    for j, T in enumerate(horizons):
        print(f"{T:>6d}{-np.expm1(-T / arl):>9.3f}{hits[:, 0, j].mean():>8.3f}"
              f"{hits[:, 1, j].mean():>8.3f}{hits[:, :, j].any(axis=1).mean():>8.3f}")


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
    ap.add_argument("--white", type=int, default=1000,
                    help="white-noise engines of the bank and fleet CUSUM false-crossing check")
    ap.add_argument("--skip-variants", action="store_true",
                    help="no table of the product's fleet-CUSUM settings")
    args = ap.parse_args()
    cfg = wear.WearSettings(limit=args.limit, rate=args.rate, margin=args.margin,
                            margin_floor=args.floor, bank_reference=args.kappa,
                            bank_alpha=args.alpha, false_alerts_per_year=args.per_year,
                            bank_arl=args.arl, bank_threshold=args.h,
                            bank_calibrated=not args.siegmund,
                            bank_rate=args.bank_rate,
                            confidence=args.confidence, hold=args.hold)
    print(_common.load_line())
    fig = fd001(args.fd001, cfg, args.units, not args.no_bank, args.cache, args.white)
    if not args.skip_variants:
        fleet_variants(args.fd001, args.cache, args.units, fig.naive)
    if not args.skip_frontier:
        frontier(fig, args.horizon, args.runs)
    if not args.skip_demo:
        demo(cfg, args.cache, not args.no_bank)
    print(f"load average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
