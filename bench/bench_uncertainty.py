"""Honest health uncertainty per design: calibrate on several simulated fleets, score on others.

For each design (method:m, "+bias": the tuners also span the three actuator biases) the
model-error term of ``estimation.uncertainty`` is fitted as the product fits it
(``app.services.designs.calibration``: demo-like fleets simulated with each of
``--calibrate-seeds``, pooled) and scored on a fleet simulated with each of ``--seeds``:
coverage of the honest 1-sigma and 2-sigma of the level (and of the
filter's own 1-sigma), level RMS, change since the baseline (RMS over all settled records and
at each segment's end) and the product's fleet-average slopes (``app.services.fleet.slopes``:
weekly means split at baseline resets, the pieces' slopes corrected by the calibrated slope
correction, inverse-variance mean, calibrated gain; percent per year) against the simulator's
truth, next to the issue's targets. A slope the calibration finds unobservable is printed as
such and left out of the worst slope error.

The engine page's other bands are scored on the same fleets, fleet by fleet against the same
band (``figure_band``): each aux output in percent (beside the filter's own sigma, what the page
showed before), its value in engineering units, each tuner against V* h of the true health, and
the smoothed deltas and EGT margin.

The slopes' 1-sigma (the pieces' noise, the error common to a fleet and the calibrated gain's
own standard error, times the calibrated scale, ``estimation.uncertainty.fleet_slope``) is
scored over the seeds: the fraction of the scoring fleets whose true slope lies within +-1
sigma and +-2 sigma of the product's, per shown slope and pooled, and the fraction within
30 %. That coverage is
conditional on the one draw of calibration fleets the product uses; ``--rotations R`` (slow)
also draws R other sets of as many calibration fleets from all the fleets of the run (the
calibration and scoring fleets' trend pieces), fits the slope calibration on each
(``uncertainty.fit_fleet_slope``) and scores it on the fleets it did not see: the coverage
over calibration draws as well.

    .venv/bin/python bench/bench_uncertainty.py                       # 8 aircraft, a year
    .venv/bin/python bench/bench_uncertainty.py --aircraft 12 --designs svd:8+bias
    .venv/bin/python bench/bench_uncertainty.py --designs subset:10 --rotations 200
    .venv/bin/python bench/bench_uncertainty.py --designs subset:10 --actuators
"""

from __future__ import annotations

import argparse
import json
import pickle
import time
from pathlib import Path

import _common  # noqa: F401  (import path)
import numpy as np

from app.engine_cache import engine_schedule
from app.services.demo import fleet as demo_fleet
from app.services.designs import calibration
from estimation import uncertainty
from tests.support import health_uncertainty

DESIGNS = ("subset:10", "svd:8+bias", "svd:6")
TARGETS = ("targets: shown parameters 1-sigma coverage 55-85 %, 2-sigma >= 85 %; change RMS "
           "<= 0.5 %; fleet-average slopes within 30 % of the truth (observable ones), the true "
           "slope within +-1 sigma on 55-85 % of the fleets and +-2 sigma on >= 85 %")
# Scoring seeds: the demo fleet's and every seventh after it (none a calibration seed).
SCORING_SEEDS = tuple(demo_fleet.SEED + 7 * k for k in range(16))


