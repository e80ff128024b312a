"""Honest health uncertainty: score the calibrated model-error term against the simulator.

The calibration is the product's (``app.services.designs.calibration``: the product's own
filter on simulated nonlinear fleets with known health; ``calibrate`` here is its one-fleet
form), stored with the design result (``Calibration.to_dict``). ``score`` measures, on
a fleet simulated with another seed, what the issue asks for: coverage of the honest 1-sigma
and 2-sigma of the level, level RMS, change RMS since the baseline and fleet-average slopes.

Baseline of a change: the first settled record (``calibration.tracks``: past the filter's
start-up transient) after the engine's first record or its last shop visit (a re-installation);
a water wash does not move the baseline (its recovery is part of the trend).

Fleet-average slopes (percent per year) are the product's (``app.services.fleet.slopes``):
weekly means of every engine's estimates, split at its baseline resets, corrected by the
calibrated slope correction, combined by inverse variance and divided by the calibrated gain;
a parameter whose slope the calibration finds unobservable is reported as such
(``slope_shown``), not scored.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.services.designs import calibration
from app.services.snapshots import buckets
from app.services.snapshots.estimator import SnapshotEstimator
from estimation import uncertainty
from estimation.engine.fleet import FleetPlan, Snapshots
from estimation.engine.health import ACTUATOR_BIASES, HEALTH_NAMES
from tests.support import health_accuracy

PRIOR_VAR = calibration.PRIOR_VAR
SLOPE_FLOOR = calibration.YEAR_SLOPE_FLOOR
Segment = calibration.Segment
segments = calibration.segments
fleet_prior = calibration.fleet_prior
_stack = calibration.stack


def calibrate(
    est: SnapshotEstimator, plan: FleetPlan, snaps: Snapshots, design: str = "",
    seed: int | None = None,
) -> uncertainty.Calibration:
    """``calibration.calibrate`` on one fleet (the product's procedure; several fleets: call it
    with a list)."""
    return calibration.calibrate(est, [(plan, snaps)], design=design,
                                 seeds=None if seed is None else [seed])


@dataclass(frozen=True)
class Score:
    """Figures against the truth per health parameter [p] (percent; slopes per year)."""

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
    slope_hat: np.ndarray  # the product's fleet-average slope (NaN where not shown)
    slope_sigma: np.ndarray  # its 1-sigma
    slope_true: np.ndarray
    slope_shown: np.ndarray  # bool: the slope is observable (else shown as unobservable)
    records: int
    segments: int
    pieces: int  # engine trends the slopes are taken over
    # The fleet page's monthly fleet-average level (``fleet_level`` of the engines' monthly
    # means) against the engines' true monthly means averaged over the fleet: RMS over months
    # of the calibrated figure, of the estimates' plain mean (the page before), and the spread
    # over engines shown against the true one (RMS ratio).
    fleet_level_rms: np.ndarray | None = None
    fleet_raw_rms: np.ndarray | None = None
    fleet_spread_ratio: np.ndarray | None = None
    # The same for the fleet page's monthly aux outputs (``fleet_aux_errors``) [n_aux]; None
    # without aux outputs.
    fleet_aux_rms: np.ndarray | None = None
    fleet_aux_raw_rms: np.ndarray | None = None
    fleet_aux_spread_ratio: np.ndarray | None = None
    # The engine page's other figures (``figures``): name -> (1-sigma, 2-sigma coverage of the
    # band shown, 1-sigma coverage of the filter's own sigma or NaN).
    figures: dict[str, tuple[float, float, float]] = field(default_factory=dict)

    @property
    def slope_error(self) -> np.ndarray:
        """(slope - true) / max(|true|, SLOPE_FLOOR) [p]; NaN where the slope is not shown."""
        return (self.slope_hat - self.slope_true) / np.maximum(np.abs(self.slope_true),
                                                               SLOPE_FLOOR)

    def report(self) -> str:
        lines = [f"{'parameter':10s} {'shown':>5s} {'1s cov':>6s} {'2s cov':>6s} "
                 f"{'filt 1s':>7s} {'rms':>6s} {'sigma':>6s} {'d 1s':>6s} {'d 2s':>6s} "
                 f"{'d rms':>6s} {'d end':>6s} {'slope/yr':>14s} {'true':>6s} {'err':>6s}"]
        for k, n in enumerate(self.names):
            if self.slope_shown[k]:
                slope = f"{self.slope_hat[k]:6.2f}+-{self.slope_sigma[k]:.2f}"
                err = f"{self.slope_error[k]:6.0%}"
            else:
                slope, err = "unobservable", "-"
            lines.append(
                f"{n:10s} {'yes' if self.observable[k] else 'no':>5s} {self.cover1[k]:6.2f} "
                f"{self.cover2[k]:6.2f} {self.filter_cover1[k]:7.2f} {self.level_rms[k]:6.2f} "
                f"{self.sigma[k]:6.2f} {self.change_cover1[k]:6.2f} "
                f"{self.change_cover2[k]:6.2f} {self.change_rms[k]:6.2f} "
                f"{self.end_change_rms[k]:6.2f} {slope:>14s} {self.slope_true[k]:6.2f} {err:>6s}")
        return "\n".join(lines)

    def summary(self) -> dict[str, float]:
        """Figures over the shown parameters next to which the targets are stated."""
        o = self.observable
        rel = np.abs(self.slope_error)
        shown = self.slope_shown
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
            "slopes_shown": int(shown.sum()),
            "slope_err_max": float(rel[shown].max()) if shown.any() else nan,
        }


def score(
    est: SnapshotEstimator, calib: uncertainty.Calibration, plan: FleetPlan, snaps: Snapshots,
) -> Score:
    """Coverage, level and change RMS and slopes of ``est`` with ``calib`` on a fleet."""
    tr = health_accuracy.tracks(est, plan, snaps)
    segs = segments(plan, tr)
    st = _stack(segs, calib.drift)
    raw_err = st["level_err"]  # the filter's estimate against its own 1-sigma
    # What the trend shows (``trends.health.apply``): the calibrated level and change.
    levels = [calib.level(s.h_hat, s.h_sigma) for s in segs]
    changes = [calib.change(s.h_hat, s.h_hat[:1], s.h_sigma, s.h_sigma[0], s.kcycles)
               for s in segs]
    st["level_err"] = np.concatenate([h - s.h_true for (h, _), s in zip(levels, segs,
                                                                        strict=True)])
    sigma = np.concatenate([sg for _, sg in levels])
    st["change_err"] = np.concatenate([dh - (s.h_true - s.h_true[0])
                                       for (dh, _), s in zip(changes, segs, strict=True)])
    d_sigma = np.concatenate([sg for _, sg in changes])
    pieces = calibration.trend_pieces(tr)
    slope_shown = calib.observable & np.isfinite(np.asarray(calib.slope_gain))
    slope_hat, slope_sigma, slope_true = pieces.fleet(
        calib.slope_gain, calib.slope_noise, calib.slope_common, calib.slope_gain_std,
        calib.slope_correction, calib.slope_scale)
    slope_hat = np.where(slope_shown, slope_hat, np.nan)
    ends = np.array([dh[-1] - (s.h_true[-1] - s.h_true[0])
                     for (dh, _), s in zip(changes, segs, strict=True)])
    fleet_rms, raw_rms, spread_ratio = fleet_average_errors(
        tr, np.asarray(calib.level_correction))
    cov = uncertainty.coverage
    aux = tuple(est.layout.aux)
    fe = calibration.figure_errors(plan, tr, aux, vstar=est.vstar) if aux else None
    fleet_aux = fleet_aux_errors(calib, aux, fe) if fe is not None else (None, None, None)
    return Score(
        names=calib.names, observable=calib.observable,
        cover1=cov(st["level_err"], sigma, 1.0), cover2=cov(st["level_err"], sigma, 2.0),
        filter_cover1=cov(raw_err, np.sqrt(st["filter_var"]), 1.0),
        level_rms=np.sqrt(np.mean(st["level_err"] ** 2, axis=0)), sigma=sigma.mean(axis=0),
        change_cover1=cov(st["change_err"], d_sigma, 1.0),
        change_cover2=cov(st["change_err"], d_sigma, 2.0),
        change_rms=np.sqrt(np.mean(st["change_err"] ** 2, axis=0)),
        end_change_rms=np.sqrt(np.mean(ends**2, axis=0)),
        slope_hat=slope_hat, slope_sigma=np.where(slope_shown, slope_sigma, np.nan),
        slope_true=slope_true, slope_shown=slope_shown,
        records=int(st["level_err"].shape[0]), segments=len(segs), pieces=len(pieces.spans),
        fleet_level_rms=fleet_rms, fleet_raw_rms=raw_rms, fleet_spread_ratio=spread_ratio,
        fleet_aux_rms=fleet_aux[0], fleet_aux_raw_rms=fleet_aux[1],
        fleet_aux_spread_ratio=fleet_aux[2],
        figures={**(figures(calib, aux, tuple(est.layout.tuners), fe) if fe is not None
                    else {}), **rate_figures(calib, segs)},
    )


def fleet_aux_errors(
    calib: uncertainty.Calibration, aux: tuple[str, ...], fe: calibration.FigureErrors,
    period: str = "month",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fleet page's monthly fleet-average aux outputs (percent of the nominal engine's
    value) as the product forms them (each engine's period means of its aux and health
    estimates and their moments, ``uncertainty.fleet_outputs`` with the calibration's
    correction), on the records ``fe`` holds, against the fleet average of the engines' true
    means over the same records: RMS error over periods [n_aux] calibrated and as estimated,
    and the RMS ratio of the spread over engines shown to the true one."""
    z_hat = fe.aux_err + fe.aux_true
    starts = buckets.period_starts(fe.epoch, period)
    periods = []
    for start in np.unique(starts):
        keys = fe.engine[starts == start]
        engines = np.unique(keys)
        at = np.flatnonzero(starts == start)
        z = np.array([z_hat[at[keys == e]].mean(0) for e in engines])
        h = np.array([fe.h_hat[at[keys == e]].mean(0) for e in engines])
        true = np.array([fe.aux_true[at[keys == e]].mean(0) for e in engines])
        mean, spread = uncertainty.fleet_outputs(
            z.mean(0), np.square(z).mean(0), (z[:, :, None] * h[:, None, :]).mean(0),
            h.mean(0), uncertainty.pair_products(h).mean(0), calib.aux_rows(aux))
        periods.append((mean, z.mean(0), spread, true))
    return _against_truth(periods)


