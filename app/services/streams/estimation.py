"""Stream estimation, as the jobs and routers import it: the service is
app/services/streams/store.py, the estimator estimator.py, the filter run run.py and the
numerics estimation/stream_filter.py."""

from app.services.streams.estimator import (
    _ESTIMATORS,
    StreamEstimationError,
    StreamEstimator,
    _stored_affine,
    estimator_for,
)
from app.services.streams.run import Carry, deviations, filter_piece
from app.services.streams.store import (
    PIECE,
    WINDOW_S,
    StreamSeries,
    estimate_one,
    estimate_recording,
    read_estimates,
)
from estimation.stream_filter import SegmentGain, resample

__all__ = [
    "PIECE", "WINDOW_S", "_ESTIMATORS", "Carry", "SegmentGain", "StreamEstimationError",
    "StreamEstimator", "StreamSeries", "_stored_affine", "deviations", "estimate_one",
    "estimate_recording", "estimator_for", "filter_piece", "read_estimates", "resample",
]