def slope_coverage(names: tuple[str, ...], rows: list[tuple[np.ndarray, ...]]) -> str:
    """Coverage of the slopes' 1-sigma over fleets: rows of (error, sigma, true[, peer sigma])
    [p] per fleet (NaN where not shown); per shown slope and pooled, with the targets' verdict
    and, given, the coverage of the peer sigma (without the gain's standard error)."""
    err, sigma, true, *peer = (np.array(x) for x in zip(*rows, strict=True))
    shown = np.isfinite(err) & np.isfinite(sigma)
    z = np.abs(err) / sigma
    rel = np.abs(err) / np.maximum(np.abs(true), calibration.YEAR_SLOPE_FLOOR)

    def peer_text(ok: np.ndarray) -> str:
        if not peer:
            return ""
        zp = np.abs(err[ok]) / peer[0][ok]
        return (f"; without the gain's error {np.mean(zp <= 1):.0%} / {np.mean(zp <= 2):.0%}")

    lines = []
    for k in np.flatnonzero(shown.any(axis=0)):
        ok = shown[:, k]
        lines.append(f"  {names[k]}: {int(ok.sum())} fleet slopes, within 1 sigma "
                     f"{np.mean(z[ok, k] <= 1):.0%}, 2 sigma {np.mean(z[ok, k] <= 2):.0%}, "
                     f"within 30 % {np.mean(rel[ok, k] <= 0.3):.0%} (worst {rel[ok, k].max():.0%}),"
                     f" sigma {sigma[ok, k].min():.3f}-{sigma[ok, k].max():.3f} %/year"
                     + peer_text(np.where(np.arange(shown.shape[1]) == k, ok[:, None], False)))
    if not shown.any():
        return "  no slope shown"
    c1, c2 = float(np.mean(z[shown] <= 1)), float(np.mean(z[shown] <= 2))
    verdict = "met" if 0.55 <= c1 <= 0.85 and c2 >= 0.85 else "missed"
    lines.append(f"  pooled: {int(shown.sum())} fleet slopes, within 1 sigma {c1:.0%} "
                 f"(55-85 %), 2 sigma {c2:.0%} (>= 85 %): {verdict}; within 30 % "
                 f"{np.mean(rel[shown] <= 0.3):.0%}" + peer_text(shown))
    return "\n".join(lines)


def per_fleet_band(calib: uncertainty.Calibration,
                   covers: list[tuple[np.ndarray, ...]]) -> str:
    """The issue's band fleet by fleet: per shown parameter, the scoring fleets whose level
    (and change) 1-sigma coverage lies within 55-85 % and 2-sigma coverage is >= 85 %, with
    the range over fleets; and the fleets where every shown parameter is in the band."""
    c1, c2, d1, d2 = (np.array(x) for x in zip(*covers, strict=True))
    shown = np.asarray(calib.observable)
    level_ok = (c1 >= 0.55) & (c1 <= 0.85) & (c2 >= 0.85)
    change_ok = (d1 >= 0.55) & (d1 <= 0.85) & (d2 >= 0.85)
    n = len(covers)
    lines = [f"the band per fleet (1-sigma 55-85 %, 2-sigma >= 85 %) over {n} scoring fleets:"]
    for k in np.flatnonzero(shown):
        lines.append(
            f"  {calib.names[k]}: level in band on {int(level_ok[:, k].sum())}/{n} (1-sigma "
            f"{c1[:, k].min():.3f}-{c1[:, k].max():.3f}, 2-sigma min {c2[:, k].min():.3f}); "
            f"change on {int(change_ok[:, k].sum())}/{n} (1-sigma {d1[:, k].min():.3f}-"
            f"{d1[:, k].max():.3f}, 2-sigma min {d2[:, k].min():.3f})")
    every = int(np.all(level_ok[:, shown], axis=1).sum()) if shown.any() else n
    every_change = int(np.all(change_ok[:, shown], axis=1).sum()) if shown.any() else n
    lines.append(f"  fleets with every shown level in the band: {every}/{n}; every shown change: "
                 f"{every_change}/{n}")
    return "\n".join(lines)


def figure_band(rows: list[dict[str, tuple[float, float, float]]]) -> str:
    """The engine page's other bands (aux outputs in percent, their values in engineering
    units, the deltas and EGT margin) fleet by fleet against the issue's band, with the
    filter's own sigma (what the aux group showed before) beside the aux outputs."""
    n = len(rows)
    lines = [f"the engine page's other figures, the band per fleet (1-sigma 55-85 %, 2-sigma "
             f">= 85 %) over {n} scoring fleets:"]
    every = np.ones(n, bool)
    for name in rows[0] if rows else ():
        c1, c2, f1 = (np.array([r[name][i] for r in rows]) for i in range(3))
        ok = (c1 >= 0.55) & (c1 <= 0.85) & (c2 >= 0.85)
        every &= ok
        before = (f"; the filter's own sigma {np.nanmin(f1):.2f}-{np.nanmax(f1):.2f}"
                  if np.isfinite(f1).any() else "")
        lines.append(f"  {name:12s} in band on {int(ok.sum())}/{n} (1-sigma {c1.min():.2f}-"
                     f"{c1.max():.2f}, 2-sigma min {c2.min():.2f}){before}")
    lines.append(f"  fleets with every figure in the band: {int(every.sum())}/{n}")
    return "\n".join(lines)