def rate_figures(calib: uncertainty.Calibration,
                 segs: list[Segment]) -> dict[str, tuple[float, float, float]]:
    """Coverage of the fleet status's rate of change (``app.services.fleet.status``): the
    change of each shown parameter's calibrated level over ``uncertainty.RATE_WINDOW`` records
    with its 1-sigma (``Calibration.rate``), against the true change over the same records,
    over every settled record of the segments with one that many records before it."""
    w = uncertainty.RATE_WINDOW
    long = [s for s in segs if len(s.kcycles) > w]
    if not long:
        return {}
    pairs = [calib.rate(s.h_hat[w:], s.h_hat[:-w], s.h_sigma[w:], s.h_sigma[:-w])
             for s in long]
    err = np.concatenate([dh - (s.h_true[w:] - s.h_true[:-w])
                          for (dh, _), s in zip(pairs, long, strict=True)])
    sigma = np.concatenate([sg for _, sg in pairs])
    cov = uncertainty.coverage
    c1, c2 = cov(err, sigma, 1.0), cov(err, sigma, 2.0)
    return {f"rate {name}": (float(c1[k]), float(c2[k]), np.nan)
            for k, name in enumerate(calib.names) if calib.observable[k]}


def figures(calib: uncertainty.Calibration, aux: tuple[str, ...], tuners: tuple[str, ...],
            fe: calibration.FigureErrors) -> dict[str, tuple[float, float, float]]:
    """Coverage of the bands the engine page draws besides the health's, as the trend forms
    them: each aux output in percent (``Calibration.aux_sigma``; the filter's own sigma beside
    it), its value in engineering units (z's error and the schedule trim's, with the trim's
    model error: ``performance.engineering_sigma``), the measured figures (deltas, EGT
    margin) and the shown tuners, calibrated, against V* h (``Calibration.tuner_level``,
    ``Calibration.tuner_sigma``; the filter's sigma beside on the tuners as estimated)."""
    cov = uncertainty.coverage
    out = {}
    filter_std = np.sqrt(fe.aux_var)
    z_sigma = calib.aux_sigma(aux, filter_std, fe.d)
    value_sigma = calib.value_sigma(aux, z_sigma)
    # The calibrated aux outputs' errors (the correction is additive: (z - X C) - z_true);
    # the filter's own sigma beside them is scored on the estimates as they were shown before.
    aux_err = calib.aux_level(aux, fe.aux_err, fe.h_hat)
    value_err = aux_err + fe.trim_err
    for k, name in enumerate(aux):
        out[f"{name} %"] = (float(cov(aux_err[:, k:k + 1], z_sigma[:, k:k + 1])[0]),
                            float(cov(aux_err[:, k:k + 1], z_sigma[:, k:k + 1], 2.0)[0]),
                            float(cov(fe.aux_err[:, k:k + 1], filter_std[:, k:k + 1])[0]))
        out[f"{name} value"] = (
            float(cov(value_err[:, k:k + 1], value_sigma[:, k:k + 1])[0]),
            float(cov(value_err[:, k:k + 1], value_sigma[:, k:k + 1], 2.0)[0]), np.nan)
    if fe.tuner_err.size:
        # The calibrated tuners (the correction is additive, as the aux outputs'); the filter's
        # own sigma beside them on the tuners as estimated; an unobservable one is not shown.
        q_filter = np.sqrt(fe.tuner_var)
        q_sigma = calib.tuner_sigma(tuners, q_filter, fe.d)
        q_err = calib.tuner_level(tuners, fe.tuner_err, fe.h_hat)
        hidden = calib.tuner_hidden(tuners)
        for k, name in enumerate(tuners):
            if hidden[k]:
                continue
            e = q_err[:, k:k + 1]
            out[f"tuner {name}"] = (float(cov(e, q_sigma[:, k:k + 1])[0]),
                                    float(cov(e, q_sigma[:, k:k + 1], 2.0)[0]),
                                    float(cov(fe.tuner_err[:, k:k + 1], q_filter[:, k:k + 1])[0]))
    for k, name in enumerate(calibration.DELTA_FIGURES):
        std = calib.delta_model_std(name)
        if std is None or not len(fe.delta_err):
            continue
        sigma = np.full((len(fe.delta_err), 1), std)
        err = fe.delta_err[:, k:k + 1]
        out[name] = (float(cov(err, sigma)[0]), float(cov(err, sigma, 2.0)[0]), np.nan)
    return out


