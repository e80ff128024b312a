"""The stream calibration filters its simulated flights as the product filters recordings: an
engine's flights in time order, each from where the engine's previous one ended (the tuners
carried, the engine states at zero deviation), the first from nominal."""

from __future__ import annotations

import numpy as np
import pytest

from app.services.streams import calibration
from app.services.streams.run import recording_start
from tests.support.stream_uncertainty import design_stream_estimator

pytestmark = pytest.mark.long(seconds=30)


def test_recording_start_carries_the_tuners_alone() -> None:
    end = np.arange(1.0, 8.0)
    start = recording_start(7, 3, 2, end)
    np.testing.assert_array_equal(start.x, [0.0, 0.0, 0.0, 4.0, 5.0, 6.0, 7.0])
    np.testing.assert_array_equal(start.u_prev, np.zeros(2))
    assert start.anchor is None and start.switches == 0 and start.plant is None
    # No previous recording, or one of another design's size: nominal.
    np.testing.assert_array_equal(recording_start(7, 3, 2).x, np.zeros(7))
    np.testing.assert_array_equal(recording_start(7, 3, 2, end[:5]).x, np.zeros(7))


def test_each_engines_flights_start_where_its_previous_one_ended() -> None:
    est = design_stream_estimator("subset", 10)
    flights = calibration.simulate(11, aircraft=1, rounds=(30, 250), duration_s=300.0)
    engines = {f.esn for f in flights}
    assert len(engines) == 2 and len(flights) == 4
    # Given newest first: the order of the result is the order given, the filtering by time.
    given = sorted(flights, key=lambda f: -f.started_at)
    carried = calibration.recorded_windows(est, given)
    nominal = calibration.recorded_windows(est, given, carried=False)
    for esn in engines:
        first, second = sorted((k for k, f in enumerate(given) if f.esn == esn),
                               key=lambda k: given[k].started_at)
        alone, end = calibration.flight_windows(est, given[first])
        np.testing.assert_array_equal(carried[first], alone)
        np.testing.assert_array_equal(nominal[first], alone)
        start = recording_start(est.n, est.nx, end.u_prev.shape[0], end.x)
        np.testing.assert_array_equal(carried[second], calibration.flight_windows(
            est, given[second], start)[0])
        np.testing.assert_array_equal(nominal[second],
                                      calibration.flight_windows(est, given[second])[0])
        assert not np.allclose(carried[second], nominal[second], equal_nan=True)


def test_a_calibration_is_of_one_sample_rate() -> None:
    """The calibration names its flights' rate (the rate a calibrated design's R holds at on
    every recording): flights of two rates are refused before anything is filtered."""
    est = design_stream_estimator("subset", 10)
    slow = calibration.simulate(11, aircraft=1, rounds=(30,), duration_s=60.0)
    fast = calibration.simulate(11, aircraft=1, rounds=(30,), rate_hz=10.0, duration_s=60.0)
    with pytest.raises(ValueError, match=r"one sample rate, not \[2.0, 10.0\] Hz"):
        calibration.calibrate_on(est, [*slow, *fast])