def fleet_average(what: str, unit: str, names: tuple[str, ...], shown: np.ndarray,
                  rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> str:
    """The fleet page's monthly fleet average of ``what`` (the shown ``names``) against the
    truth, over the scoring fleets: the worst fleet's RMS over months, calibrated (what the page
    shows) and as estimated (the page before), and the spread over engines shown against the
    true spread."""
    level, raw, ratio = (np.array([r[i] for r in rows])[:, shown] for i in range(3))
    lines = [f"fleet-average {what} per month (the fleet page) against the truth, RMS over "
             f"months, worst fleet [{unit}]: calibrated / as estimated; spread over engines "
             "shown / true (median over fleets)"]
    for k, n in enumerate(n for n, o in zip(names, shown, strict=True) if o):
        lines.append(f"  {n:10s} {level[:, k].max():5.2f} / {raw[:, k].max():5.2f}   "
                     f"spread {np.median(ratio[:, k]):4.2f}")
    return "\n".join(lines)


def rotations(pieces: list[uncertainty.TrendPieces], observable: np.ndarray, k: int,
              draws: int, names: tuple[str, ...]) -> str:
    """Coverage over ``draws`` random sets of ``k`` calibration fleets from ``pieces``, each
    scored on the others (slopes shown where the level is ``observable`` and the draw has a
    gain), beside the sigma without the gain's standard error."""
    rng = np.random.default_rng(0)
    rows, cover1, gains, gain_stds = [], [], [], []
    for _ in range(draws):
        pick = rng.choice(len(pieces), k, replace=False)
        fit = uncertainty.fit_fleet_slope([pieces[i] for i in pick],
                                          calibration.YEAR_SLOPE_FLOOR,
                                          calibration.SLOPE_TOLERANCE, correct=True)
        shown = observable & np.isfinite(fit.gain)
        gains.append(fit.gain)
        gain_stds.append(fit.gain_std)
        z = []
        for i in sorted(set(range(len(pieces))) - set(pick.tolist())):
            slope, sigma, true = pieces[i].fleet(fit.gain, fit.noise, fit.common, fit.gain_std,
                                                 fit.correction, fit.scale)
            peer = pieces[i].fleet(fit.gain, fit.noise, fit.common, None, fit.correction,
                                   fit.scale)[1]
            nan = np.where(shown, 0.0, np.nan)
            rows.append((slope - true + nan, sigma + nan, true, peer + nan))
            z.append(np.abs(slope - true)[shown] / sigma[shown])
        if shown.any():
            cover1.append(np.mean(np.concatenate(z) <= 1))
    c1 = np.array(cover1)
    g, u = np.array(gains), np.array(gain_stds)
    spread = " ".join(f"{n} {np.nanstd(g[:, j]):.3f} against {np.nanmean(u[:, j]):.3f}"
                      for j, n in enumerate(names) if np.isfinite(g[:, j]).sum() > 2)
    return (f"  {draws} draws of {k} calibration fleets from {len(pieces)}, each scored on the "
            f"other {len(pieces) - k} (per draw, the 1-sigma coverage ranges "
            f"{np.percentile(c1, 10):.0%}-{np.percentile(c1, 90):.0%}, 10-90 %); the gain's "
            f"spread over the draws against its mean jackknife standard error: {spread}\n"
            + slope_coverage(names, rows))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--aircraft", type=int, default=calibration.CALIBRATION_AIRCRAFT)
    ap.add_argument("--score-aircraft", type=int, default=None,
                    help="aircraft of each scoring fleet (default: --aircraft; the demo "
                         f"fleet has {demo_fleet.DemoSize().aircraft})")
    ap.add_argument("--flights", type=int, default=730)
    ap.add_argument("--calibrate-seeds", default=",".join(map(str, calibration.CALIBRATION_SEEDS)))
    ap.add_argument("--seeds", default=",".join(map(str, SCORING_SEEDS)))
    ap.add_argument("--rotations", type=int, default=0,
                    help="also score this many other draws of calibration fleets (slow)")
    ap.add_argument("--designs", default=",".join(DESIGNS))
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"))
    ap.add_argument("--json", type=Path, default=None, help="write the calibrations here")
    ap.add_argument("--pieces", type=Path, default=None,
                    help="pickle each design's trend pieces of every fleet here (calibration "
                         "fleets first), its observable parameters and their names, for "
                         "comparing slope fits offline")
    ap.add_argument("--actuators", action="store_true",
                    help="also measure how much of each level's error is the engines' actuator "
                         "biases (rigging), over the scoring fleets")
    args = ap.parse_args()

    sched = engine_schedule(args.cache)
    t0 = time.perf_counter()
    cal_seeds = [int(s) for s in args.calibrate_seeds.split(",")]
    test_seeds = [int(s) for s in args.seeds.split(",")]
    cal_fleets = [calibration.simulate_fleet(s, args.aircraft, args.flights) for s in cal_seeds]
    score_aircraft = args.score_aircraft or args.aircraft
    test_fleets = [calibration.simulate_fleet(s, score_aircraft, args.flights)
                   for s in test_seeds]
    print(f"fleets: {args.aircraft} aircraft ({score_aircraft} in each scoring fleet), "
          f"{args.flights} flights; calibration seeds "
          f"{cal_seeds}, scoring seeds {test_seeds}; simulated in "
          f"{time.perf_counter() - t0:.0f} s")
    print(TARGETS)
    stored = {}
    all_pieces: dict[str, tuple[list[uncertainty.TrendPieces], np.ndarray, tuple[str, ...],
                                int]] = {}
    for item in args.designs.split(","):
        method, m = item.split(":")
        biases = m.endswith("+bias")
        est = demo_fleet.design_estimator(sched, method, int(m.removesuffix("+bias")), biases)
        t1 = time.perf_counter()
        calib = calibration.calibrate(est, cal_fleets, design=item, seeds=cal_seeds)
        stored[item] = calib.to_dict()
        print(f"\n== {item} (m = {est.m}; calibrated in {time.perf_counter() - t1:.0f} s on "
              f"{calib.source['records']} records, {calib.source['segments']} segments)")
        print("model error s [%]: " + " ".join(
            f"{n}={v:.2f}" for n, v in zip(calib.names, calib.level_std, strict=True)))
        print("analytic bias [%]: " + " ".join(
            f"{n}={v:.2f}" for n, v in zip(calib.names, np.sqrt(calib.bias2), strict=True)))
        print("calibration slope error (pooled, before the gain): " + " ".join(
            f"{n}={v:.0%}" for n, v in zip(calib.names, calib.slope_error, strict=True)))
        print("slope error of a calibration fleet, cross-validated (RMS): " + " ".join(
            f"{n}={v:.0%}" for n, v in zip(calib.names, calib.source["slope_cross_error"],
                                           strict=True) if v is not None))
        print("slope gain (nan: slope unobservable): " + " ".join(
            f"{n}={v:.2f}" for n, v in zip(calib.names, np.asarray(calib.slope_gain),
                                           strict=True)))
        A = np.asarray(calib.slope_correction)
        print("slope correction A (diagonal; largest off-diagonal of each row): " + " ".join(
            f"{n}={A[k, k]:+.2f}/{np.delete(A[k], k)[np.argmax(np.abs(np.delete(A[k], k)))]:+.2f}"
            for k, n in enumerate(calib.names)) + f"; 1-sigma scale {calib.slope_scale[0]:.2f}")
        print("slope gain's relative standard error (jackknife): " + " ".join(
            f"{n}={v:.1%}" for n, v in zip(calib.names, calib.source["slope_gain_relative_std"],
                                           strict=True) if v is not None))
        print("level correction (calibrated level) on: "
              + (", ".join(calib.source["level_corrected"]) or "none"))
        print("aux outputs corrected on the health estimates (calibrated): "
              + (", ".join(calib.source.get("aux_corrected", [])) or "none"))
        print("shown: " + ", ".join(n for n, o in zip(calib.names, calib.observable,
                                                      strict=True) if o))
        tuners = tuple(est.layout.tuners)
        hidden = calib.tuner_hidden(tuners)
        print("tuners shown (calibrated: V* times the calibrated level): "
              + ", ".join(n + ("" if n in calib.tuners_corrected else " (as estimated)")
                          for n, x in zip(tuners, hidden, strict=True) if not x)
              + "; unobservable: "
              + (", ".join(n for n, x in zip(tuners, hidden, strict=True) if x) or "none"))
        slope_rows, covers, fleet_rows, figure_rows, fleet_aux_rows = [], [], [], [], []
        for seed, test_fleet in zip(test_seeds, test_fleets, strict=True):
            sc = health_uncertainty.score(est, calib, *test_fleet)
            covers.append((sc.cover1, sc.cover2, sc.change_cover1, sc.change_cover2))
            peer = np.sqrt(np.maximum(sc.slope_sigma**2 - np.square(
                np.asarray(calib.slope_scale) * sc.slope_hat
                * np.asarray(calib.slope_gain_std) / np.asarray(calib.slope_gain)), 0.0))
            slope_rows.append((sc.slope_hat - sc.slope_true, sc.slope_sigma, sc.slope_true,
                               peer))
            s = sc.summary()
            print(f"-- scored on seed {seed}: {sc.records} records, {sc.segments} segments, "
                  f"{sc.pieces} trend pieces")
            print(sc.report())
            print(f"shown {s['shown']} of {len(sc.names)}: 1-sigma coverage "
                  f"{s['cover1_min']:.2f}-{s['cover1_max']:.2f} (target 0.55-0.85), 2-sigma "
                  f"min {s['cover2_min']:.2f} (>= 0.85), level RMS {s['level_rms']:.2f} %, "
                  f"change RMS {s['change_rms']:.2f} % (all records; <= 0.5), "
                  f"{s['end_change_rms']:.2f} % (segment ends), worst slope error "
                  f"{s['slope_err_max']:.0%} over {s['slopes_shown']} observable slopes "
                  f"(<= 30 %)")
            assert sc.fleet_level_rms is not None and sc.fleet_raw_rms is not None
            assert sc.fleet_spread_ratio is not None
            fleet_rows.append((sc.fleet_level_rms, sc.fleet_raw_rms, sc.fleet_spread_ratio))
            if sc.fleet_aux_rms is not None:
                assert sc.fleet_aux_raw_rms is not None and sc.fleet_aux_spread_ratio is not None
                fleet_aux_rows.append((sc.fleet_aux_rms, sc.fleet_aux_raw_rms,
                                       sc.fleet_aux_spread_ratio))
            figure_rows.append(sc.figures)
            print(_common.load_line())
        print(per_fleet_band(calib, covers))
        print(fleet_average("level", "%", calib.names, np.asarray(calib.observable, bool),
                            fleet_rows))
        if fleet_aux_rows:
            aux = tuple(est.layout.aux)
            print(fleet_average("aux outputs", "% of nominal", aux, np.ones(len(aux), bool),
                                fleet_aux_rows))
        print(figure_band(figure_rows))
        print(f"fleet-average slopes over the {len(test_seeds)} scoring fleets (1-sigma with the "
              "gain's standard error; the peer: without it):")
        print(slope_coverage(calib.names, slope_rows))
        if args.actuators:
            print(health_uncertainty.actuator_share(est, test_fleets).report())
        if args.rotations or args.pieces:
            pieces = [calibration.trend_pieces(calibration.tracks(est, *f))
                      for f in cal_fleets + test_fleets]
            all_pieces[item] = (pieces, np.asarray(calib.observable), calib.names,
                                len(cal_fleets))
        if args.rotations:
            print(rotations(pieces, calib.observable, len(cal_fleets), args.rotations,
                            calib.names))
        print(_common.load_line())
    if args.json:
        args.json.write_text(json.dumps(stored, indent=1))
    if args.pieces:
        args.pieces.write_bytes(pickle.dumps(all_pieces))


if __name__ == "__main__":
    main()