def fleet_average_errors(
    tracks: list[calibration.HealthTrack], correction: np.ndarray, period: str = "month",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fleet page's fleet-average level per period, as the product forms it (each engine's
    mean of its estimates in the period, their products, ``uncertainty.fleet_level``), against
    the fleet average of the engines' true means over the same records: RMS error over periods
    [p] with the correction and without it, and the RMS ratio of the spread over engines shown
    to the true one."""
    per: dict[float, list[tuple[np.ndarray, np.ndarray]]] = {}
    for track in tracks:
        assert track.epoch is not None
        starts = buckets.period_starts(track.epoch, period)
        for start in np.unique(starts):
            mine = starts == start
            per.setdefault(float(start), []).append((track.h_hat[mine].mean(0),
                                                     track.h_true[mine].mean(0)))
    periods = []
    for start in sorted(per):
        hat = np.array([h for h, _ in per[start]])
        true = np.array([t for _, t in per[start]])
        level, spread = uncertainty.fleet_level(
            hat.mean(0), uncertainty.pair_products(hat).mean(0), correction)
        periods.append((level, hat.mean(0), spread, true))
    return _against_truth(periods)


def _against_truth(
    periods: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per period, the fleet page's figure [k], the estimates' plain mean [k], the spread over
    engines shown [k] and the engines' true means [engines, k]: the RMS over periods of the
    figure's and of the plain mean's error against the fleet average of the true means, and
    the RMS ratio of the spread shown to the true one."""
    def rms(x: list[np.ndarray]) -> np.ndarray:
        return np.sqrt(np.mean(np.square(np.array(x)), axis=0))

    return (rms([f - t.mean(0) for f, _, _, t in periods]),
            rms([m - t.mean(0) for _, m, _, t in periods]),
            rms([s for _, _, s, _ in periods]) / rms([t.std(0) for _, _, _, t in periods]))


