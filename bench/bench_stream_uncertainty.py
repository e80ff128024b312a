"""The recording page's bands against the truth: the stream filter's tuners and health.

The demo's active design (and others by ``--designs``) is calibrated for streams
(``streams.calibration.calibrate``: the product's stream filter over whole flights of the
built-in engine's closed-loop transient simulator, the stored one-second windows) on the
product's calibration fleets, then scored on other fleets' flights: per fleet and parameter,
the share of estimated windows whose truth lies within +-1 and +-2 sigma, for the band the
page drew before (the filter's own 1-sigma on the estimate as filtered) and for the calibrated
one (the calibrated level, its sigma, unobservable parameters not shown); RMS error of both;
the tuners against V* h the same way. Every engine's flights are filtered as the product filters
an engine's recordings, each from where the previous one ended (``recorded_windows``); the peer
is the calibration as it was before it did so (every calibration flight from nominal, fitted on
the same simulated flights), scored on the same windows. ``--score-rate-hz 10`` scores fleets
recorded at another rate than the calibration's 2 Hz, filtered as the product filters a
calibrated design's recordings (``estimator.calibrated_interval``); the peer is then the filter
before it did so (R per sample at every rate), with the same calibration. Target: 1-sigma
55-85 % and 2-sigma >= 85 % on every fleet for every shown figure.

Run: .venv/bin/python bench/bench_stream_uncertainty.py [--designs subset:10] [--seeds 4]
     [--score-rate-hz 10]
"""

from __future__ import annotations

import argparse
import time

import _common  # noqa: F401  (pins BLAS threads)
import numpy as np

from app.services.streams import calibration
from tests.support.stream_uncertainty import design_stream_estimator, score

SCORE_SEEDS = (20260501, 20260502, 20260503, 20260504, 20260505, 20260506)
# A scoring fleet: the demo's twelve aircraft, their engines' flights in the calibration's rounds.
SCORE_AIRCRAFT = 12


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--designs", default="subset:10")
    ap.add_argument("--calibrate-aircraft", type=int, default=calibration.AIRCRAFT)
    ap.add_argument("--seeds", type=int, default=len(SCORE_SEEDS))
    ap.add_argument("--score-aircraft", type=int, default=SCORE_AIRCRAFT)
    ap.add_argument("--score-rate-hz", type=float, default=calibration.RATE_HZ)
    args = ap.parse_args()
    print(_common.load_line())
    for spec in args.designs.split(","):
        method, m = spec.split(":")
        est = design_stream_estimator(method, int(m))
        started = time.monotonic()
        flights = calibration.simulate(calibration.SEED, aircraft=args.calibrate_aircraft)
        calib = calibration.calibrate_on(est, flights, design=spec)
        other_rate = args.score_rate_hz != calibration.RATE_HZ
        if other_rate:
            # the product's estimator of the calibrated design, against the filter before it
            # held the calibration's gain per second (R per sample at every rate)
            peer_est, est = est, design_stream_estimator(method, int(m), calib)
            before = calib
            peer_title = f"R per sample at {args.score_rate_hz:g} Hz (the filter before)"
        else:
            peer_est = est
            before = calibration.calibrate_on(est, flights, design=spec, carried=False)
            peer_title = "the calibration before (every flight from nominal)"
        print(f"== {spec}: calibrated (and as before) in {time.monotonic() - started:.0f} s on "
              f"{calib.source['windows']} windows of {calib.source['flights']} flights "
              f"({args.calibrate_aircraft} aircraft in {calib.source['groups']} groups, rounds "
              f"{list(calibration.ROUNDS)}, {calibration.RATE_HZ:g} Hz)")
        print("shown: " + ", ".join(n for n, o in zip(calib.names, calib.observable,
                                                      strict=True) if o))
        hidden = calib.tuner_hidden(calib.tuner_names)
        print("tuners shown: " + ", ".join(n for n, x in zip(calib.tuner_names, hidden,
                                                             strict=True) if not x))
        print(f"shown by {peer_title}: " + ", ".join(
            n for n, o in zip(before.names, before.observable, strict=True) if o))
        rows, peers = [], []
        for seed in SCORE_SEEDS[:args.seeds]:
            fleet = calibration.simulate(seed, aircraft=args.score_aircraft,
                                         rate_hz=args.score_rate_hz)
            windows = calibration.fleet_windows(est, fleet)
            rows.append(score(est, calib, windows))
            peer_windows = calibration.fleet_windows(peer_est, fleet) if other_rate else windows
            peers.append(score(peer_est, before, peer_windows))
            print(f"-- seed {seed} at {args.score_rate_hz:g} Hz: {len(windows.h_hat)} windows; "
                  + "; ".join(f"{n} {a:.2f}/{b:.2f} rms {r:.2f} (filter's own {f:.2f})"
                              for n, (a, b, r, f) in rows[-1].items()))
            print(f"   {peer_title}: " + "; ".join(
                f"{n} {a:.2f}/{b:.2f} rms {r:.2f}" for n, (a, b, r, _f) in peers[-1].items()))
            print(_common.load_line())
        for title, figures in (("calibrated", rows), (peer_title, peers)):
            n = len(figures)
            every = np.ones(n, bool)
            print(f"{title}: per figure over {n} scoring fleets (1-sigma 55-85 %, "
                  "2-sigma >= 85 %):")
            for name in figures[0]:
                c1 = np.array([r[name][0] for r in figures])
                c2 = np.array([r[name][1] for r in figures])
                rms = np.array([r[name][2] for r in figures])
                own = np.array([r[name][3] for r in figures])
                ok = (c1 >= 0.55) & (c1 <= 0.85) & (c2 >= 0.85)
                every &= ok
                print(f"  {name:10s} in band on {int(ok.sum())}/{n} (1-sigma {c1.min():.2f}-"
                      f"{c1.max():.2f}, 2-sigma min {c2.min():.2f}, RMS {rms.min():.2f}-"
                      f"{rms.max():.2f} %); the filter's own sigma {own.min():.2f}-"
                      f"{own.max():.2f}")
            print(f"  fleets with every shown figure in the band: {int(every.sum())}/{n}")


if __name__ == "__main__":
    main()
