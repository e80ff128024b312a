"""Honest uncertainty of the snapshot filter's health estimate: three parts and a change.

The filter's own covariance (``snapshot.snapshot_filter`` h_std) counts sensor noise only.
The error of h_hat against the true health has three parts, per health parameter k:

    sigma_k^2 = bias2_k + var_k + s_k^2

- ``bias2_k = diag(B_h P_h B_h^T)_k``: the design's analytic bias under the fleet prior P_h
  (seed 002 eq. 18-19, seed 003 "Analytical derivation of Kalman estimation error"). For the
  snapshot filter the steady state of a constant h is the information-weighted least-squares
  tuner fit over the operating conditions it sees (``snapshot_bias_matrix``):

      N = sum_j (G_j V*^+)^T R_j^-1 (G_j V*^+)      [m, m]   information per record, averaged
      b = sum_j (G_j V*^+)^T R_j^-1 G_j             [m, p]
      q_ss = N^+ b h,   B_h = V*^+ N^+ b - I        [p, p]

  with N^+ a pseudo-inverse that drops the tuner directions whose information is too small
  for the filter to resolve within its memory (their estimate stays at the prior mean 0).
- ``var_k``: the filter variance, diag(V*^+ P V*^+T) per record (what the product stores).
- ``s_k^2``: the model's own error (linearisation and scheduling of the nonlinear engine, the
  mix of take-off and cruise in one filter), not in the linear theory: calibrated on the
  nonlinear fleet simulator with the product's own filter (``fit_model_std``) and stored with
  the design as a ``Calibration`` (JSON: ``to_dict`` / ``from_dict``).

The change since a baseline record 0 (installation, shop visit, first settled record):

    delta_hat = h_hat(t) - h_hat(0)
    sigma_delta_k^2 = var_k(t) + var_k(0) + (d_k c)^2 + s_delta_k^2

The bias B_h h(0) common to both records cancels, as does the part of the model error that is
constant per engine (scatter, actuator offsets). What remains: the bias of the change itself,
B_h (h(t) - h(0)); along the fleet's mean deterioration rate r [% per 1000 cycles] it is
d = B_h r per 1000 cycles (``drift_bias``), over c thousand cycles since the baseline; the
filter noise at both ends (treated as independent: the filter's memory is much shorter than a
trend); and a calibrated s_delta for the model error that varies along the trend.

Fleet-average deterioration slope. Each engine's trend between baseline resets (a piece)
gives a weighted least-squares slope b_e over its span T_e (``piece_slope``). Its error against
the true slope is the change of a slowly wandering model error over the span (the level error
drifts with the operating conditions and with the other modules' wear, over weeks, not record
to record), so var(b_e - b_true,e) = a_k / T_e^2: the fleet slope is the inverse-variance
mean with weights T_e^2 (``fleet_slope``), and its 1-sigma sqrt(a_k / sum T_e^2 + c_k), c_k
the part of the error common to one fleet's pieces (what does not average out over its
engines: the calibration fleets' errors beyond their piece noise). The nonlinear
engine moves an estimated trend by a gain g_k (the linear theory's I + B_h along the fleet's
rates: other modules' wear read as this one's); the estimate is divided by g_k. a_k
(``fit_slope_noise``), c_k and g_k (``fit_slope_gain``) are calibrated on the simulated fleets
with s (``fit_fleet_slope``, over K calibration fleets).

The gain is itself an estimate from K fleets, and its error moves every fleet's corrected
slope the same way (slope * dg / g): the 1-sigma holds it in quadrature,

    sigma_k^2 = (a_k / sum T_e^2 + c_k) / g_k^2 + (slope_k * u_k / g_k)^2

with u_k the gain's jackknife standard error over the calibration fleets (the gains g_(-j)
of the K leave-one-fleet-out pools: u^2 = (K - 1) / K sum_j (g_(-j) - mean g_(-j))^2,
``fit_fleet_slope``). c_k (cross-validated: each fleet corrected with the gain of the others)
holds a K-1-fleet gain error in expectation too, but averaged over K = 6 fleets and clipped at
0 it often does not; u is the gain's error on its own (its jackknife matches the spread of the
gain over independent draws of calibration fleets, bench_uncertainty). One calibration fleet
cannot be cross-validated: its slopes are unobservable.

Slope correction. A gain is one number per parameter, but the error of a piece's slope is not
a fixed share of it: other modules' wear is read into this one in proportions that differ
from engine to engine and from fleet to fleet. So each piece's estimated slopes b_e [p] are
corrected first, as the level is (``correct_slopes``),

    b_e,cal = b_e - A b_e,

row k of A the least-squares fit of the pieces' errors b_e,k - b_true,e,k on b_e over the
calibration fleets, each piece's row weighted by T_e^2, its weight in its fleet's slope
(``fit_slope_correction``). g, a, c and u are then fitted on the corrected slopes, each
calibration fleet's corrected by the A fitted without it. The sigma so refitted over-covered
on the simulator (the demo design's hpc_eff and hpc_flow held the truth within 1-sigma on 96 %
and 88 % of 48 scoring fleets, bench_uncertainty), so it carries a scale lambda:

    sigma_k = lambda sqrt((a_k / sum T_e^2 + c_k) / g_k^2 + (slope_k u_k / g_k)^2)

fitted by nested cross-validation: each calibration fleet's slope and sigma from the
corrected calibration of the other fleets (their own left-out A inside), z = |slope - true| /
sigma pooled over the shown slopes, lambda the smallest holding ``SLOPE_ONE_SIGMA`` of them
within lambda sigma and ``SLOPE_TWO_SIGMA`` within 2 lambda sigma (``fit_slope_scale``). A
slope is shown where it passes the rule below both as estimated and corrected: A sharpens a
trend the design reads, it does not make one of the other parameters' slopes.

Calibrated level. On the nonlinear engine most of the level error is not noise but a
function of the engine's state that a linear filter reads the same way on every fleet: an
engine far from nominal (hpc_flow -17 %) has its hpc_eff read 4.6 % low. So the level shown
is calibrated on the simulated fleets (docs/math.md section 15): the error of each parameter k
is regressed on the record's estimates,

    h_hat_k - h_k ~ C_k x(h_hat),     h_cal = h_hat - x(h_hat) C^T      (``correct_level``)

with x = [1, h_hat] (straight) or x = [1, h_hat, h_hat_i h_hat_j] (curved: the engine's error
bends with the products of its estimates; ``correction_design``), curved where that cuts the
straight fit's cross-validated error by at least ``MIN_CURVE_GAIN``
(``fit_level_correction``), and C_k is kept where a C fitted on the other calibration fleets
cuts the RMS error of the fleet left out by at least ``MIN_CORRECTION_GAIN``. Every
calibration figure is then taken on the records corrected by their own fleet's left-out C:
the correction's error out of sample. The change since a baseline is the calibrated level's at
both ends, differenced: the constant cancels (``correct_change``). The model error s grows
with the record's distance from the nominal engine d (``spread``: the RMS of its estimated
deviations):

    sigma_k^2 = a_k^2 bias2_k + (f_k sigma_f,k)^2 + s_k^2 + (kappa_k d)^2

(``fit_model_spread``), where f_k <= 1 (``fit_filter_scale``) scales the filter variance where
the corrected error is smaller than it claims (the correction regresses on every estimate,
whose errors are correlated, so it cancels part of the filter noise too). The change's sigma
scales the filter variances at both ends by its own f_delta,k <= 1: the two ends' errors are
correlated (most of a level error is a constant of the engine), so their sum in quadrature
overstates the change's.

A parameter is shown as unobservable (no number) when the design cannot tell it apart from the
fleet prior: its honest sigma (bias, filter and model error at steady state) is more than
``reduction`` of its prior sigma, or (for trends) the fleet-average slope the calibration run
measured is off the true slope by more than ``slope_tolerance`` (``observable``). Its
fleet-average slope is unobservable as well, and also without a gain (no trend the calibration
fleets measure well enough to calibrate it on, or one the design reads backwards).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from estimation.errors import DimensionError

CALIBRATION_FORMAT = "fleethealth.uncertainty-calibration/1"
# Coverage the calibration aims at on its own (pooled) fleets: 72 % at 1-sigma and 96 % at
# 2-sigma, inside the required 55-85 % and >= 85 % with room for the spread from one fleet to
# another (most of a level error is a constant of its engine, and a fleet has a few dozen).
# With the calibrated level (its correction and spread) the errors are close enough to a
# Gaussian for both; before it, their heavy tails let the 2-sigma level set s, and a 2-sigma
# aim of 0.87 was the most the 1-sigma band allowed (bench_uncertainty).
ONE_SIGMA_TARGET = 0.72
TWO_SIGMA_TARGET = 0.96
# A tuner direction is resolved when its information per record is at least this fraction of
# the largest one (below, the filter's random walk forgets faster than it learns).
MIN_INFORMATION = 1e-4
# The fleet status's rate of change compares an engine's latest level with the one this many
# records before it (``Calibration.rate``).
RATE_WINDOW = 50


def snapshot_bias_matrix(
    G_y: np.ndarray, noise_std: np.ndarray, Vp: np.ndarray, min_information: float = MIN_INFORMATION
) -> np.ndarray:
    """Bias matrix B_h [p, p] of the snapshot filter's steady state (module docstring).

    G_y [J, ny, p]: gains at J representative records (percent per percent); noise_std
    [J, ny] sensor noise (percent of trim, with the sensor model error); Vp = V*^+ [p, m].
    h_hat_ss - h = B_h h for a constant health h; B_h = 0 when the tuners are the health
    parameters and the conditions observe all of them.
    """
    G_y = np.asarray(G_y, float)
    noise_std = np.asarray(noise_std, float)
    Vp = np.asarray(Vp, float)
    if G_y.ndim != 3:
        raise DimensionError(f"G_y must be [J, ny, p], found shape {G_y.shape}")
    J, ny, p = G_y.shape
    if noise_std.shape != (J, ny):
        raise DimensionError(
            f"Incompatible dimensions of noise_std; expected ({J}, {ny}) but found "
            f"{noise_std.shape}"
        )
    if Vp.shape[0] != p:
        raise DimensionError(f"Incompatible dimensions of Vp; expected ({p}, m), found {Vp.shape}")
    W = G_y / noise_std[:, :, None]  # R^-1/2 G_y per record
    Hw = W @ Vp  # [J, ny, m]
    N = np.einsum("jim,jin->mn", Hw, Hw) / J
    b = np.einsum("jim,jip->mp", Hw, W) / J
    evals, evecs = np.linalg.eigh(0.5 * (N + N.T))
    keep = evals > min_information * max(float(evals[-1]), 0.0)
    inv = (evecs[:, keep] / evals[keep]) @ evecs[:, keep].T  # N^+ on resolved directions
    return Vp @ inv @ b - np.eye(p)


def analytic_bias2(B_h: np.ndarray, Ph: np.ndarray) -> np.ndarray:
    """diag(B_h P_h B_h^T) [p] (seed 002 eq. 19), percent squared."""
    B_h = np.asarray(B_h, float)
    return np.einsum("ij,jk,ik->i", B_h, np.asarray(Ph, float), B_h)


def drift_bias(B_h: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """Bias of an estimated trend d = B_h r [p] (percent per 1000 cycles) for the fleet's mean
    deterioration rate r [p]: the estimated slope is r + d."""
    return np.asarray(B_h, float) @ np.asarray(rate, float)


@dataclass(frozen=True)
class Calibration:
    """Model-error term of one design, fitted on the nonlinear fleet simulator.

    names [p]: health parameters; level_std [p]: s_k, percent; change_std [p]: s_delta_k,
    percent; slope_error [p]: (estimated - true) mean rate over the calibration fleets'
    segments over max(|true|, a floor) (the level's observability rule); bias2 [p]: the
    analytic bias^2 (a^2 bias2 is used, a = bias_scale); observable [p]: the rule's verdict;
    slope_gain [p]: g_k (None: 1; NaN: the slope is unobservable); slope_noise [p]: a_k,
    (percent per year)^2 years^2 (None: not calibrated); slope_common [p]: c_k, (percent per
    year)^2 (None: 0); source: how it was made (seed, fleet size, design).
    """

    names: tuple[str, ...]
    level_std: np.ndarray
    change_std: np.ndarray
    slope_error: np.ndarray
    bias2: np.ndarray
    drift: np.ndarray  # d = B_h r, percent per 1000 cycles
    observable: np.ndarray  # bool
    bias_scale: np.ndarray | None = None  # [p] a of a^2 bias2 (fit_bias_scale); None: 1
    source: Mapping[str, Any] = field(default_factory=dict)
    # Aux outputs (thrust, margins): s of each, percent of the record's trim, fitted like
    # level_std on the filter's aux variance (``fit_model_std``); empty: not calibrated.
    aux_names: tuple[str, ...] = ()
    aux_std: np.ndarray | None = None
    # Per aux output: the scale f (0, 1] of its filter variance where that alone over-covers
    # (``fit_filter_scale``; None: 1), and the model error s_trim (percent of trim; None: 0)
    # that a value in engineering units (the engine schedule's interpolated trim (1 + z / 100))
    # carries besides z's honest sigma: the trim's error against the nominal engine solved at
    # the record's condition, fitted on the values' errors as ``fit_model_std`` does.
    aux_scale: np.ndarray | None = None
    aux_trim_std: np.ndarray | None = None
    aux_spread: np.ndarray | None = None  # kappa of each aux output, as the level's (None: 0)
    # Measured figures (the engine type's smoothed deltas and EGT margin, each in its unit):
    # their whole 1-sigma, fitted like aux_std with no filter variance; empty: not calibrated.
    delta_names: tuple[str, ...] = ()
    delta_std: np.ndarray | None = None
    # The tuners (q_hat against V* h of the true health): their filter variance's scale and
    # model error, as the aux outputs', the model error growing with the record's distance
    # from nominal as the level's (None: 1, 0 and 0; empty: not calibrated).
    tuner_names: tuple[str, ...] = ()
    tuner_std: np.ndarray | None = None
    tuner_scale: np.ndarray | None = None
    tuner_spread: np.ndarray | None = None  # kappa, as the level's (None: 0)
    # The calibrated tuners: the level's correction seen along the design's tuner directions,
    # V* C [m, correction_width(p)] (q_hat - X (V* C)^T = V* times the calibrated level, as
    # q_hat = V* h_hat), and which tuners are shown [m] bool (the level's rule on their own
    # errors); None: the tuners as estimated, every one shown (a calibration stored before).
    tuner_correction: np.ndarray | None = None
    tuner_observable: np.ndarray | None = None
    # Fleet-average slope: gain g_k, noise a_k and common error c_k (module docstring); None:
    # 1, unknown and 0.
    slope_gain: np.ndarray | None = None
    slope_noise: np.ndarray | None = None
    slope_common: np.ndarray | None = None
    # The gain's standard error u_k (module docstring); None: not calibrated (a calibration
    # stored before the slope's sigma held it: the slope's sigma is unknown, recalibrate).
    slope_gain_std: np.ndarray | None = None
    # The calibrated level (module docstring): the correction C [p, 1 + p] (None: zeros, the
    # level as estimated), the model error's spread kappa [p] (None: 0) and the filter
    # variance's scale f [p] (None: 1).
    level_correction: np.ndarray | None = None
    level_spread: np.ndarray | None = None
    filter_scale: np.ndarray | None = None
    # The change's filter variance scale [p] (None: 1): the filter's errors at a record and
    # at its baseline are correlated (most of a level error is a constant of the engine), so
    # their variances in quadrature overstate the change's.
    change_scale: np.ndarray | None = None
    # The fleet slope's correction A [p, p] of the pieces' estimated slopes (None: zeros, the
    # slopes as estimated: a calibration stored before it) and its 1-sigma's scale lambda [p]
    # (None: 1).
    slope_correction: np.ndarray | None = None
    slope_scale: np.ndarray | None = None
    # The rate of change (the calibrated level's change over ``RATE_WINDOW`` records): its
    # filter variance's scale f, model error s and spread kappa [p], fitted as the aux
    # outputs' (``fit_output_sigma``); None: not calibrated (a calibration stored before
    # them), the change's sigma over the window instead.
    rate_std: np.ndarray | None = None
    rate_scale: np.ndarray | None = None
    rate_spread: np.ndarray | None = None
    # The calibrated aux outputs: a correction C_z [n_aux, correction_width(p)] of each aux
    # output (percent of trim) on the regressors of the health estimates, as the level's
    # (``fit_level_correction``; a row of zeros: that output as estimated); None: none (a
    # calibration stored before it).
    aux_correction: np.ndarray | None = None

    def __post_init__(self) -> None:
        p = len(self.names)
        # What a field left out (None: a calibration stored before it) stands for, and the
        # shape every field must have.
        defaults = {"level_correction": np.zeros((p, correction_width(p))),
                    "slope_correction": np.zeros((p, p)),
                    "slope_scale": np.ones(p), "level_spread": np.zeros(p),
                    "filter_scale": np.ones(p), "change_scale": np.ones(p),
                    "bias_scale": np.ones(p), "slope_gain": np.ones(p),
                    "slope_noise": np.full(p, np.nan), "slope_common": np.zeros(p),
                    "slope_gain_std": np.full(p, np.nan)}
        for name, default in defaults.items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, default)
        C = np.asarray(self.level_correction, float)
        if C.shape == (p, p + 1):  # stored before the curved correction: straight alone
            object.__setattr__(self, "level_correction", np.concatenate(
                [C, np.zeros((p, correction_width(p) - p - 1))], axis=1))
        shapes = {"level_correction": (p, correction_width(p)), "slope_correction": (p, p)}
        for name in ("level_correction", "slope_correction", "bias_scale", "level_std",
                     "change_std", "slope_error", "bias2", "drift", "observable", "slope_gain",
                     "slope_noise", "slope_common", "slope_gain_std", "level_spread",
                     "filter_scale", "change_scale", "slope_scale"):
            value = np.asarray(getattr(self, name), bool if name == "observable" else float)
            shape = shapes.get(name, (p,))
            if value.shape != shape:
                raise DimensionError(f"Incompatible dimensions of {name}; expected {shape} but "
                                     f"found {value.shape}")
            object.__setattr__(self, name, value)
        rate = (self.rate_std, self.rate_scale, self.rate_spread)
        if any(x is not None for x in rate):
            for name, fill in (("rate_std", 0.0), ("rate_scale", 1.0), ("rate_spread", 0.0)):
                value = getattr(self, name)
                value = np.full(p, fill) if value is None else np.asarray(value, float)
                if value.shape != (p,):
                    raise DimensionError(f"Incompatible dimensions of {name}; expected ({p},) "
                                         f"but found {value.shape}")
                object.__setattr__(self, name, value)
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "source", dict(self.source))
        # The outputs' fields, one value per name of their group (None: the fill; NaN in
        # aux_std or delta_std: that one not calibrated).
        for group in ("aux_names", "tuner_names", "delta_names"):
            object.__setattr__(self, group, tuple(getattr(self, group)))
        for name, held in (("aux_correction", self.aux_names),
                           ("tuner_correction", self.tuner_names)):
            if getattr(self, name) is None:
                continue
            value = np.asarray(getattr(self, name), float)
            shape = (len(held), correction_width(p))
            if value.shape != shape:
                raise DimensionError(f"Incompatible dimensions of {name}; expected "
                                     f"{shape} but found {value.shape}")
            object.__setattr__(self, name, value)
        if self.tuner_observable is not None:
            value = np.asarray(self.tuner_observable, bool)
            if value.shape != (len(self.tuner_names),):
                raise DimensionError(f"Incompatible dimensions of tuner_observable; expected "
                                     f"({len(self.tuner_names)},) but found {value.shape}")
            object.__setattr__(self, "tuner_observable", value)
        for name, fill, held in (("aux_std", np.nan, self.aux_names),
                                 ("aux_scale", 1.0, self.aux_names),
                                 ("aux_spread", 0.0, self.aux_names),
                                 ("aux_trim_std", 0.0, self.aux_names),
                                 ("tuner_std", 0.0, self.tuner_names),
                                 ("tuner_scale", 1.0, self.tuner_names),
                                 ("tuner_spread", 0.0, self.tuner_names),
                                 ("delta_std", np.nan, self.delta_names)):
            value = getattr(self, name)
            value = np.full(len(held), fill) if value is None else np.asarray(value, float)
            if value.shape != (len(held),):
                raise DimensionError(f"Incompatible dimensions of {name}; expected "
                                     f"({len(held)},) but found {value.shape}")
            object.__setattr__(self, name, value)

    def on(self, names: Sequence[str]) -> Calibration:
        """The calibration in the order of ``names``; a name it does not hold gets no model
        error (s = 0, no bias, no drift), a slope gain of 1 (exact: no gain error) with unknown
        noise, and counts as observable."""
        where = {n: k for k, n in enumerate(self.names)}
        index = np.array([where.get(n, -1) for n in names], int)
        held = index >= 0

        def pick(values: np.ndarray | None, missing: float | bool) -> np.ndarray:
            out = np.full(len(index), missing, np.asarray(values).dtype)
            out[held] = np.asarray(values)[index[held]]
            return out

        q = len(index)
        rows = np.flatnonzero(held)
        correction = np.zeros((q, correction_width(q)))
        correction[rows] = _on_regressors(np.asarray(self.level_correction)[index[rows]],
                                          index)
        slope_correction = np.zeros((q, q))
        A = np.asarray(self.slope_correction)
        for j in rows:
            slope_correction[rows, j] = A[index[rows], index[j]]
        aux_correction, tuner_correction = (
            None if C is None else _on_regressors(np.asarray(C), index)
            for C in (self.aux_correction, self.tuner_correction))
        return replace(
            self, names=tuple(names), level_std=pick(self.level_std, 0.0),
            level_correction=correction, level_spread=pick(self.level_spread, 0.0),
            slope_correction=slope_correction, slope_scale=pick(self.slope_scale, 1.0),
            filter_scale=pick(self.filter_scale, 1.0), change_scale=pick(self.change_scale, 1.0),
            change_std=pick(self.change_std, 0.0), slope_error=pick(self.slope_error, 0.0),
            bias2=pick(self.bias2, 0.0), drift=pick(self.drift, 0.0),
            observable=pick(self.observable, True), bias_scale=pick(self.bias_scale, 1.0),
            slope_gain=pick(self.slope_gain, 1.0), slope_noise=pick(self.slope_noise, np.nan),
            slope_common=pick(self.slope_common, 0.0),
            slope_gain_std=pick(self.slope_gain_std, 0.0),
            rate_std=None if self.rate_std is None else pick(self.rate_std, 0.0),
            rate_scale=None if self.rate_scale is None else pick(self.rate_scale, 1.0),
            rate_spread=None if self.rate_spread is None else pick(self.rate_spread, 0.0),
            aux_correction=aux_correction, tuner_correction=tuner_correction)

    def level(self, h_hat: np.ndarray, filter_std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The calibrated level and its honest 1-sigma [N, p] of estimates h_hat [N, p] with
        the filter's 1-sigma filter_std [N, p] (in this calibration's order: ``on``):
        ``correct_level``, and sqrt(a^2 bias2 + (f sigma_f)^2 + s^2 + (kappa d)^2) with d the
        record's ``spread``."""
        d = spread(h_hat)[..., None]
        model = np.sqrt(np.square(self.level_std) + np.square(np.asarray(self.level_spread) * d))
        bias2 = np.square(np.asarray(self.bias_scale)) * self.bias2
        return (correct_level(h_hat, np.asarray(self.level_correction)),
                level_sigma(np.asarray(self.filter_scale) * filter_std, bias2, model))

    def change(
        self, h_hat: np.ndarray, h_hat0: np.ndarray, filter_std: np.ndarray,
        filter_std0: np.ndarray, kcycles: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The calibrated change and its 1-sigma [N, p] of the estimates h_hat(t) [N, p]
        since their baseline h_hat(0) [N, p] (``correct_change``; ``change_sigma`` with the
        filter's 1-sigma at t and at the baseline scaled by the change's scale)."""
        f = np.asarray(self.change_scale)
        return (correct_change(h_hat, h_hat0, np.asarray(self.level_correction)),
                change_sigma(f * filter_std, f * filter_std0, kcycles, self.drift,
                             self.change_std))

    def rate(
        self, h_hat: np.ndarray, h_hat0: np.ndarray, filter_std: np.ndarray,
        filter_std0: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The calibrated change and its 1-sigma [N, p] over ``RATE_WINDOW`` records, from the
        estimates h_hat0 to h_hat [N, p] with the filter's 1-sigma filter_std0 and filter_std:
        sqrt(f^2 (sigma_f^2 + sigma_f0^2) + s^2 + (kappa d)^2), d the later record's
        ``spread``; not calibrated, the change's sigma (``change``, no drift over so short a
        span), which holds more than the level's errors between two records so close."""
        if self.rate_std is None:
            return self.change(h_hat, h_hat0, filter_std, filter_std0,
                               np.zeros(np.shape(h_hat)[:-1]))
        names = self.names
        both = np.hypot(np.asarray(filter_std, float), np.asarray(filter_std0, float))
        return (correct_change(h_hat, h_hat0, np.asarray(self.level_correction)),
                _model_sigma(names, self.rate_std, self.rate_scale, self.rate_spread, names,
                             both, spread(h_hat)))

    def aux_model_std(self, name: str) -> float | None:
        """s of one aux output (percent of trim); None when it was not calibrated."""
        return _held_value(self.aux_names, self.aux_std, name)

    def delta_model_std(self, name: str) -> float | None:
        """1-sigma of one measured figure (its unit); None when it was not calibrated."""
        return _held_value(self.delta_names, self.delta_std, name)

    def aux_level(self, names: Sequence[str], z_hat: np.ndarray,
                  h_hat: np.ndarray) -> np.ndarray:
        """The calibrated aux outputs [N, k] (percent of trim) named ``names`` of the
        estimates z_hat [N, k] at the health estimates h_hat [N, p] (in this calibration's
        order: ``on``): ``correct_outputs`` with each output's row of ``aux_correction``; an
        output it does not hold, or without a correction, as estimated."""
        z_hat = np.asarray(z_hat, float)
        C = self.aux_rows(names)
        return z_hat.copy() if C is None else correct_outputs(z_hat, h_hat, C)

    def aux_rows(self, names: Sequence[str]) -> np.ndarray | None:
        """The rows of ``aux_correction`` of the aux outputs ``names`` [k, w] (zeros for one it
        does not hold); None without a correction (a calibration stored before it)."""
        return _rows(self.aux_names, self.aux_correction, names)

    def tuner_level(self, names: Sequence[str], q_hat: np.ndarray,
                    h_hat: np.ndarray) -> np.ndarray:
        """The calibrated tuners [N, m] named ``names`` of the estimates q_hat [N, m] at the
        health estimates h_hat [N, p] (in this calibration's order: ``on``): V* times the
        calibrated level (``tuner_correction``); a tuner it does not hold, or without a
        correction, as estimated."""
        q_hat = np.asarray(q_hat, float)
        C = _rows(self.tuner_names, self.tuner_correction, names)
        return q_hat.copy() if C is None else correct_outputs(q_hat, h_hat, C)

    def tuner_hidden(self, names: Sequence[str]) -> np.ndarray:
        """[m] bool: the tuners named ``names`` the calibration finds unobservable (shown as
        such, not as a number); one it does not hold, or a calibration stored before the
        verdict, is shown."""
        shown = (np.ones(len(self.tuner_names), bool) if self.tuner_observable is None
                 else self.tuner_observable)
        return ~_by_name(self.tuner_names, shown.astype(float), names, 1.0).astype(bool)

    @property
    def tuners_corrected(self) -> list[str]:
        """The tuners whose values it corrects (a row of ``tuner_correction`` not zero)."""
        return _corrected(self.tuner_names, self.tuner_correction)

    @property
    def aux_corrected(self) -> list[str]:
        """The aux outputs whose values it corrects (a row of ``aux_correction`` not zero)."""
        return _corrected(self.aux_names, self.aux_correction)

    def aux_sigma(self, names: Sequence[str], filter_std: np.ndarray,
                  d: np.ndarray) -> np.ndarray:
        """The honest 1-sigma [N, nz] of aux estimates named ``names`` with the filter's
        1-sigma filter_std [N, nz] at records at distance d [N] from nominal (``spread``):
        sqrt((f sigma_f)^2 + s^2 + (kappa d)^2), percent of trim; an output the calibration
        does not hold keeps the filter's."""
        return _model_sigma(self.aux_names, self.aux_std, self.aux_scale, self.aux_spread,
                            names, filter_std, d)

    def tuner_sigma(self, names: Sequence[str], filter_std: np.ndarray,
                    d: np.ndarray) -> np.ndarray:
        """The honest 1-sigma [N, m] of the tuners named ``names`` with the filter's 1-sigma
        filter_std [N, m] at records at distance d [N] from nominal (their ``spread``):
        sqrt((f sigma_f)^2 + s^2 + (kappa d)^2)."""
        return _model_sigma(self.tuner_names, self.tuner_std, self.tuner_scale,
                            self.tuner_spread, names, filter_std, d)

    def value_sigma(self, names: Sequence[str], z_sigma: np.ndarray) -> np.ndarray:
        """1-sigma [N, nz] (percent of trim) of the values in engineering units, trim (1 + z /
        100), of the aux outputs ``names`` whose honest z sigma is z_sigma [N, nz]
        (``aux_sigma``): with their trim's model error s_trim in quadrature (0: not held)."""
        return np.hypot(np.asarray(z_sigma, float),
                        _by_name(self.aux_names, self.aux_trim_std, names, 0.0))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (``fleethealth.uncertainty-calibration/1``; NaN as null)."""

        def listed(a: np.ndarray) -> list[Any]:
            return [None if not np.isfinite(x) else float(x) for x in a]

        return {
            "format": CALIBRATION_FORMAT,
            "names": list(self.names),
            "level_std": listed(self.level_std),
            "change_std": listed(self.change_std),
            "slope_error": listed(self.slope_error),
            "bias2": listed(self.bias2),
            "drift": listed(self.drift),
            "observable": [bool(x) for x in self.observable],
            "bias_scale": listed(np.asarray(self.bias_scale)),
            "source": dict(self.source),
            "aux_names": list(self.aux_names),
            "aux_std": listed(np.asarray(self.aux_std)),
            "aux_scale": listed(np.asarray(self.aux_scale)),
            "aux_trim_std": listed(np.asarray(self.aux_trim_std)),
            "aux_spread": listed(np.asarray(self.aux_spread)),
            "tuner_names": list(self.tuner_names),
            "tuner_std": listed(np.asarray(self.tuner_std)),
            "tuner_scale": listed(np.asarray(self.tuner_scale)),
            "tuner_spread": listed(np.asarray(self.tuner_spread)),
            # null: the tuners as estimated (a design whose tuners span more than the health)
            "tuner_correction": None if self.tuner_correction is None
            else [listed(row) for row in self.tuner_correction],
            "tuner_observable": None if self.tuner_observable is None
            else [bool(x) for x in self.tuner_observable],
            "delta_names": list(self.delta_names),
            "delta_std": listed(np.asarray(self.delta_std)),
            "slope_gain": listed(np.asarray(self.slope_gain)),
            "slope_noise": listed(np.asarray(self.slope_noise)),
            "slope_common": listed(np.asarray(self.slope_common)),
            "slope_gain_std": listed(np.asarray(self.slope_gain_std)),
            "level_correction": [listed(row) for row in np.asarray(self.level_correction)],
            "level_spread": listed(np.asarray(self.level_spread)),
            "filter_scale": listed(np.asarray(self.filter_scale)),
            "change_scale": listed(np.asarray(self.change_scale)),
            "slope_correction": [listed(row) for row in np.asarray(self.slope_correction)],
            "slope_scale": listed(np.asarray(self.slope_scale)),
            **({} if self.aux_correction is None else {
                "aux_correction": [listed(row) for row in np.asarray(self.aux_correction)]}),
            **({} if self.rate_std is None else {
                "rate_std": listed(np.asarray(self.rate_std)),
                "rate_scale": listed(np.asarray(self.rate_scale)),
                "rate_spread": listed(np.asarray(self.rate_spread))}),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Calibration:
        if d.get("format") != CALIBRATION_FORMAT:
            raise ValueError(f"format must be {CALIBRATION_FORMAT!r}, found {d.get('format')!r}")

        def arr(key: str) -> np.ndarray:
            return np.array([np.nan if x is None else x for x in d[key]], float)

        return cls(
            names=tuple(d["names"]), level_std=arr("level_std"), change_std=arr("change_std"),
            slope_error=arr("slope_error"), bias2=arr("bias2"), drift=arr("drift"),
            observable=np.array(d["observable"], bool),
            bias_scale=arr("bias_scale") if "bias_scale" in d else None,
            source=dict(d.get("source", {})),
            aux_names=tuple(d.get("aux_names", ())),
            aux_std=arr("aux_std") if "aux_std" in d else None,
            aux_scale=arr("aux_scale") if "aux_scale" in d else None,
            aux_trim_std=arr("aux_trim_std") if "aux_trim_std" in d else None,
            aux_spread=arr("aux_spread") if "aux_spread" in d else None,
            tuner_names=tuple(d.get("tuner_names", ())),
            tuner_std=arr("tuner_std") if "tuner_std" in d else None,
            tuner_scale=arr("tuner_scale") if "tuner_scale" in d else None,
            tuner_spread=arr("tuner_spread") if "tuner_spread" in d else None,
            delta_names=tuple(d.get("delta_names", ())),
            delta_std=arr("delta_std") if "delta_std" in d else None,
            slope_gain=arr("slope_gain") if "slope_gain" in d else None,
            slope_noise=arr("slope_noise") if "slope_noise" in d else None,
            slope_common=arr("slope_common") if "slope_common" in d else None,
            slope_gain_std=arr("slope_gain_std") if "slope_gain_std" in d else None,
            level_correction=np.array(d["level_correction"], float)
            if "level_correction" in d else None,
            level_spread=arr("level_spread") if "level_spread" in d else None,
            filter_scale=arr("filter_scale") if "filter_scale" in d else None,
            change_scale=arr("change_scale") if "change_scale" in d else None,
            slope_correction=np.array(d["slope_correction"], float)
            if "slope_correction" in d else None,
            slope_scale=arr("slope_scale") if "slope_scale" in d else None,
            rate_std=arr("rate_std") if "rate_std" in d else None,
            rate_scale=arr("rate_scale") if "rate_scale" in d else None,
            rate_spread=arr("rate_spread") if "rate_spread" in d else None,
            aux_correction=np.array(d["aux_correction"], float).reshape(
                len(d.get("aux_names", ())), -1) if "aux_correction" in d else None,
            tuner_correction=np.array(d["tuner_correction"], float).reshape(
                len(d.get("tuner_names", ())), -1)
            if d.get("tuner_correction") is not None else None,
            tuner_observable=np.array(d["tuner_observable"], bool)
            if d.get("tuner_observable") is not None else None,
        )

    @property
    def slope_sigma_known(self) -> bool:
        """Whether the slopes' 1-sigma can be formed: the gain's standard error was calibrated
        wherever a slope is shown (False: stored before it was, recalibrate)."""
        shown = np.asarray(self.observable) & np.isfinite(np.asarray(self.slope_gain))
        return bool(np.all(np.isfinite(np.asarray(self.slope_gain_std))[shown]))


def _model_sigma(held: Sequence[str], std: np.ndarray | None, scale: np.ndarray | None,
                 kappa: np.ndarray | None, names: Sequence[str], filter_std: np.ndarray,
                 d: np.ndarray) -> np.ndarray:
    """sqrt((f sigma_f)^2 + s^2 + (kappa d)^2) [N, k] of outputs ``names`` from the fitted s,
    f and kappa of the ``held`` ones (a name not held: the filter's sigma)."""
    s = _by_name(held, std, names, 0.0)
    f = _by_name(held, scale, names, 1.0)
    k = _by_name(held, kappa, names, 0.0)
    return np.sqrt(np.square(f * np.asarray(filter_std, float)) + np.square(s)
                   + np.square(k * np.asarray(d, float)[..., None]))


def _rows(held: Sequence[str], C: np.ndarray | None,
          names: Sequence[str]) -> np.ndarray | None:
    """The rows [k, w] of a correction C of the outputs ``held`` for the outputs ``names``
    (zeros for one not held); None without a correction."""
    if C is None:
        return None
    where = {n: k for k, n in enumerate(held)}
    out = np.zeros((len(names), C.shape[1]))
    for j, name in enumerate(names):
        if name in where:
            out[j] = C[where[name]]
    return out


def _corrected(held: Sequence[str], C: np.ndarray | None) -> list[str]:
    """The outputs of ``held`` whose row of the correction C is not zero."""
    if C is None:
        return []
    return [name for name, row in zip(held, C, strict=True) if np.any(row != 0.0)]


def _held_value(held: Sequence[str], values: np.ndarray | None, name: str) -> float | None:
    """The value of ``name`` among ``held``; None when not held or not finite."""
    if name not in held:
        return None
    value = float(np.asarray(values)[held.index(name)])
    return value if np.isfinite(value) else None


def _by_name(held: Sequence[str], values: np.ndarray | None, names: Sequence[str],
             missing: float) -> np.ndarray:
    """[len(names)] the values of ``held`` names in the order of ``names``; ``missing`` for a
    name not held or a value not finite."""
    v = np.asarray(values, float)
    out = np.array([v[held.index(n)] if n in held else missing for n in names], float)
    return np.where(np.isfinite(out), out, missing)


def _on_regressors(C: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Rows of a correction C [r, correction_width(p)] on the regressors of p health
    parameters, taken onto those of the q parameters whose index among the p is ``index``
    [q] (-1: not held, no regressor): the constant, one column per name, one per pair of
    names (``correction_design``)."""
    q = len(index)
    out = np.zeros((C.shape[0], correction_width(q)))
    if not C.size:
        return out
    column = _correction_columns(correction_p(C.shape[1]))
    new_column = _correction_columns(q)
    held = np.flatnonzero(index >= 0)
    out[:, 0] = C[:, 0]
    for j in held:
        out[:, 1 + j] = C[:, 1 + index[j]]
        for i in held[held <= j]:
            out[:, new_column[i, j]] = C[:, column[index[i], index[j]]]
    return out


def correction_p(width: int) -> int:
    """The number of parameters p whose correction has ``width`` = 1 + p + p (p + 1) / 2
    columns (``correction_width``)."""
    p = int(round((-3.0 + np.sqrt(9.0 + 8.0 * (width - 1))) / 2.0))
    if correction_width(p) != width:
        raise DimensionError(f"no number of parameters has a correction {width} wide")
    return p


def _correction_columns(p: int) -> np.ndarray:
    """[p, p] int: the column of the product h_i h_j in ``correction_design`` (symmetric)."""
    out = np.zeros((p, p), int)
    i, j = pairs(p)
    out[i, j] = out[j, i] = 1 + p + np.arange(i.size)
    return out


def level_sigma(
    filter_std: np.ndarray, bias2: np.ndarray, model_std: np.ndarray
) -> np.ndarray:
    """Honest 1-sigma of h_hat [..., p]: sqrt(bias2 + filter variance + s^2) (module)."""
    return np.sqrt(np.asarray(bias2) + np.square(filter_std) + np.square(model_std))


def change_sigma(
    filter_std: np.ndarray, filter_std0: np.ndarray, kcycles: np.ndarray,
    drift: np.ndarray, change_std: np.ndarray,
) -> np.ndarray:
    """1-sigma of h_hat(t) - h_hat(0) [..., p] (module docstring).

    filter_std [..., p] at t, filter_std0 [..., p] at the baseline; kcycles [...]: thousand
    cycles since the baseline; drift d [p]; change_std s_delta [p].
    """
    c = np.asarray(kcycles, float)[..., None]
    return np.sqrt(np.square(filter_std) + np.square(filter_std0)
                   + np.square(np.asarray(drift) * c) + np.square(change_std))


def coverage(err: np.ndarray, sigma: np.ndarray, k: float = 1.0) -> np.ndarray:
    """Fraction of rows with |err| <= k sigma, per column [p] (NaN rows ignored)."""
    ok = np.isfinite(err) & np.isfinite(sigma)
    inside = (np.abs(err) <= k * sigma) & ok
    return inside.sum(axis=0) / np.maximum(ok.sum(axis=0), 1)


def fit_model_std(
    err: np.ndarray, base_var: np.ndarray,
    one_sigma: float = ONE_SIGMA_TARGET, two_sigma: float = TWO_SIGMA_TARGET,
) -> np.ndarray:
    """The model-error std s [p] that makes sqrt(base_var + s^2) an honest 1-sigma.

    err [N, p]: h_hat - h on the calibration records; base_var [N, p]: the analytic and
    filter variance of each record. Per column, the smallest s with at least ``one_sigma`` of
    the records inside 1-sigma and ``two_sigma`` inside 2-sigma; 0 when the base variance
    covers already.
    """
    err = np.asarray(err, float)
    base_var = np.broadcast_to(np.asarray(base_var, float), err.shape)
    if err.ndim != 2:
        raise DimensionError(f"err must be [N, p], found shape {err.shape}")
    # Record i is inside width * sigma exactly when s >= s_i = sqrt(max(0, (e_i / width)^2
    # - v_i)); the coverage of s is the fraction of s_i <= s, so the smallest s reaching a
    # level is an order statistic of the s_i.
    out = np.zeros(err.shape[1])
    for k in range(err.shape[1]):
        ok = np.isfinite(err[:, k]) & np.isfinite(base_var[:, k])
        e, v = np.abs(err[ok, k]), base_var[ok, k]
        if e.size == 0:
            out[k] = np.nan
            continue
        need = 0.0
        for level, width in ((one_sigma, 1.0), (two_sigma, 2.0)):
            s_i = np.sort(np.sqrt(np.maximum((e / width) ** 2 - v, 0.0)))
            rank = min(e.size - 1, max(0, int(np.ceil(level * e.size)) - 1))
            need = max(need, float(s_i[rank]))
        out[k] = need
    return out


def fit_bias_scale(
    err: np.ndarray, bias2: np.ndarray, filter_var: np.ndarray, one_sigma: float = ONE_SIGMA_TARGET,
) -> np.ndarray:
    """Scale a [p] in (0, 1] of the analytic bias^2 where it alone over-covers.

    The analytic bias^2 is a fleet average under the prior; where bias2 + filter variance
    already holds more than ``one_sigma`` of the calibration errors err [N, p], the smallest
    a with a^2 bias2 + filter_var holding ``one_sigma`` of them (an order statistic of
    (e_i^2 - v_i) / bias2, as in ``fit_model_std``); 1 elsewhere.
    """
    err = np.asarray(err, float)
    var = np.broadcast_to(np.asarray(filter_var, float), err.shape)
    b = np.asarray(bias2, float)
    out = np.ones(err.shape[1])
    for k in range(err.shape[1]):
        ok = np.isfinite(err[:, k]) & np.isfinite(var[:, k])
        e, v = err[ok, k], var[ok, k]
        if e.size == 0 or b[k] <= 0.0:
            continue
        a2 = np.sort(np.maximum(e**2 - v, 0.0) / b[k])
        rank = min(e.size - 1, max(0, int(np.ceil(one_sigma * e.size)) - 1))
        out[k] = min(1.0, float(np.sqrt(a2[rank])))
    return out


def observable(
    prior_var: np.ndarray, bias2: np.ndarray, filter_var: np.ndarray, model_std: np.ndarray,
    slope_error: np.ndarray | None = None, reduction: float = 0.5,
    slope_tolerance: float = 0.3,
) -> np.ndarray:
    """Which parameters to show [p] bool (module docstring).

    prior_var [p]: diag(P_h); bias2, filter_var (steady state), model_std [p]. A parameter is
    observable when sqrt(bias2 + filter_var + s^2) <= reduction * sqrt(prior_var) (the design
    knows it at least 1/reduction times better than the fleet prior) and, given slope_error
    (relative error of the fleet-average slope), |slope_error| <= slope_tolerance.
    """
    sigma = np.sqrt(np.asarray(bias2) + np.asarray(filter_var) + np.square(model_std))
    ok = sigma <= reduction * np.sqrt(np.asarray(prior_var, float))
    if slope_error is not None:
        r = np.asarray(slope_error, float)
        ok &= ~(np.isfinite(r) & (np.abs(r) > slope_tolerance))
    return np.asarray(ok, bool)


def piece_slope(x: np.ndarray, y: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """Weighted least-squares slope [p] of y [S, p] on x [S] (weights w [S], None: 1)."""
    x = np.asarray(x, float)
    w = np.ones_like(x) if w is None else np.asarray(w, float)
    xc = x - (w @ x) / w.sum()
    return ((w * xc) @ np.asarray(y, float)) / ((w * xc) @ xc)


def fleet_slope(
    slopes: np.ndarray, spans: np.ndarray, gain: np.ndarray | None = None,
    noise: np.ndarray | None = None, common: np.ndarray | None = None,
    gain_std: np.ndarray | None = None, correction: np.ndarray | None = None,
    scale: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Fleet-average slope [p] and its 1-sigma [p] from the pieces' slopes [S, p] over spans
    [S] (module docstring): the pieces' slopes corrected by A [p, p] (``correct_slopes``;
    None: as estimated), their mean weighted by T_e^2, divided by the gain g [p] (None: 1);
    sigma lambda sqrt((a / sum T_e^2 + c) / g^2 + (slope u / g)^2) for the noise a [p] (None:
    NaN), the error common to a fleet's pieces c [p] (None: 0), the gain's standard error u
    [p] (None: 0, an exact gain; NaN: unknown, NaN sigma) and the sigma's scale lambda [p]
    (None: 1). No piece: NaN."""
    slopes = np.asarray(slopes, float)
    if correction is not None:
        slopes = correct_slopes(slopes, correction)
    w = np.square(np.asarray(spans, float))
    p = slopes.shape[1] if slopes.ndim == 2 else 0
    g = np.ones(p) if gain is None else np.asarray(gain, float)
    a = np.full(p, np.nan) if noise is None else np.asarray(noise, float)
    c = np.zeros(p) if common is None else np.asarray(common, float)
    u = np.zeros(p) if gain_std is None else np.asarray(gain_std, float)
    lam = np.ones(p) if scale is None else np.asarray(scale, float)
    if not w.size or w.sum() <= 0.0:
        return np.full(p, np.nan), np.full(p, np.nan)
    slope = (w @ slopes) / w.sum() / g
    return slope, lam * np.sqrt((a / w.sum() + c) / g**2 + np.square(slope * u / g))


def correct_slopes(slopes: np.ndarray, correction: np.ndarray) -> np.ndarray:
    """The corrected slopes [S, p] of estimated slopes [S, p]: b - b A^T for the slope
    correction A [p, p] (``fit_slope_correction``; a row of zeros leaves its parameter as
    estimated)."""
    slopes = np.asarray(slopes, float)
    return slopes - slopes @ np.asarray(correction, float).T


# The corrections' least squares (of the slopes, of the level on its regressors scaled to unit
# mean square) leave out the directions below this fraction of the largest singular value:
# an SVD design's m tuners span all its estimates, and beyond them the regressors hold only
# rounding (1e-8 of the largest on svd:6; the estimates are kept as float32), whose fit gave
# coefficients of 1e5-1e8 (bench_uncertainty), which multiply rounding that differs between
# the calibration and the stored estimates.
CORRECTION_RCOND = 1e-6


def fit_slope_correction(fleets: Sequence[TrendPieces]) -> np.ndarray:
    """The slope correction A [p, p] over the pooled pieces of ``fleets`` (module docstring,
    "Slope correction"): row k the least-squares fit of the pieces' errors b_e,k - b_true,e,k
    on their estimated slopes b_e, each piece's row weighted by T_e^2, its weight in its
    fleet's slope (so its squared residual by T_e^4), the least-norm one over the directions
    the slopes span (``CORRECTION_RCOND``); zeros without pieces."""
    pooled = TrendPieces.pooled(fleets)
    p = pooled.hat.shape[1]
    w = np.square(pooled.spans)
    ok = (np.all(np.isfinite(pooled.hat), axis=1) & np.all(np.isfinite(pooled.true), axis=1)
          & (w > 0.0))
    if ok.sum() < p:
        return np.zeros((p, p))
    X = w[ok, None] * pooled.hat[ok]
    Y = w[ok, None] * (pooled.hat[ok] - pooled.true[ok])
    return np.asarray(np.linalg.lstsq(X, Y, rcond=CORRECTION_RCOND)[0].T)


def fit_slope_gain(hat: np.ndarray, true: np.ndarray, spans: np.ndarray,
                   floor: float = 0.0) -> np.ndarray:
    """Gain g [p] of the fleet-average slope: the T_e^2-weighted mean of the estimated piece
    slopes hat [S, p] over that of the true ones true [S, p] (pooled over the calibration
    fleets); NaN where the true mean is within ``floor`` of 0 or the ratio is not positive
    (no trend to measure a gain on, or the design reads it backwards)."""
    hat_mean, _ = fleet_slope(hat, spans)
    true_mean, _ = fleet_slope(true, spans)
    with np.errstate(invalid="ignore", divide="ignore"):
        g = hat_mean / true_mean
    return np.where((np.abs(true_mean) > floor) & (g > 0.0), g, np.nan)


def fit_slope_noise(hat: np.ndarray, true: np.ndarray, spans: np.ndarray,
                    gain: np.ndarray) -> np.ndarray:
    """Noise a [p] of a piece's slope, var(b_e / g - b_true,e) = a / T_e^2: the mean of
    (T_e (b_e / g - b_true,e))^2 over the pieces (NaN without pieces)."""
    spans = np.asarray(spans, float)
    if not spans.size:
        return np.full(np.asarray(hat).shape[1], np.nan)
    err = np.asarray(hat, float) / np.asarray(gain, float) - np.asarray(true, float)
    return np.mean(np.square(spans[:, None] * err), axis=0)



@dataclass(frozen=True)
class TrendPieces:
    """The pieces of one fleet's trends (``period_pieces``): per piece the slope of the
    estimate and of the true health [S, p] (percent per year) and its span [S] (years)."""

    hat: np.ndarray
    true: np.ndarray
    spans: np.ndarray

    def fleet(self, gain: np.ndarray | None = None, noise: np.ndarray | None = None,
              common: np.ndarray | None = None, gain_std: np.ndarray | None = None,
              correction: np.ndarray | None = None, scale: np.ndarray | None = None,
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(estimated slope, its 1-sigma, true slope) [p] over the fleet (``fleet_slope``)."""
        slope, sigma = fleet_slope(self.hat, self.spans, gain, noise, common, gain_std,
                                   correction, scale)
        return slope, sigma, fleet_slope(self.true, self.spans)[0]

    def corrected(self, correction: np.ndarray) -> TrendPieces:
        """The pieces with their estimated slopes corrected by A (``correct_slopes``)."""
        return TrendPieces(correct_slopes(self.hat, correction), self.true, self.spans)

    @staticmethod
    def pooled(fleets: Sequence[TrendPieces]) -> TrendPieces:
        """The pieces of several fleets as one."""
        return TrendPieces(np.concatenate([f.hat for f in fleets]),
                           np.concatenate([f.true for f in fleets]),
                           np.concatenate([f.spans for f in fleets]))


@dataclass(frozen=True)
class SlopeFit:
    """The fleet-average slope's calibration [p] each (``fit_fleet_slope``)."""

    gain: np.ndarray  # g (NaN: the slope is unobservable)
    gain_std: np.ndarray  # u, the gain's jackknife standard error
    noise: np.ndarray  # a
    common: np.ndarray  # c
    error: np.ndarray  # pooled relative error of the uncorrected slope
    sigma: np.ndarray  # its relative 1-sigma over the pooled pieces
    cross: np.ndarray  # RMS relative error of a fleet's corrected slope (cross-validated)
    correction: np.ndarray | None = None  # A [p, p] (None: the slopes as estimated)
    scale: np.ndarray | None = None  # lambda of the 1-sigma (None: 1)


# A fleet slope is shown when its cross-validated RMS relative error is within this share of
# the slope tolerance: a fleet then misses the tolerance only beyond 1.5 times that RMS
# (bench_uncertainty: at the whole tolerance, lpc_flow's RMS 0.29 of a gain of 1.76 left 38 %
# of the scoring fleets beyond 30 %).
CROSS_SHARE = 2.0 / 3.0


# The slope's 1-sigma scale lambda (``fit_slope_scale``) holds this share of the calibration
# fleets' cross-validated slopes within 1-sigma and this share within 2-sigma (the middle of
# the required 55-85 % and above 85 %, with room for the spread of a dozen fleets).
SLOPE_ONE_SIGMA = 0.70
SLOPE_TWO_SIGMA = 0.95


def fit_fleet_slope(fleets: Sequence[TrendPieces], floor: float = 0.0,
                    tolerance: float = 0.3, correct: bool = False,
                    one_sigma: float = SLOPE_ONE_SIGMA,
                    two_sigma: float = SLOPE_TWO_SIGMA) -> SlopeFit:
    """The fleet-average slope's calibration over the K ``fleets`` (module docstring).

    Without ``correct``: the slopes as estimated, ``fit_slope_gains``. With it (the product's
    calibration): the slope correction A over all fleets (``fit_slope_correction``), each
    fleet's pieces corrected by the A of the other fleets (so that its gain, noise, common
    error and cross-validated error are the correction's out of sample) and
    ``fit_slope_gains`` on them; a slope is shown (finite gain) where it passes that rule both
    corrected and as estimated (the correction sharpens a trend the design reads, it does
    not make one of the other parameters' slopes: fan_flow's, made so, missed 30 % on 6 of
    48 scoring fleets, bench_uncertainty), and its 1-sigma carries the scale lambda of
    ``fit_slope_scale``. Fewer than two fleets: nothing to cross-validate, no slope.
    """
    plain = fit_slope_gains(fleets, floor, tolerance)
    if not correct or len(fleets) < 2:
        return plain
    fit = _corrected_fit(fleets, floor, tolerance, plain)
    return replace(fit, scale=fit_slope_scale(fleets, fit, floor, tolerance, one_sigma,
                                              two_sigma))


def _corrected_fit(fleets: Sequence[TrendPieces], floor: float, tolerance: float,
                   plain: SlopeFit | None = None) -> SlopeFit:
    """``fit_fleet_slope`` with ``correct`` before its 1-sigma scale (``plain``: the fit of
    the slopes as estimated, made here when not given)."""
    plain = fit_slope_gains(fleets, floor, tolerance) if plain is None else plain
    others = [[o for k, o in enumerate(fleets) if k != j] for j in range(len(fleets))]
    corrected = [f.corrected(fit_slope_correction(o)) for f, o in zip(fleets, others,
                                                                       strict=True)]
    fit = fit_slope_gains(corrected, floor, tolerance)
    return replace(fit, gain=np.where(np.isfinite(plain.gain), fit.gain, np.nan),
                   error=plain.error, sigma=plain.sigma,
                   correction=fit_slope_correction(fleets))


def fit_slope_scale(fleets: Sequence[TrendPieces], fit: SlopeFit, floor: float = 0.0,
                    tolerance: float = 0.3, one_sigma: float = SLOPE_ONE_SIGMA,
                    two_sigma: float = SLOPE_TWO_SIGMA) -> np.ndarray:
    """The 1-sigma's scale lambda [p] of the corrected slope (module docstring, "Slope
    correction"): each fleet j's slope and 1-sigma from the corrected calibration of the other
    fleets (``fit_fleet_slope`` with ``correct``, its own left-out corrections nested inside),
    z_j = |slope - true| / sigma over the slopes ``fit`` shows, pooled; lambda the smallest
    scale holding ``one_sigma`` of them within lambda sigma and ``two_sigma`` within 2 lambda
    sigma (order statistics, as ``fit_model_std``), the same for every parameter (a dozen
    fleets per parameter are too few for one each); 1 where nothing is shown or fewer than
    three fleets."""
    p = np.asarray(fit.noise).shape[0]
    shown = np.isfinite(fit.gain)
    if len(fleets) < 3 or not shown.any():
        return np.ones(p)
    z = []
    for j, f in enumerate(fleets):
        sub = _corrected_fit([o for k, o in enumerate(fleets) if k != j], floor, tolerance)
        slope, sigma, true = f.fleet(sub.gain, sub.noise, sub.common, sub.gain_std,
                                     sub.correction)
        ok = shown & np.isfinite(slope) & np.isfinite(sigma) & (sigma > 0.0)
        z.append(np.abs(slope - true)[ok] / sigma[ok])
    z_all = np.sort(np.concatenate(z))
    if not z_all.size:
        return np.ones(p)
    lam = 0.0
    for level, width in ((one_sigma, 1.0), (two_sigma, 2.0)):
        rank = min(z_all.size - 1, max(0, int(np.ceil(level * z_all.size)) - 1))
        lam = max(lam, float(z_all[rank]) / width)
    return np.full(p, lam)


def fit_slope_gains(fleets: Sequence[TrendPieces], floor: float = 0.0,
                    tolerance: float = 0.3) -> SlopeFit:
    """The fleet-average slope's gain and noise over the pooled pieces of the K ``fleets``
    (module docstring): the gain g and the noise a (``fit_slope_gain``, ``fit_slope_noise``);
    for each fleet j the gain g_(-j) of the other fleets, with which its corrected slope is
    cross-validated: the common error c is the mean of its squared error beyond its piece
    noise (clipped at 0), u the jackknife standard error of the gain over the g_(-j), and
    ``cross`` the RMS relative error (relative to max(|true|, ``floor``)). Also the pooled
    uncorrected slope's relative error and 1-sigma. The gain is NaN (the slope unobservable)
    where that 1-sigma is over half of ``tolerance`` (the calibration fleets cannot tell the
    trend from its noise), where the cross-validated RMS error is over ``tolerance`` (the
    level's rule for its slope, here for a fleet's corrected slope on a fleet the gain did not
    see; over ``CROSS_SHARE`` of it, since an RMS error at the tolerance leaves about a
    third of the fleets beyond it), or with fewer than two fleets (nothing to
    cross-validate)."""
    pooled = TrendPieces.pooled(fleets)
    gain = fit_slope_gain(pooled.hat, pooled.true, pooled.spans, floor)
    noise = fit_slope_noise(pooled.hat, pooled.true, pooled.spans, np.nan_to_num(gain, nan=1.0))
    raw, raw_sigma, true = pooled.fleet(None, noise)
    scale = np.maximum(np.abs(true), floor)
    excess, relative, left_out = [], [], []
    for j, f in enumerate(fleets):
        if not len(f.spans) or len(fleets) < 2:
            continue
        others = TrendPieces.pooled([o for k, o in enumerate(fleets) if k != j])
        g = fit_slope_gain(others.hat, others.true, others.spans, floor)
        slope, _, true_f = f.fleet(np.where(np.isfinite(g), g, 1.0))
        excess.append((slope - true_f) ** 2 - noise / np.sum(f.spans**2))
        relative.append((slope - true_f) / np.maximum(np.abs(true_f), floor))
        left_out.append(g)
    p = noise.shape[0]
    if len(left_out) < 2:
        nan = np.full(p, np.nan)
        return SlopeFit(nan, nan, noise, np.zeros(p), (raw - true) / scale, raw_sigma / scale,
                        nan)
    common = np.maximum(np.mean(excess, axis=0), 0.0)
    cross = np.sqrt(np.mean(np.square(relative), axis=0))
    k = len(left_out)
    gain_std = np.sqrt((k - 1) / k * np.sum(np.square(left_out - np.mean(left_out, axis=0)),
                                             axis=0))
    sigma = raw_sigma / scale
    # NaN sigma or cross-validation error: NaN gain.
    gain = np.where((sigma <= 0.5 * tolerance) & (cross <= CROSS_SHARE * tolerance), gain,
                    np.nan)
    return SlopeFit(gain, gain_std, noise, common, (raw - true) / scale, sigma, cross)


YEAR_S = 365.25 * 86400.0


def period_pieces(
    start: np.ndarray, end: np.ndarray, n: np.ndarray, means: np.ndarray, resets: np.ndarray,
    settle: int, min_span: float,
) -> tuple[np.ndarray, np.ndarray]:
    """One engine's trend pieces from its period means: slopes [S, q] (per year) and spans [S]
    (years).

    start, end [K] (epoch seconds, time order), n [K] records and means [K, q] of each period;
    resets [R] epoch seconds of the baseline resets. A period holding a reset mixes two pieces
    and is left out; a piece starts ``settle`` records after its first record (the filter's
    start-up transient) and counts when its periods span at least ``min_span`` years. Each
    period sits at its middle, weighted by its records.
    """
    start, end = np.asarray(start, float), np.asarray(end, float)
    n = np.asarray(n, float)
    means = np.asarray(means, float)
    resets = np.sort(np.asarray(resets, float))
    piece = np.searchsorted(resets, start, side="right")
    mixed = piece != np.searchsorted(resets, end, side="left")
    slopes, spans = [], []
    for k in np.unique(piece):
        sel = np.flatnonzero((piece == k) & ~mixed)
        before = np.cumsum(n[sel]) - n[sel]  # records of the piece before each period
        sel = sel[before >= settle]
        if sel.size < 3:
            continue
        x = 0.5 * (start[sel] + end[sel]) / YEAR_S
        span = float(x.max() - x.min())
        if span < min_span:
            continue
        slopes.append(piece_slope(x, means[sel], n[sel]))
        spans.append(span)
    q = means.shape[1] if means.ndim == 2 else 0
    return np.reshape(slopes, (len(slopes), q)), np.asarray(spans, float)


# The level's correction (module docstring, "Calibrated level"): a parameter is corrected when
# the correction cuts its error, cross-validated over the calibration fleets, by at least this
# fraction of its RMS (below, it mostly refits noise).
MIN_CORRECTION_GAIN = 0.2
# A corrected parameter's correction is curved (on the estimates' products too) where that
# cuts the straight correction's cross-validated RMS error by at least this fraction.
MIN_CURVE_GAIN = 0.05
# Grid of the spread kappa (``fit_model_spread``): 0 to 0.6 in steps of 0.005.
SPREAD_GRID = np.arange(0.0, 0.6 + 1e-9, 0.005)


def correction_width(p: int) -> int:
    """Columns of the level's correction of p parameters: the constant, the p estimates and
    their p (p + 1) / 2 products (``correction_design``)."""
    return 1 + p + p * (p + 1) // 2


def correction_design(h_hat: np.ndarray, curved: bool = True) -> np.ndarray:
    """[N, 1 + p + p (p + 1) / 2]: the regressors of the level's correction, a column of ones,
    the estimates h_hat [N, p] and, ``curved``, their products h_i h_j (``pair_products``);
    [N, 1 + p] without the products."""
    h_hat = np.asarray(h_hat, float)
    columns = [np.ones(h_hat.shape[:-1] + (1,)), h_hat]
    if curved:
        columns.append(pair_products(h_hat))
    return np.concatenate(columns, axis=-1)


@functools.cache
def pairs(p: int) -> tuple[np.ndarray, np.ndarray]:
    """(i, j) of the p (p + 1) / 2 pairs i <= j of p parameters, ``np.triu_indices`` order,
    made once per p."""
    return np.triu_indices(p)


def pair_products(h: np.ndarray) -> np.ndarray:
    """[..., p (p + 1) / 2]: the products h_i h_j (i <= j, ``pairs`` order) of h [..., p]."""
    h = np.asarray(h, float)
    i, j = pairs(h.shape[-1])
    return h[..., i] * h[..., j]


def correct_level(h_hat: np.ndarray, correction: np.ndarray) -> np.ndarray:
    """The calibrated level [N, p]: h_hat - X C^T for the correction C [p, w] on the
    regressors X of ``correction_design`` (w = 1 + p: the straight part alone); a row of
    zeros leaves its parameter as estimated."""
    return correct_outputs(h_hat, h_hat, correction)


def correct_outputs(values: np.ndarray, h_hat: np.ndarray, correction: np.ndarray) -> np.ndarray:
    """values [N, q] - X C^T: estimates corrected by C [q, w] on the regressors X of
    ``correction_design`` of the health estimates h_hat [N, p] (the level's, and the aux
    outputs' in the engine's units' percent); a row of zeros leaves its value as estimated."""
    h_hat = np.asarray(h_hat, float)
    correction = np.asarray(correction, float)
    p = h_hat.shape[-1]
    if correction.shape[-1] > 1 + p and not np.any(correction[:, 1 + p:]):
        correction = correction[:, :1 + p]  # no row curved: the products are not formed
    return (np.asarray(values, float)
            - correction_design(h_hat, correction.shape[-1] > 1 + p) @ correction.T)


def fleet_outputs(
    values: np.ndarray, squares: np.ndarray, cross: np.ndarray | None, mean: np.ndarray,
    products: np.ndarray, correction: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """The mean and spread over engines [T, k] of the calibrated outputs (the aux outputs,
    ``Calibration.aux_level``) of engines whose outputs average values [T, k] with squares
    averaging squares [T, k] and products with their health estimates averaging cross
    [T, k, p] (None: not kept), and whose health estimates average mean [T, p] with products
    averaging products [T, p (p + 1) / 2]; correction C [k, w] (``Calibration.aux_rows``;
    None: none). The mean is exact (the correction is linear in the regressors); the spread
    carries the engines' covariance of outputs and health through the correction's Jacobian at
    the mean, as ``fleet_level``'s (exact for a straight correction). Without a correction, or
    without the cross moments, the outputs' own mean and standard deviation."""
    values = np.asarray(values, float)
    spread = np.sqrt(np.maximum(np.asarray(squares, float) - values**2, 0.0))
    if correction is None:
        return values.copy(), spread
    C = np.asarray(correction, float)
    regressors = np.concatenate([np.ones(values.shape[:-1] + (1,)), mean, products], axis=-1)
    level = values - regressors[..., : C.shape[1]] @ C.T
    if cross is None:
        return level, spread
    jacobian = _correction_jacobian(C, mean)  # [T, k, p]
    cov_h = _covariance(mean, products)
    cov_zh = np.asarray(cross, float) - values[..., :, None] * mean[..., None, :]
    variance = (spread**2 - 2.0 * np.einsum("...kl,...kl->...k", jacobian, cov_zh)
                + np.einsum("...kl,...lm,...km->...k", jacobian, cov_h, jacobian))
    return level, np.sqrt(np.maximum(variance, 0.0))


def _covariance(mean: np.ndarray, products: np.ndarray) -> np.ndarray:
    """[..., p, p]: the covariance of values whose mean is mean [..., p] and whose products
    (i <= j, ``pairs`` order) average products [..., p (p + 1) / 2]."""
    p = mean.shape[-1]
    second = np.zeros(mean.shape[:-1] + (p, p))
    i, j = pairs(p)
    second[..., i, j] = products
    second[..., j, i] = products
    return second - mean[..., :, None] * mean[..., None, :]


def _correction_jacobian(C: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """d (x(h) C^T) / d h [..., r, p] of a correction C [r, w] on the regressors of
    ``correction_design`` at the health estimates mean [..., p]."""
    p = mean.shape[-1]
    jacobian = np.broadcast_to(C[:, 1 : 1 + p], mean.shape[:-1] + (C.shape[0], p)).copy()
    if C.shape[-1] > 1 + p:
        i, j = pairs(p)
        curved = C[:, 1 + p :]  # [r, pairs]
        for k, (a, b) in enumerate(zip(i, j, strict=True)):
            jacobian[..., :, a] += curved[:, k] * mean[..., b, None]
            jacobian[..., :, b] += curved[:, k] * mean[..., a, None]
    return jacobian


def fleet_level(
    mean: np.ndarray, products: np.ndarray, correction: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The mean and spread over engines [T, p] of the calibrated level of engines whose
    estimates average mean [T, p] with the products of their estimates averaging products [T,
    p (p + 1) / 2] (``pair_products``), for the correction C [p, w]
    (``correct_level``). The mean is exact for each engine's level taken at its own mean
    estimates (the correction is linear in the regressors of ``correction_design``); the
    spread is the engines' covariance carried through the correction's Jacobian at the mean
    (exact for a straight correction). With C = 0: the estimates' mean and standard deviation.
    """
    mean = np.asarray(mean, float)
    products = np.asarray(products, float)
    C = np.asarray(correction, float)
    p = mean.shape[-1]
    regressors = np.concatenate([np.ones(mean.shape[:-1] + (1,)), mean, products], axis=-1)
    level = mean - regressors[..., : C.shape[-1]] @ C.T
    covariance = _covariance(mean, products)
    # d level / d h = I - d (x(h) C^T) / d h at the mean.
    jacobian = np.eye(p) - _correction_jacobian(C, mean)
    variance = np.einsum("...kl,...lm,...km->...k", jacobian, covariance, jacobian)
    return level, np.sqrt(np.maximum(variance, 0.0))


def correct_change(h_hat: np.ndarray, h_hat0: np.ndarray, correction: np.ndarray) -> np.ndarray:
    """The calibrated change [N, p] of the estimates h_hat [N, p] since the baseline's
    h_hat0 [p] or [N, p]: the calibrated level at both ends, differenced (its constant
    cancels)."""
    return (correct_level(h_hat, correction)
            - correct_level(np.broadcast_to(h_hat0, np.shape(h_hat)), correction))


def spread(h_hat: np.ndarray) -> np.ndarray:
    """The record's distance from the nominal engine d [N]: the RMS of its estimated health
    deviations (percent), on which the model error grows (``fit_model_spread``)."""
    return np.sqrt(np.mean(np.square(np.asarray(h_hat, float)), axis=-1))


@dataclass(frozen=True)
class LevelCorrection:
    """The level's correction (``fit_level_correction``): C [p, w] over all calibration
    fleets (w = ``correction_width``), and for each fleet of ``groups`` the C fitted without
    it ([G, p, w], the rows not kept zero as in C): a calibration record corrected by its
    fleet's left-out C carries the correction's error on a fleet it did not see, which is
    what its sigma is fitted on. curved [p]: the rows that use the estimates' products."""

    matrix: np.ndarray
    groups: np.ndarray
    left_out: np.ndarray
    curved: np.ndarray

    def without(self, group: object) -> np.ndarray:
        """The C fitted without the fleet ``group`` (C itself for a fleet not in groups)."""
        hit = np.flatnonzero(self.groups == group)
        return self.left_out[hit[0]] if hit.size else self.matrix


def fit_level_correction(
    h_hat: np.ndarray, err: np.ndarray, fleet: np.ndarray,
    min_gain: float = MIN_CORRECTION_GAIN, min_curve_gain: float = MIN_CURVE_GAIN,
    min_fleets: int = 2,
) -> LevelCorrection:
    """The level's correction (module docstring, "Calibrated level").

    h_hat [N, p] and err = h_hat - h [N, p] (or the errors of q other outputs [N, q], the aux
    outputs', corrected on the same regressors) on the calibration records, fleet [N] the
    calibration fleet of each. Row k of C is the least-squares fit of err_k on the
    regressors of ``correction_design`` over all fleets (the least-norm one over the
    directions they span, ``CORRECTION_RCOND``): on [1, h_hat] (straight), or also on
    the estimates' products (curved) where that, fitted on the other fleets and scored on the
    one left out, cuts the straight fit's RMS error by at least ``min_curve_gain``. A row is
    kept where its fit so cross-validated cuts the RMS error by at least ``min_gain`` (pooled
    over the left-out fleets); zeros elsewhere, and everywhere with fewer than two fleets
    (nothing to cross-validate) or than ``min_fleets`` (too few for the cross-validation to
    vouch for its coefficients).
    """
    err = np.asarray(err, float)
    fleet = np.asarray(fleet)
    q = err.shape[1]  # the outputs corrected: the level's p, or the aux outputs
    p = np.shape(h_hat)[1]
    width = correction_width(p)
    X = correction_design(h_hat)
    groups = np.unique(fleet)
    ok = np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(err), axis=1)
    if len(groups) < max(2, min_fleets) or not ok.any():
        return LevelCorrection(np.zeros((q, width)), groups, np.zeros((len(groups), q, width)),
                               np.zeros(q, bool))

    # The regressors at unit mean square, so that the least squares' cut of the directions the
    # estimates do not span (``CORRECTION_RCOND``) weighs estimates and products alike.
    scale = np.sqrt(np.mean(np.square(X[ok]), axis=0))
    scale[scale == 0.0] = 1.0
    Z = X / scale

    def fitted(rows: np.ndarray, columns: int) -> np.ndarray:  # [q, width], zero padded
        out = np.zeros((q, width))
        W = np.linalg.lstsq(Z[rows, :columns], err[rows], rcond=CORRECTION_RCOND)[0]
        out[:, :columns] = (W / scale[:columns, None]).T
        return out

    left_out = {w: np.zeros((len(groups), q, width)) for w in (1 + p, width)}
    rms = {}
    for w, outs in left_out.items():
        residual = err.copy()
        for i, g in enumerate(groups):
            test = (fleet == g) & ok
            outs[i] = fitted(ok & (fleet != g), w)
            residual[test] = err[test] - X[test] @ outs[i].T
        rms[w] = np.sqrt(np.mean(np.square(residual[ok]), axis=0))
    curved = rms[width] <= (1.0 - min_curve_gain) * rms[1 + p]
    after = np.where(curved, rms[width], rms[1 + p])
    keep = after <= (1.0 - min_gain) * np.sqrt(np.mean(np.square(err[ok]), axis=0))
    matrix = np.where(curved[:, None], fitted(ok, width), fitted(ok, 1 + p))
    left = np.where(curved[None, :, None], left_out[width], left_out[1 + p])
    return LevelCorrection(np.where(keep[:, None], matrix, 0.0), groups,
                           np.where(keep[None, :, None], left, 0.0), curved & keep)


def fit_model_spread(
    err: np.ndarray, base_var: np.ndarray, d: np.ndarray,
    one_sigma: float = ONE_SIGMA_TARGET, two_sigma: float = TWO_SIGMA_TARGET,
    grid: np.ndarray = SPREAD_GRID,
) -> tuple[np.ndarray, np.ndarray]:
    """The model error's constant s [p] and spread kappa [p]: sqrt(base_var + s^2 + (kappa
    d)^2) an honest 1-sigma whose size follows the record's distance d [N] from the nominal
    engine (``spread``).

    For each kappa of ``grid``, s is ``fit_model_std``'s (the smallest holding ``one_sigma``
    and ``two_sigma`` of the records); of those, the pair holding the fewest records inside
    1-sigma (the tightest sigma that meets both levels, the closest to the errors' shape).
    kappa = 0 is ``fit_model_std`` alone.
    """
    err = np.asarray(err, float)
    base_var = np.broadcast_to(np.asarray(base_var, float), err.shape)
    d2 = np.square(np.asarray(d, float))[:, None]
    best_cover = np.full(err.shape[1], np.inf)
    s_out = np.zeros(err.shape[1])
    kappa_out = np.zeros(err.shape[1])
    for kappa in grid:
        var = base_var + kappa**2 * d2
        s = fit_model_std(err, var, one_sigma, two_sigma)
        cover = coverage(err, np.sqrt(var + np.square(np.nan_to_num(s))), 1.0)
        better = cover < best_cover - 1e-12
        best_cover = np.where(better, cover, best_cover)
        s_out = np.where(better, s, s_out)
        kappa_out = np.where(better, kappa, kappa_out)
    return s_out, kappa_out


def fit_output_sigma(
    err: np.ndarray, filter_var: np.ndarray, d: np.ndarray,
    one_sigma: float = ONE_SIGMA_TARGET, two_sigma: float = TWO_SIGMA_TARGET,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(f, s, kappa) [k] of outputs other than the level (aux outputs, tuners) with errors
    err [N, k], filter variance filter_var [N, k] at records at distance d [N] from nominal:
    the filter variance's scale where it alone over-covers (``fit_filter_scale``), then the
    model error and its spread on top (``fit_model_spread``), as the level's."""
    f = fit_filter_scale(err, filter_var, one_sigma)
    s, kappa = fit_model_spread(err, f**2 * np.asarray(filter_var, float), d, one_sigma,
                                two_sigma)
    return f, s, kappa


def fit_filter_scale(
    err: np.ndarray, filter_var: np.ndarray, one_sigma: float = ONE_SIGMA_TARGET,
) -> np.ndarray:
    """Scale f [p] in (0, 1] of the filter variance where it alone over-covers the calibrated
    level's errors err [N, p] (module docstring, "Calibrated level": the correction regresses
    on every estimate, whose errors are correlated, and so cancels part of the filter noise
    too): the smallest f with f^2 filter_var holding ``one_sigma`` of them (an order statistic
    of e_i^2 / v_i); 1 where it does not over-cover."""
    err = np.asarray(err, float)
    var = np.broadcast_to(np.asarray(filter_var, float), err.shape)
    out = np.ones(err.shape[1])
    for k in range(err.shape[1]):
        ok = np.isfinite(err[:, k]) & np.isfinite(var[:, k]) & (var[:, k] > 0.0)
        if not ok.any():
            continue
        f2 = np.sort(err[ok, k] ** 2 / var[ok, k])
        rank = min(f2.size - 1, max(0, int(np.ceil(one_sigma * f2.size)) - 1))
        out[k] = min(1.0, float(np.sqrt(f2[rank])))
    return out
