"""Honest health uncertainty: calibrate the model-error term on the fleet simulator, score it.

``calibrate`` runs the product's own filter (``health_accuracy.tracks``: ``pipeline.run_filters``
on ``detection_replay.engine_runs``, as after an upload) on a simulated nonlinear fleet with
known health and fits the model-error term of ``estimation.uncertainty`` for the design; the
returned ``Calibration`` is stored with the design result (``to_dict``). ``score`` measures, on
a fleet simulated with another seed, what the issue asks for: coverage of the honest 1-sigma
and 2-sigma of the level, level RMS, change RMS since the baseline and fleet-average slopes.

Baseline of a change: the first settled record (``health_accuracy.tracks``: past the filter's
start-up transient) after the engine's first record or its last shop visit (a re-installation);
a water wash does not move the baseline (its recovery is part of the trend).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from app.services.snapshots.estimator import MODEL_ERROR, SnapshotEstimator
from estimation import uncertainty
from estimation.engine.fleet import FleetPlan, Snapshots
from tests.support import health_accuracy

# The demo designs' fleet prior: P_h = 4 I (percent^2, design_spec "Ph").
PRIOR_VAR = 4.0
# Slopes are compared relative to max(|true slope|, SLOPE_FLOOR) (percent per 1000 cycles).
SLOPE_FLOOR = 0.1
MIN_SEGMENT_RECORDS = 20
# A slope needs a stretch of at least this many thousand cycles (each segment weighs the same
# in the fleet average, and a short one's slope is mostly filter noise).
MIN_SLOPE_SPAN = 0.2
# Observability rule (uncertainty.observable): honest sigma at most this fraction of the prior
# sigma, and the calibration fleet's slope within this relative error of the truth.
REDUCTION = 0.6
SLOPE_TOLERANCE = 0.3


@dataclass(frozen=True)
class Segment:
    """One engine's settled records between shop visits, from its baseline on ([S, p])."""

    kcycles: np.ndarray  # [S] thousand cycles since the baseline record
    h_hat: np.ndarray
    h_sigma: np.ndarray  # the filter's 1-sigma
    h_true: np.ndarray


def segments(plan: FleetPlan, tracks: Sequence[health_accuracy.HealthTrack]) -> list[Segment]:
    """Split each track at the engine's shop visits and abrupt faults (a fault is a step the
    shift detector reports, not deterioration); keep each piece's settled records."""
    cfg = plan.config
    round_s = 86400.0 / cfg.flights_per_day
    shop: dict[str, list[int]] = {}
    seen: set[str] = set()
    for inst in sorted(plan.installations, key=lambda i: i.installed_at):
        if inst.esn in seen:
            shop.setdefault(inst.esn, []).append(
                int(np.floor((inst.installed_at - cfg.start_epoch_s) / round_s + 1e-6)))
        seen.add(inst.esn)
    for fault in plan.faults:  # an abrupt fault starts a new trend (the shift detector's)
        shop.setdefault(fault.esn, []).append(
            int(np.floor((fault.occurred_at - cfg.start_epoch_s) / round_s + 1e-6)) + 1)
    out = []
    for t in tracks:
        piece = np.searchsorted(np.array(sorted(shop.get(t.esn, [])), dtype=float),
                                t.round, side="right")
        for k in np.unique(piece):
            sel = (piece == k) & t.settled
            if sel.sum() < MIN_SEGMENT_RECORDS:
                continue
            r = t.round[sel].astype(float)
            out.append(Segment((r - r[0]) / 1000.0, t.h_hat[sel], t.h_sigma[sel],
                               t.h_true[sel]))
    return out


def bias_matrix(est: SnapshotEstimator, plan: FleetPlan, snaps: Snapshots,
                records: int = 256, phases: Sequence[str] = ("takeoff", "cruise"),
                seed: int = 0) -> np.ndarray:
    """B_h [p, p] of the design's snapshot filter over the fleet's own operating conditions
    (``records`` drawn from the snapshots of ``phases``)."""
    keep = np.flatnonzero(np.isin(snaps.phase.astype(str), list(phases)))
    pick = np.random.default_rng(seed).choice(keep, size=min(records, keep.size), replace=False)
    cond = np.stack([snaps.alt_ft[pick], snaps.mach[pick], snaps.dtamb_k[pick],
                     snaps.power_pct[pick]], axis=1)
    g = est.schedule(cond)
    noise = (np.broadcast_to(est.noise_std, g.G_y.shape[:2]) if g.noise_std is None
             else np.sqrt(g.noise_std**2 + MODEL_ERROR**2))
    return uncertainty.snapshot_bias_matrix(np.asarray(g.G_y), noise, est.Vp)


