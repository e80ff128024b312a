"""The recording page's bands scored against the simulator's truth: the stream estimates of a
design of the built-in engine (as the product stores and filters them) with the figures the
page draws, calibrated (``streams.calibration``) and as the stream filter gives them.
bench/bench_stream_uncertainty.py and tests/app/services/streams/test_calibration_truth.py."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pytest

from app.models import EngineModel, EstimatorDesign
from app.services.demo import fleet as demo
from app.services.designs import service as designs
from app.services.snapshots import estimator
from app.services.streams import calibration
from app.services.streams.estimator import CALIBRATION_KEY, StreamEstimator, stream_estimator
from app.services.trends import health as health_view
from estimation import uncertainty
from estimation.engine.fleet import StreamFlight
from estimation.model import MODEL_FORMAT, LinearModel


def design_stream_estimator(method: str, m: int,
                            calib: uncertainty.Calibration | None = None) -> StreamEstimator:
    """A demo design of the built-in engine as the product stores it, ready for streams; with
    ``calib`` stored as its stream calibration (the filter then holds the calibration's gain
    per second at every rate, ``estimator.calibrated_interval``)."""
    p = demo.DESIGN_POINT
    model = estimator.builtin_schedule().model_at(p["alt"], p["mach"], p["power"])
    sensors = [n for n in model.sensor_names if n != "Wf"]
    spec = demo.design_spec(method, m, sensors)
    result = designs.design_step(model, spec)
    if calib is not None:
        result[CALIBRATION_KEY] = calib.to_dict()
    row = EngineModel(source="builtin", format=MODEL_FORMAT,
                      content=LinearModel.from_dict(result["model"]).to_dict())
    design = EstimatorDesign(id=0, status="ready", result=result, spec=spec)
    signals = [*model.sensor_names, "VSV", "VBV"]
    return stream_estimator(design, row, signals)


def score(est: StreamEstimator, calib: uncertainty.Calibration,
          windows: calibration.StreamWindows) -> dict[str, tuple[float, float, float, float]]:
    """Per figure: (1-sigma, 2-sigma coverage, RMS) calibrated, and the filter's own 1-sigma
    coverage as drawn before; unobservable figures left out."""
    layout = est.layout
    values = np.zeros((len(windows.h_hat), layout.width))
    sl = layout.slices()
    values[:, sl["h"]], values[:, sl["h_sigma"]] = windows.h_hat, windows.h_sigma
    values[:, sl["q"]], values[:, sl["q_sigma"]] = windows.q_hat, windows.q_sigma
    shown, _meta = health_view.apply(values, sl, tuple(layout.health), calib, "level",
                                    tuner_names=tuple(layout.tuners))
    out = {}
    for block, sigma_block, names, truth, raw, raw_sigma in (
            ("h", "h_sigma", layout.health, windows.h_true, windows.h_hat, windows.h_sigma),
            ("q", "q_sigma", layout.tuners, windows.q_true, windows.q_hat, windows.q_sigma)):
        err = shown[:, sl[block]] - truth
        sigma = shown[:, sl[sigma_block]]
        for k, name in enumerate(names):
            if np.isnan(err[:, k]).all():
                continue  # unobservable: not shown
            z = np.abs(err[:, k]) / sigma[:, k]
            before = np.abs(raw[:, k] - truth[:, k]) / raw_sigma[:, k]
            out[name] = (float(np.mean(z <= 1.0)), float(np.mean(z <= 2.0)),
                         float(np.sqrt(np.mean(err[:, k] ** 2))), float(np.mean(before <= 1.0)))
    return out


_SIMULATED: dict[tuple[object, ...], list[StreamFlight]] = {}


def simulate_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """The stream calibration's fleet (``streams.calibration.simulate``) simulated once per test
    process for each set of arguments: a calibration job run on both databases simulates its
    fleet once (the simulator is most of such a test's time). The flights are the simulator's
    own; only the second run of the same arguments reuses them."""
    real = calibration.simulate

    def simulate(seed: int, aircraft: int = calibration.AIRCRAFT,
                 rounds: Sequence[int] = calibration.ROUNDS,
                 rate_hz: float = calibration.RATE_HZ, duration_s: float | None = None,
                 progress: Callable[[float], None] | None = None) -> list[StreamFlight]:
        key = (seed, aircraft, tuple(rounds), rate_hz, duration_s)
        if key not in _SIMULATED:
            _SIMULATED[key] = real(seed, aircraft, rounds, rate_hz, duration_s, progress)
        elif progress is not None:
            progress(1.0)
        return list(_SIMULATED[key])

    monkeypatch.setattr(calibration, "simulate", simulate)