@dataclass(frozen=True)
class ActuatorShare:
    """How much of each level's error is the engines' actuator biases (Wf, VSV, VBV rigging:
    fixed per engine in the simulator) that a design without bias tuners cannot estimate.
    Per engine, the mean over its settled records of the estimate and of its error; per
    parameter [p], the RMS over engines of that error once a straight fit on the engine's
    mean estimates is taken out (what a straight level correction leaves), and once a fit on
    the estimates and the true biases is (all biases, then each alone). Every fit is made on
    the other fleets (leave one fleet out)."""

    names: tuple[str, ...]
    biases: tuple[str, ...]
    engines: int
    rms: np.ndarray  # [p]
    rms_without: np.ndarray  # [p, 1 + len(biases)]

    def report(self) -> str:
        head = ", ".join(("all", *self.biases))
        lines = [f"level error per engine (mean over its settled records, {self.engines} "
                 "engines), RMS [%] after a straight correction on the estimates -> on the "
                 f"estimates and the true actuator biases ({head}); fitted leaving the "
                 "engine's fleet out:"]
        for k, n in enumerate(self.names):
            rest = " / ".join(f"{v:.3f}" for v in self.rms_without[k])
            share = 1.0 - (self.rms_without[k, 0] / self.rms[k]) ** 2
            lines.append(f"  {n:10s} {self.rms[k]:.3f} -> {rest}  ({share:.0%} of what the "
                         "correction leaves is the biases')")
        return "\n".join(lines)