def _stack(segs: Sequence[Segment], drift: np.ndarray) -> dict[str, np.ndarray]:
    level_err = np.concatenate([s.h_hat - s.h_true for s in segs])
    filt_var = np.concatenate([s.h_sigma**2 for s in segs])
    d_err = np.concatenate([(s.h_hat - s.h_hat[0]) - (s.h_true - s.h_true[0]) for s in segs])
    d_var = np.concatenate([s.h_sigma**2 + s.h_sigma[0] ** 2
                            + np.square(drift * s.kcycles[:, None]) for s in segs])
    return {"level_err": level_err, "filter_var": filt_var, "change_err": d_err,
            "change_var": d_var}


def _slopes(segs: Sequence[Segment]) -> tuple[np.ndarray, np.ndarray]:
    long = [s for s in segs if np.ptp(s.kcycles) >= MIN_SLOPE_SPAN]
    x = [s.kcycles for s in long]
    return (uncertainty.fleet_slopes(x, [s.h_hat for s in long]),
            uncertainty.fleet_slopes(x, [s.h_true for s in long]))


def fleet_prior(segs: Sequence[Segment]) -> np.ndarray:
    """The fleet prior P_h [p, p] of a simulated fleet: the second moment E[h h^T] of the true
    health over its settled records (the mean deterioration is a bias of a design as much as
    the spread around it)."""
    h = np.concatenate([s.h_true for s in segs])
    return (h.T @ h) / h.shape[0]


def calibrate(
    est: SnapshotEstimator, plan: FleetPlan, snaps: Snapshots, design: str = "",
    prior_var: float = PRIOR_VAR, seed: int | None = None,
    reduction: float = REDUCTION, slope_tolerance: float = SLOPE_TOLERANCE,
) -> uncertainty.Calibration:
    """Fit the model-error term of ``est`` on one simulated fleet (module docstring).

    The analytic bias^2 is taken under the simulated fleet's own prior (``fleet_prior``); a
    parameter is shown when its honest steady-state sigma is at most ``reduction`` times the
    design's prior sigma sqrt(prior_var) and its fleet-average slope on this fleet is within
    ``slope_tolerance`` of the truth (``uncertainty.observable``).
    """
    tr = health_accuracy.tracks(est, plan, snaps)
    segs = segments(plan, tr)
    B_h = bias_matrix(est, plan, snaps)
    p = B_h.shape[0]
    bias2 = uncertainty.analytic_bias2(B_h, fleet_prior(segs))
    slope_hat, slope_true = _slopes(segs)
    drift = uncertainty.drift_bias(B_h, slope_true)
    st = _stack(segs, drift)
    scale = uncertainty.fit_bias_scale(st["level_err"], bias2, st["filter_var"])
    level_std = uncertainty.fit_model_std(st["level_err"], scale**2 * bias2 + st["filter_var"])
    change_std = uncertainty.fit_model_std(st["change_err"], st["change_var"])
    slope_error = (slope_hat - slope_true) / np.maximum(np.abs(slope_true), SLOPE_FLOOR)
    shown = uncertainty.observable(
        np.full(p, prior_var), scale**2 * bias2, np.median(st["filter_var"], axis=0), level_std,
        slope_error=slope_error, reduction=reduction, slope_tolerance=slope_tolerance)
    return uncertainty.Calibration(
        names=tuple(est.layout.health), level_std=level_std, change_std=change_std,
        slope_error=slope_error, bias2=bias2, drift=drift, observable=shown, bias_scale=scale,
        source={"design": design, "seed": seed, "engines": len(plan.esns),
                "flights": plan.config.n_flights, "records": int(st["level_err"].shape[0]),
                "prior_var": prior_var, "reduction": reduction,
                "slope_tolerance": slope_tolerance},
    )


