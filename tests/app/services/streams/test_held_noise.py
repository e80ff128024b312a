"""A design calibrated for streams holds its sensor noise at the calibration's interval
(``estimator.calibrated_interval``): the recordings it estimated before, at another rate than
the calibration's, are estimated again from their first sample with that filter
(``store.estimate_held``, which the calibration job runs once it stored the calibration);
those at the calibration's rate keep their estimates, bit for bit."""

from __future__ import annotations

import functools
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import EstimatorDesign, StreamRecording
from app.models.stream_estimates import StreamEstimate, StreamFilterState
from app.services.demo import fleet as demo
from app.services.fleet import service as fleet_service
from app.services.streams import calibration, recordings, store
from app.services.streams.estimator import estimator_for
from app.services.tenancy import service as tenancy
from estimation.engine.fleet import StreamFlight
from tests.app.services.streams.simulated import stream_csv

pytestmark = pytest.mark.long(seconds=85)

SEED = 41
DURATION_S = 400.0  # idle, take-off and climb (at idle the tuners are not estimated)


# The calibration fleet: ``calibration.calibrate``'s simulation, of two aircraft.
CALIBRATION_SOURCE: dict[str, object] = {
    "seeds": [7], "aircraft": 2, "rounds": list(calibration.ROUNDS), "duration_s": DURATION_S}


@functools.cache
def _recorded() -> tuple[StreamFlight, ...]:
    """One aircraft's two engines' flights: position 1 recorded at 10 Hz, position 2 at 2 Hz
    (simulated once for both databases: the simulator is most of the test's time)."""
    fast = calibration.simulate(SEED, aircraft=1, rounds=(30, 250), rate_hz=10.0,
                                duration_s=DURATION_S)
    slow = calibration.simulate(SEED, aircraft=1, rounds=(30, 250), duration_s=DURATION_S)
    return tuple([f for f in fast if f.position == 1] + [f for f in slow if f.position == 2])


@functools.cache
def _calibration_flights() -> tuple[StreamFlight, ...]:
    """The calibration fleet's flights, as ``calibration.calibrate`` simulates them."""
    return tuple(calibration.simulate(7, 2, calibration.ROUNDS, calibration.RATE_HZ,
                                      DURATION_S))


def _packed(session: Session, recording_id: int) -> list[bytes]:
    return list(session.scalars(select(StreamEstimate.packed)
                                .where(StreamEstimate.recording_id == recording_id)
                                .order_by(StreamEstimate.window)).all())


def _state(session: Session, recording_id: int) -> StreamFilterState:
    row = session.scalar(select(StreamFilterState)
                         .where(StreamFilterState.recording_id == recording_id))
    assert row is not None
    return row


def test_recordings_at_another_rate_are_estimated_again_once_the_design_is_calibrated(
    session: Session, tmp_path: Path,
) -> None:
    op = tenancy.create_operator(session, name=f"Held Air {datetime.now(UTC).timestamp()}")
    type_id, design_id = demo._designs(session, op.id, lambda _m: None)  # the demo's, active
    design = session.get(EstimatorDesign, design_id)
    assert design is not None
    flights = _recorded()
    tail = fleet_service.create_aircraft(session, operator_id=op.id, tail=flights[0].tail)
    first = min(f.started_at for f in flights) - 86400.0
    for position in (1, 2):
        esn = next(f.esn for f in flights if f.position == position)
        engine = fleet_service.create_engine(session, operator_id=op.id, esn=esn,
                                             engine_type_id=type_id)
        fleet_service.install(session, operator_id=op.id, engine_id=engine.id,
                              aircraft_id=tail.id, position=position,
                              installed_at=datetime.fromtimestamp(first, UTC))
    rate: dict[int, float] = {}
    for flight in flights:
        _upload, recording, _ = recordings.upload_recording(
            session, operator_id=op.id, api_key_id=None, data_dir=tmp_path,
            body=stream_csv(flight), content_format="csv",
            meta={"tail": flight.tail, "position": flight.position,
                  "started_at": datetime.fromtimestamp(flight.started_at, UTC).isoformat(),
                  "flight_id": flight.flight_id})
        store.estimate_recording(session, operator_id=op.id, recording_id=recording.id,
                                 data_dir=tmp_path)
        rate[recording.id] = round(1.0 / float(recording.dt_s), 6)
    assert sorted(rate.values()) == [2.0, 2.0, 10.0, 10.0]
    before = {k: _packed(session, k) for k in rate}
    assert all(_state(session, k).state["noise_interval_s"] is None for k in rate)
    assert store.estimate_held(session, tmp_path, design) == []  # uncalibrated: nothing to do

    est = estimator_for(session, design, session.get(StreamRecording, next(iter(rate))).signals)
    calib = calibration.calibrate_on(est, _calibration_flights(), source=CALIBRATION_SOURCE)
    calibration.store_calibration(session, design, calib)
    again = store.estimate_held(session, tmp_path, design)
    assert sorted(again) == sorted(k for k, hz in rate.items() if hz == 10.0)
    for k, hz in rate.items():
        after = _packed(session, k)
        assert len(after) == len(before[k]) > 0
        state = _state(session, k).state
        assert state["noise_interval_s"] == (0.5 if hz == 10.0 else None)
        if hz == 10.0:
            assert after != before[k]  # filtered with R held at 0.5 s
        else:
            assert after == before[k]  # the same filter at 2 Hz: kept, bit for bit
    # The stored windows are the held filter's over the engine's first flight, from nominal.
    first_fast = min((k for k, hz in rate.items() if hz == 10.0),
                     key=lambda k: session.get(StreamRecording, k).started_at)
    recording = session.get(StreamRecording, first_fast)
    flight = next(f for f in flights if f.position == 1 and
                  datetime.fromtimestamp(f.started_at, UTC) == recording.started_at.replace(
                      tzinfo=UTC))
    held = estimator_for(session, design, recording.signals)
    assert held.noise_interval_s == 0.5
    expected, _end = calibration.flight_windows(held, flight)
    stored = held.layout.unpack(_packed(session, first_fast))
    sl = held.layout.slices()
    for block in ("q", "h"):  # stored in float32 from the CSV's text: to a thousandth of a %
        np.testing.assert_allclose(stored[:, sl[block]], expected[:, sl[block]], atol=1e-3)
    assert store.estimate_held(session, tmp_path, design) == []  # done once