def actuator_share(
    est: SnapshotEstimator, fleets: list[tuple[FleetPlan, Snapshots]],
) -> ActuatorShare:
    """``ActuatorShare`` of ``est`` over ``fleets`` (at least two)."""
    cols = [HEALTH_NAMES.index(b) for b in ACTUATOR_BIASES]
    fleet_of, means, errors, biases = [], [], [], []
    for f, (plan, snaps) in enumerate(fleets):
        for t in health_accuracy.tracks(est, plan, snaps):
            ok = t.settled
            if not ok.any():
                continue
            means.append(t.h_hat[ok].mean(axis=0))
            errors.append((t.h_hat[ok] - t.h_true[ok]).mean(axis=0))
            biases.append(plan.health[t.round[ok], plan.esns.index(t.esn)][:, cols].mean(axis=0))
            fleet_of.append(f)
    h, err, b, fl = np.array(means), np.array(errors), np.array(biases), np.array(fleet_of)

    def left(x: np.ndarray) -> np.ndarray:
        """RMS [p] of what a fit of the errors on [1, x], made on the other fleets, leaves."""
        x = np.c_[np.ones(len(x)), x]
        rest = np.empty_like(err)
        for f in np.unique(fl):
            out = fl == f
            coef, *_ = np.linalg.lstsq(x[~out], err[~out], rcond=None)
            rest[out] = err[out] - x[out] @ coef
        return np.sqrt(np.mean(rest**2, axis=0))

    picks = [list(range(len(cols)))] + [[c] for c in range(len(cols))]
    return ActuatorShare(
        names=tuple(est.layout.health), biases=tuple(ACTUATOR_BIASES), engines=len(err),
        rms=left(h), rms_without=np.stack([left(np.c_[h, b[:, p]]) for p in picks], axis=1))
