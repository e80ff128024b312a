"""Estimated health against the fleet simulator's truth, per engine and flight.

The fleet simulator (``estimation.engine.fleet``) fixes every engine's true health for every
round (``FleetPlan.health`` [F, E, 13], percent). This module runs the pipeline's own filter
(``pipeline.run_filters`` on ``detection_replay.engine_runs``, as after an upload) and lines up
each record's h_hat and its 1-sigma with the truth of the record's engine and round:

- per health parameter: bias (mean of h_hat - h) and RMS error over all records, and the
  mean of the filter's own 1-sigma (what the filter claims);
- the same at each engine's last record (end of the data);
- the fleet-average deterioration slope, estimated vs true: a least-squares line through
  (cycles flown, h) of every engine, per engine, averaged over the engines (percent per
  1000 cycles), with the records of the first ``settle`` flights after a start or a
  maintenance reset left out (the filter's start-up transient);
- the change error: per engine, the estimated change of h from its first settled record to its
  last minus the true change (an error constant per engine, e.g. from an actuator bias the
  filter does not model, cancels here: this is what a trend shows).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from app.services.designs.calibration import HealthTrack, tracks  # noqa: F401
from app.services.snapshots import estimator


@dataclass(frozen=True)
class Accuracy:
    """Per health parameter figures over a replay (arrays [p], percent)."""

    names: tuple[str, ...]
    bias: np.ndarray
    rms: np.ndarray
    sigma: np.ndarray  # mean 1-sigma the filter reports
    end_rms: np.ndarray  # RMS of h_hat - h at each engine's last record
    end_sigma: np.ndarray
    slope_hat: np.ndarray  # fleet-average slope, percent per 1000 cycles
    slope_true: np.ndarray
    change_rms: np.ndarray  # RMS over engines of (estimated - true) change, first to last
    records: int
    engines: int

    def report(self) -> str:
        head = (f"{'parameter':10s} {'bias':>7s} {'rms':>7s} {'1-sigma':>8s} {'end rms':>8s} "
                f"{'end 1s':>7s} {'slope est':>10s} {'slope true':>10s} {'change rms':>10s}")
        lines = [head]
        for k, name in enumerate(self.names):
            lines.append(
                f"{name:10s} {self.bias[k]:7.2f} {self.rms[k]:7.2f} {self.sigma[k]:8.2f} "
                f"{self.end_rms[k]:8.2f} {self.end_sigma[k]:7.2f} {self.slope_hat[k]:10.2f} "
                f"{self.slope_true[k]:10.2f} {self.change_rms[k]:10.2f}"
            )
        lines.append(
            f"{'all':10s} {np.sqrt(np.mean(self.bias**2)):7.2f} "
            f"{np.sqrt(np.mean(self.rms**2)):7.2f} {np.sqrt(np.mean(self.sigma**2)):8.2f} "
            f"{np.sqrt(np.mean(self.end_rms**2)):8.2f} {np.sqrt(np.mean(self.end_sigma**2)):7.2f}"
            f" (root mean square over parameters; slopes in % per 1000 cycles; "
            f"{self.records} records, {self.engines} engines)"
        )
        return "\n".join(lines)


def _slope(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares slope of each column of y [S, p] on x [S]."""
    xc = x - x.mean()
    return (xc @ (y - y.mean(axis=0))) / (xc @ xc)


def accuracy(est: estimator.SnapshotEstimator, track_list: Sequence[HealthTrack],
             min_records: int = 20) -> Accuracy:
    """Bias, RMS error, end-of-data error and slopes over settled records (see the module)."""
    err = np.concatenate([t.h_hat[t.settled] - t.h_true[t.settled] for t in track_list])
    sig = np.concatenate([t.h_sigma[t.settled] for t in track_list])
    ends = [t for t in track_list if t.settled[-1]]
    end_err = np.array([t.h_hat[-1] - t.h_true[-1] for t in ends])
    end_sig = np.array([t.h_sigma[-1] for t in ends])
    slopes_hat, slopes_true, changes = [], [], []
    for t in track_list:
        # The longest stretch without a reset: the plan's truth there is deterioration only
        # (plus fouling, washes and faults, which the truth carries as well).
        k = t.settled
        if k.sum() < min_records or np.ptp(t.round[k]) < 10:
            continue
        x = t.round[k].astype(float) / 1000.0  # one cycle per round the engine flew
        slopes_hat.append(_slope(x, t.h_hat[k]))
        slopes_true.append(_slope(x, t.h_true[k]))
        first, last = np.flatnonzero(k)[[0, -1]]
        changes.append((t.h_hat[last] - t.h_hat[first]) - (t.h_true[last] - t.h_true[first]))
    p = len(est.layout.health)
    return Accuracy(
        names=tuple(est.layout.health),
        bias=err.mean(axis=0), rms=np.sqrt(np.mean(err**2, axis=0)),
        sigma=sig.mean(axis=0),
        end_rms=np.sqrt(np.mean(end_err**2, axis=0)) if len(ends) else np.full(p, np.nan),
        end_sigma=end_sig.mean(axis=0) if len(ends) else np.full(p, np.nan),
        slope_hat=np.mean(slopes_hat, axis=0) if slopes_hat else np.full(p, np.nan),
        slope_true=np.mean(slopes_true, axis=0) if slopes_true else np.full(p, np.nan),
        change_rms=np.sqrt(np.mean(np.square(changes), axis=0)) if changes
        else np.full(p, np.nan),
        records=int(err.shape[0]), engines=len(track_list),
    )