@dataclass(frozen=True)
class Score:
    """Figures against the truth per health parameter [p] (percent; slopes per 1000 cycles)."""

    names: tuple[str, ...]
    observable: np.ndarray
    cover1: np.ndarray  # honest level sigma
    cover2: np.ndarray
    filter_cover1: np.ndarray  # the filter's own sigma, for comparison
    level_rms: np.ndarray
    sigma: np.ndarray  # mean honest sigma
    change_cover1: np.ndarray
    change_cover2: np.ndarray
    change_rms: np.ndarray  # all settled records against their baseline
    end_change_rms: np.ndarray  # last record of each segment against its baseline
    slope_hat: np.ndarray
    slope_true: np.ndarray
    records: int
    segments: int

    def report(self) -> str:
        lines = [f"{'parameter':10s} {'shown':>5s} {'1s cov':>6s} {'2s cov':>6s} "
                 f"{'filt 1s':>7s} {'rms':>6s} {'sigma':>6s} {'d 1s':>6s} {'d 2s':>6s} "
                 f"{'d rms':>6s} {'d end':>6s} {'slope':>7s} {'true':>7s} {'err':>6s}"]
        for k, n in enumerate(self.names):
            err = (self.slope_hat[k] - self.slope_true[k]) / max(abs(self.slope_true[k]),
                                                                  SLOPE_FLOOR)
            lines.append(
                f"{n:10s} {'yes' if self.observable[k] else 'no':>5s} {self.cover1[k]:6.2f} "
                f"{self.cover2[k]:6.2f} {self.filter_cover1[k]:7.2f} {self.level_rms[k]:6.2f} "
                f"{self.sigma[k]:6.2f} {self.change_cover1[k]:6.2f} "
                f"{self.change_cover2[k]:6.2f} {self.change_rms[k]:6.2f} "
                f"{self.end_change_rms[k]:6.2f} {self.slope_hat[k]:7.2f} "
                f"{self.slope_true[k]:7.2f} {err:6.0%}")
        return "\n".join(lines)

    def summary(self) -> dict[str, float]:
        """Figures over the shown parameters next to which the targets are stated."""
        o = self.observable
        rel = np.abs(self.slope_hat - self.slope_true) / np.maximum(np.abs(self.slope_true),
                                                                   SLOPE_FLOOR)
        nan = float("nan")
        return {
            "shown": int(o.sum()),
            "cover1_min": float(self.cover1[o].min()) if o.any() else nan,
            "cover1_max": float(self.cover1[o].max()) if o.any() else nan,
            "cover2_min": float(self.cover2[o].min()) if o.any() else nan,
            "level_rms": float(np.sqrt(np.mean(self.level_rms[o] ** 2))) if o.any() else nan,
            "change_rms": float(np.sqrt(np.mean(self.change_rms[o] ** 2))) if o.any() else nan,
            "end_change_rms": float(np.sqrt(np.mean(self.end_change_rms[o] ** 2)))
            if o.any() else nan,
            "slope_err_max": float(rel[o].max()) if o.any() else nan,
        }


def score(
    est: SnapshotEstimator, calib: uncertainty.Calibration, plan: FleetPlan, snaps: Snapshots,
) -> Score:
    """Coverage, level and change RMS and slopes of ``est`` with ``calib`` on a fleet."""
    tr = health_accuracy.tracks(est, plan, snaps)
    segs = segments(plan, tr)
    st = _stack(segs, calib.drift)
    sigma = np.sqrt(np.asarray(calib.bias_scale) ** 2 * calib.bias2 + st["filter_var"]
                    + calib.level_std**2)
    d_sigma = np.sqrt(st["change_var"] + calib.change_std**2)
    slope_hat, slope_true = _slopes(segs)
    ends = np.array([(s.h_hat[-1] - s.h_hat[0]) - (s.h_true[-1] - s.h_true[0]) for s in segs])
    cov = uncertainty.coverage
    return Score(
        names=calib.names, observable=calib.observable,
        cover1=cov(st["level_err"], sigma, 1.0), cover2=cov(st["level_err"], sigma, 2.0),
        filter_cover1=cov(st["level_err"], np.sqrt(st["filter_var"]), 1.0),
        level_rms=np.sqrt(np.mean(st["level_err"] ** 2, axis=0)), sigma=sigma.mean(axis=0),
        change_cover1=cov(st["change_err"], d_sigma, 1.0),
        change_cover2=cov(st["change_err"], d_sigma, 2.0),
        change_rms=np.sqrt(np.mean(st["change_err"] ** 2, axis=0)),
        end_change_rms=np.sqrt(np.mean(ends**2, axis=0)),
        slope_hat=slope_hat, slope_true=slope_true,
        records=int(st["level_err"].shape[0]), segments=len(segs),
    )
