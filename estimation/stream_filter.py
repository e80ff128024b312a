"""The stream filter's numerics at one anchor condition: the design model resampled to the
recording's sample interval (``resample``), its reduced model and steady-state gain
(``segment_gain``, docs/math.md sections 2-3) and the filter run over samples with that gain
(``filter_run``). The scheduling over the envelope, the storage and the service are in
app/services/streams/.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from estimation.errors import UnobservableDesignError
from estimation.kalman import FilterTerms, filter_terms, run_filter_terms, steady_state_gain
from estimation.model import LinearModel
from estimation.reduced import reduced_model


class ResampleError(ValueError):
    """A model that cannot be resampled to another sample interval."""


@dataclass(frozen=True)
class SegmentGain:
    """Reduced model and steady-state gain at one anchor condition and sample interval."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    F: np.ndarray
    G: np.ndarray
    K: np.ndarray
    sigma: np.ndarray  # [q | h | z] 1-sigma from the a-posteriori covariance
    # Transient bias compensation (docs/math.md section 7): the gain of each transient-index
    # region (-1, +1) with R_b in place of R; empty without a bias model.
    region_gains: Mapping[int, np.ndarray] = field(default_factory=dict)
    # The recursion's products of K (``kalman.filter_terms``), formed once for the many short
    # runs a gain serves (a live upload's chunk of a few samples).
    terms: FilterTerms = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "terms", filter_terms(self.A, self.C, self.K, self.B, self.D))


def resample(model: LinearModel, dt: float) -> LinearModel:
    """The model at sample interval ``dt`` (zero-order hold on u and h).

    With A = exp(Ac dt0) and [B, L] = Ac^-1 (A - I) [Bc, Lc], the same continuous system at dt
    has A_r = A^r (r = dt / dt0, through the eigenvalues of A, real and positive for spool and
    metal-temperature modes) and [B_r, L_r] = (A - I)^-1 (A_r - I) [B, L] (functions of A
    commute), which keeps the steady-state gains C (I - A)^-1 L + M.
    """
    if math.isclose(dt, model.dt, rel_tol=1e-9):
        return model
    w, T = np.linalg.eig(model.A)
    on_negative_axis = (np.abs(np.imag(w)) <= 1e-12 * np.abs(w)) & (np.real(w) <= 0.0)
    if np.any(on_negative_axis):
        raise ResampleError(
            f"the design model (dt {model.dt:g} s) cannot be resampled to {dt:g} s: "
            "its state matrix has eigenvalues on the negative real axis"
        )
    # Principal powers of conjugate pairs are conjugate: the product is real.
    Ar_c = np.linalg.solve(T.T, (T * w ** (dt / model.dt)).T).T  # T diag(w^r) T^-1
    Ar = np.real(Ar_c)
    eye = np.eye(model.n_states)
    BL = np.linalg.solve(model.A - eye, (Ar - eye) @ np.hstack([model.B, model.L]))
    nu = model.n_inputs
    return replace(model, A=Ar, B=BL[:, :nu], L=BL[:, nu:], dt=dt)


def noise_scale(dt: float, noise_interval_s: float | None) -> float:
    """The factor on a sensor noise R that holds at ``noise_interval_s`` for samples ``dt``
    apart (noise_interval_s / dt; 1 at that interval, to the bit, or with None)."""
    if noise_interval_s is None or math.isclose(dt, noise_interval_s, rel_tol=1e-9):
        return 1.0
    return noise_interval_s / dt


def segment_gain(
    model: LinearModel, vstar: np.ndarray, Vp: np.ndarray, Q: np.ndarray, Qh: np.ndarray,
    dt: float, R_regions: Mapping[int, np.ndarray] | None = None,
    noise_interval_s: float | None = None,
) -> SegmentGain:
    """The reduced model and steady-state gain of ``model`` at sample interval ``dt``, with the
    random walks and process noise Q, Qh given per sample of the model (they scale with the
    sample interval). ``R_regions`` (region -> R_b, seed 004 eq. 6) adds one gain per
    transient-index region. ``noise_interval_s``: the sample interval R (and each R_b) holds
    at, scaled by noise_interval_s / dt at another interval, so that the sensors tell the
    filter as much per second at every rate; None: R per sample at every interval.

    Where the sensors cannot estimate the tuners at this condition (no stabilising
    steady-state gain: at ground idle the demo's ten-tuner design has unobservable
    directions), the segment runs on the model's prediction alone: K = 0 (the tuners hold their
    last estimate, the spool states follow the inputs) and every 1-sigma is NaN, "not
    estimated here", rather than failing the recording."""
    ratio = dt / model.dt
    model = resample(model, dt)
    red = reduced_model(model, vstar, Q * ratio, Qh * ratio)
    per_sample = noise_scale(dt, noise_interval_s)
    R = model.R * per_sample
    try:
        ss = steady_state_gain(red.A, red.C, red.Q, R)
    except UnobservableDesignError:
        K = np.zeros((red.A.shape[0], red.C.shape[0]))
        sigma = np.full(vstar.shape[0] + Vp.shape[0] + red.F.shape[0], np.nan)
        return SegmentGain(red.A, red.B, red.C, red.D, red.F, red.G, K, sigma,
                           {r: K for r in (R_regions or {})})
    P = ss.P_post
    nx = model.n_states
    Pq = P[nx:, nx:]
    sigma = np.sqrt(np.maximum(np.concatenate([
        np.diag(Pq), np.diag(Vp @ Pq @ Vp.T), np.diag(red.F @ P @ red.F.T)
    ]), 0.0))
    regions = {r: steady_state_gain(red.A, red.C, red.Q, Rb * per_sample).K
               for r, Rb in (R_regions or {}).items()}
    return SegmentGain(red.A, red.B, red.C, red.D, red.F, red.G, ss.K, sigma, regions)


def filter_run(g: SegmentGain, ys: np.ndarray, us: np.ndarray, x_prev: np.ndarray,
                u_prev: np.ndarray) -> np.ndarray:
    """x_hat [L, n] over samples ys [L, ny], us [L, nu] with one gain. A sample missing a
    sensor (null) is not a measurement: x_hat is the prediction A x_hat + B du there."""
    missing = np.isnan(ys).any(axis=1)
    L = ys.shape[0]
    if not missing.any():
        return run_filter_terms(g.terms, ys[:, None, :], us[:, None, :], x_prev,
                                u_prev)[:, 0, :]
    x = np.empty((L, g.A.shape[0]))
    k = 0
    while k < L:
        if missing[k]:
            x[k] = g.A @ x_prev + g.B @ u_prev
            x_prev, u_prev, k = x[k], us[k], k + 1
            continue
        rest = missing[k:]
        e = k + int(np.argmax(rest)) if rest.any() else L
        x[k:e] = run_filter_terms(g.terms, ys[k:e, None, :], us[k:e, None, :], x_prev,
                                  u_prev)[:, 0, :]
        x_prev, u_prev, k = x[e - 1], us[e - 1], e
    return x
