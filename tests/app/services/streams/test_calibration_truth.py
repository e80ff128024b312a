"""The recording page's bands against the simulator's truth (reduced, seeded).

The demo's active design is calibrated for streams (``streams.calibration.calibrate``) on one
simulated fleet's recorded flights (half the product's fleet, the first 500 s: idle, take-off
and climb, at 2 Hz)
and scored on another fleet's: the stream filter's own 1-sigma holds the true health in a few
percent of the windows; the calibrated band of every shown parameter and tuner holds it at
2-sigma, and at 1-sigma in the issue's band for the median figure (the unobservable ones not
scored: the page does not draw them). bench/bench_stream_uncertainty.py
scores whole flights fleet by fleet.

The scoring fleet is recorded at 10 Hz, and read at 2 Hz as every fifth sample (what a 2 Hz
recorder of the same flights reads). Its 10 Hz recordings, filtered as the product filters a
calibrated design's recordings (R held at the calibration's 0.5 s,
``estimator.calibrated_interval``), are held by the same bands and err no more than at 2 Hz.
With R per sample at 10 Hz they erred up to 1.9 times as much (hpc_flow RMS 2.76 % against
1.49 %) and left the band (2-sigma 0.76).
"""

from __future__ import annotations

import numpy as np
import pytest

from app.services.streams import calibration
from estimation import uncertainty
from estimation.engine.fleet import StreamFlight
from tests.support.stream_uncertainty import design_stream_estimator, score

pytestmark = pytest.mark.long(seconds=130)

DURATION_S = 500.0
AIRCRAFT = 32  # half the product's calibration fleet, over the first 500 s of each flight


def test_calibrated_stream_bands_hold_the_truth_where_the_filters_did_not() -> None:
    est = design_stream_estimator("subset", 10)
    calib = calibration.calibrate(est, seed=31, aircraft=AIRCRAFT, duration_s=DURATION_S)
    assert calib.source["flights"] == AIRCRAFT * 2 * len(calibration.ROUNDS)
    assert est.noise_interval_s is None  # uncalibrated: R per sample
    product = design_stream_estimator("subset", 10, calib)
    assert product.noise_interval_s == 1.0 / calibration.RATE_HZ
    rms: dict[float, dict[str, float]] = {}
    # The scoring fleet recorded at 10 Hz, and the same recordings at 2 Hz (every fifth
    # sample: what a 2 Hz recorder of the same flights reads).
    fast = calibration.simulate(32, aircraft=12, duration_s=DURATION_S, rate_hz=10.0)
    every = round(10.0 / calibration.RATE_HZ)
    for rate_hz, flights in ((calibration.RATE_HZ, [_every(f, every) for f in fast]),
                             (10.0, fast)):
        figures = score(product, calib, calibration.fleet_windows(product, flights))
        report = f"{rate_hz:g} Hz: " + "; ".join(
            f"{n} {a:.2f}/{b:.2f} rms {r:.2f} (filter's {f:.2f})"
            for n, (a, b, r, f) in figures.items())
        print(report)
        _assert_held(calib, figures, report)
        rms[rate_hz] = {n: r for n, (_a, _b, r, _f) in figures.items()}
    slow = rms[calibration.RATE_HZ]
    assert all(r <= 1.1 * slow[n] for n, r in rms[10.0].items()), rms


def _every(flight: StreamFlight, n: int) -> StreamFlight:
    """Every n-th sample of a recording, from the first."""
    return flight._replace(**{k: getattr(flight, k)[::n] for k in (
        "time_s", "alt_ft", "mach", "dtamb_k", "power_pct", "actuators", "sensors")})


def _assert_held(calib: uncertainty.Calibration,
                 figures: dict[str, tuple[float, float, float, float]], report: str) -> None:
    shown = [n for n, o in zip(calib.names, calib.observable, strict=True) if o]
    assert shown and set(shown) == {n for n in figures if n in calib.names}, report
    # The filter's own band holds sensor noise alone; the calibrated one the truth, each shown
    # figure's at 2-sigma, and at 1-sigma in the band for the median figure (each
    # figure's 1-sigma on twelve aircraft is a draw over their engines: >= 0.5 here).
    assert np.median([before for *_, before in figures.values()]) < 0.15, report
    for _name, (one, two, _rms, _before) in figures.items():
        assert one >= 0.5 and two >= 0.85, report
    assert 0.55 <= np.median([one for one, *_ in figures.values()]) <= 0.85, report
