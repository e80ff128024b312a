"""Transient bias compensation: model-plant mismatch learnt offline (seed 004, docs/math.md
section 7).

The on-board model's state derivatives give a transient index (seed 004 eq. 8)

    TI[k] = (1 / n_x) sum_i xdot_hat_i[k] / x_ref_i                       [1/s]

and a bias model learnt on a healthy engine maps it to a mean bias b(TI) and a measurement
covariance R_b(TI) (seed 004 Table 4): inside the dead band |TI| <= TI* b = 0 and R_b = R;
above TI* and below -TI* b is a quadratic in TI fitted by least squares and R_b is the sample
covariance of the fit residuals (seed 004 Algorithm 1). The filter then uses

    r[k] = y[k] - y_hat[k] - b(TI[k])        R -> R_b(TI[k])           (seed 004 eq. 5-6)

With the steady-state gains of the stream filter, R_b per region means one gain per region
(three in all); ``filter_compensated`` switches between them sample by sample.

R_b is stored as its excess over the sensor noise the fit was made with (the part of the
Algorithm 1 covariance above R, positive semidefinite), and applied as R + excess: the
covariance the seed uses when the filter's R is the fit's, and never below the sensor noise.

Corrected parameters (seed 004 eq. 10, X_corr = X / (theta^a delta^b)) carry a model learnt at
sea level elsewhere: the index is formed from corrected states (``state_scale``), and a bias in
percent of the trim at the sample's own condition needs no de-correction (percent of trim is
already a ratio of like-corrected quantities).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from estimation.errors import DimensionError, ModelFormatError
from estimation.kalman import stream_input_terms
from estimation.model import check_shape

__all__ = [
    "BIAS_FORMAT",
    "TI_STAR",
    "BiasModel",
    "BiasRegion",
    "BiasFitWarning",
    "CompensatedEstimate",
    "correction_factor",
    "filter_compensated",
    "fit_bias",
    "transient_index",
]

BIAS_FORMAT = "fleethealth.transient-bias/1"
TI_STAR = 1e-3  # 1/s, seed 004's dead band
MIN_SAMPLES = 10  # per region: fewer and the region is left uncompensated


class BiasFitWarning(UserWarning):
    """A region of the transient index had too few samples to fit; it stays uncompensated."""


def correction_factor(theta: np.ndarray, delta: np.ndarray, a: np.ndarray,
                      b: np.ndarray) -> np.ndarray:
    """theta^a delta^b [S, n] for conditions theta, delta [S] and exponents a, b [n]
    (seed 004 eq. 10: X_corrected = X / correction_factor)."""
    th = np.asarray(theta, float)[:, None]
    de = np.asarray(delta, float)[:, None]
    return th ** np.asarray(a, float)[None, :] * de ** np.asarray(b, float)[None, :]


def transient_index(xdot: np.ndarray, x_ref: np.ndarray) -> np.ndarray:
    """TI [S] = mean_i xdot[:, i] / x_ref[i] (seed 004 eq. 8); xdot [S, n_x], x_ref [n_x]."""
    xdot = np.atleast_2d(np.asarray(xdot, float))
    x_ref = check_shape("x_ref", x_ref, (xdot.shape[1],))
    return np.mean(xdot / x_ref, axis=1)


@dataclass(frozen=True)
class BiasRegion:
    """One side of the dead band: b(TI) = coeffs[0] TI^2 + coeffs[1] TI + coeffs[2]
    (coeffs [3, ny]), R_b = R + excess (excess [ny, ny], PSD), from n_samples samples."""

    coeffs: np.ndarray
    excess: np.ndarray
    n_samples: int

    def mean(self, ti: np.ndarray) -> np.ndarray:
        t = np.asarray(ti, float)[..., None]
        c = self.coeffs
        return (c[0] * t + c[1]) * t + c[2]

    def to_dict(self) -> dict[str, Any]:
        return {"coeffs": self.coeffs.tolist(), "excess": self.excess.tolist(),
                "n_samples": int(self.n_samples)}


@dataclass(frozen=True)
class BiasModel:
    """Mean bias and covariance per transient-index region (seed 004 Table 4), for the named
    sensors (percent of trim), with the state exponents used to correct the index."""

    sensors: tuple[str, ...]
    ti_star: float
    accelerating: BiasRegion | None  # TI > TI*
    decelerating: BiasRegion | None  # TI < -TI*
    x_ref: tuple[float, ...] = ()  # reference (corrected) state values of the index, if any
    ti_tau_s: float = 0.0  # time constant of the first-order low-pass on TI (0: none)

    @property
    def n_sensors(self) -> int:
        return len(self.sensors)

    def region(self, ti: np.ndarray) -> np.ndarray:
        """-1 (decelerating), 0 (dead band), +1 (accelerating) per sample."""
        t = np.asarray(ti, float)
        return np.where(t > self.ti_star, 1, np.where(t < -self.ti_star, -1, 0))

    def regions(self) -> dict[int, BiasRegion]:
        out = {}
        if self.accelerating is not None:
            out[1] = self.accelerating
        if self.decelerating is not None:
            out[-1] = self.decelerating
        return out

    def mean(self, ti: np.ndarray) -> np.ndarray:
        """b(TI) [S, ny]: zero in the dead band and in a region with no fit."""
        t = np.atleast_1d(np.asarray(ti, float))
        out = np.zeros((t.shape[0], self.n_sensors))
        reg = self.region(t)
        for r, fit in self.regions().items():
            sel = reg == r
            if sel.any():
                out[sel] = fit.mean(t[sel])
        return out

    def covariance(self, region: int, R: np.ndarray) -> np.ndarray:
        """R_b of a region: R in the dead band (or a region with no fit), else R + excess."""
        R = check_shape("R", R, (self.n_sensors, self.n_sensors))
        fit = self.regions().get(int(region))
        return R if fit is None else R + fit.excess

    def select_sensors(self, names: Sequence[str]) -> BiasModel:
        """The model restricted to ``names`` (each must be one of its sensors)."""
        missing = [n for n in names if n not in self.sensors]
        if missing:
            raise DimensionError(f"the bias model has no sensor(s) {missing}")
        idx = [self.sensors.index(n) for n in names]

        def sub(r: BiasRegion | None) -> BiasRegion | None:
            if r is None:
                return None
            return BiasRegion(r.coeffs[:, idx], r.excess[np.ix_(idx, idx)], r.n_samples)

        return BiasModel(tuple(names), self.ti_star, sub(self.accelerating),
                         sub(self.decelerating), self.x_ref, self.ti_tau_s)

    def for_sensors(self, names: Sequence[str]) -> BiasModel:
        """The model over ``names``: a sensor it was not fitted on gets no bias and no excess."""
        known = [n for n in names if n in self.sensors]
        idx = [self.sensors.index(n) for n in known]
        pos = [list(names).index(n) for n in known]
        ny = len(names)

        def sub(r: BiasRegion | None) -> BiasRegion | None:
            if r is None:
                return None
            c = np.zeros((3, ny))
            e = np.zeros((ny, ny))
            c[:, pos] = r.coeffs[:, idx]
            e[np.ix_(pos, pos)] = r.excess[np.ix_(idx, idx)]
            return BiasRegion(c, e, r.n_samples)

        return BiasModel(tuple(names), self.ti_star, sub(self.accelerating),
                         sub(self.decelerating), self.x_ref, self.ti_tau_s)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready ``fleethealth.transient-bias/1`` dict."""
        return {
            "format": BIAS_FORMAT,
            "sensors": list(self.sensors),
            "ti_star": float(self.ti_star),
            "x_ref": list(self.x_ref),
            "ti_tau_s": float(self.ti_tau_s),
            "accelerating": None if self.accelerating is None else self.accelerating.to_dict(),
            "decelerating": None if self.decelerating is None else self.decelerating.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> BiasModel:
        """Rebuild from ``to_dict`` output; ModelFormatError names what is wrong."""
        if d.get("format") != BIAS_FORMAT:
            raise ModelFormatError(f"format must be {BIAS_FORMAT!r}, found {d.get('format')!r}")
        for key in ("sensors", "ti_star", "accelerating", "decelerating"):
            if key not in d:
                raise ModelFormatError(f"missing key {key!r}")
        sensors = tuple(str(s) for s in d["sensors"])
        ny = len(sensors)

        def region(name: str) -> BiasRegion | None:
            r = d[name]
            if r is None:
                return None
            try:
                c = np.asarray(r["coeffs"], float)
                e = np.asarray(r["excess"], float)
                n = int(r["n_samples"])
            except (KeyError, TypeError, ValueError) as exc:
                raise ModelFormatError(f"{name}: {exc}") from exc
            if c.shape != (3, ny) or e.shape != (ny, ny):
                raise ModelFormatError(
                    f"{name}: coeffs must be (3, {ny}) and excess ({ny}, {ny}), found "
                    f"{c.shape} and {e.shape}")
            if not (np.all(np.isfinite(c)) and np.all(np.isfinite(e))):
                raise ModelFormatError(f"{name}: coefficients must be finite")
            return BiasRegion(c, e, n)

        ti_star = float(d["ti_star"])
        if not np.isfinite(ti_star) or ti_star < 0:
            raise ModelFormatError(f"ti_star must be a finite number >= 0, found {ti_star}")
        x_ref = tuple(float(v) for v in d.get("x_ref", ()))
        tau = float(d.get("ti_tau_s", 0.0))
        if not np.isfinite(tau) or tau < 0:
            raise ModelFormatError(f"ti_tau_s must be a finite number >= 0, found {tau}")
        return cls(sensors, ti_star, region("accelerating"), region("decelerating"), x_ref, tau)


def _psd_part(S: np.ndarray) -> np.ndarray:
    """The positive semidefinite part of a symmetric matrix (negative eigenvalues to 0)."""
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    out = (V * np.maximum(w, 0.0)) @ V.T
    return 0.5 * (out + out.T)


def fit_bias(
    ti: np.ndarray, residuals: np.ndarray, R: np.ndarray, sensors: Sequence[str],
    ti_star: float = TI_STAR, x_ref: Sequence[float] = (), ti_tau_s: float = 0.0,
) -> BiasModel:
    """Fit the bias model to residuals [S, ny] of a healthy engine against TI [S].

    Per region (TI > TI*, TI < -TI*) the quadratic b = p1 TI^2 + p2 TI + p3 is the least-squares
    fit of each sensor (seed 004 Table 4); e = r - b(TI) gives the sample covariance
    S_b = sum e e^T / (N - 1) (seed 004 Algorithm 1), stored as its excess over R (the noise
    covariance the residuals carry). Samples with a NaN are left out; a region with fewer than
    MIN_SAMPLES samples is left uncompensated (BiasFitWarning).
    """
    ti = np.asarray(ti, float).ravel()
    r = np.asarray(residuals, float)
    if r.ndim != 2 or r.shape[0] != ti.shape[0]:
        raise DimensionError(
            f"residuals must be [{ti.shape[0]}, n_sensors] to match TI, found {r.shape}")
    ny = r.shape[1]
    if len(sensors) != ny:
        raise DimensionError(f"sensors must name {ny} columns, found {len(sensors)}")
    R = check_shape("R", R, (ny, ny))
    if not np.isfinite(ti_star) or ti_star < 0:
        raise ValueError(f"ti_star must be a finite number >= 0, got {ti_star}")
    ok = np.isfinite(ti) & np.all(np.isfinite(r), axis=1)
    fits: dict[int, BiasRegion | None] = {}
    for side, sel in ((1, ok & (ti > ti_star)), (-1, ok & (ti < -ti_star))):
        N = int(sel.sum())
        if N < MIN_SAMPLES:
            warnings.warn(
                f"{N} samples with TI {'>' if side > 0 else '<'} {'' if side > 0 else '-'}"
                f"{ti_star:g}/s (fewer than {MIN_SAMPLES}): that region stays uncompensated",
                BiasFitWarning, stacklevel=2)
            fits[side] = None
            continue
        t = ti[sel]
        V = np.column_stack([t * t, t, np.ones(N)])
        coeffs = np.linalg.lstsq(V, r[sel], rcond=None)[0]  # [3, ny]
        e = r[sel] - V @ coeffs
        S_b = e.T @ e / (N - 1)  # seed 004 Algorithm 1, line 6
        fits[side] = BiasRegion(coeffs, _psd_part(S_b - R), N)
    return BiasModel(tuple(str(s) for s in sensors), float(ti_star), fits[1], fits[-1],
                     tuple(float(v) for v in x_ref), float(ti_tau_s))


class CompensatedEstimate(NamedTuple):
    """Output of ``filter_compensated``, time-major.

    x_hat [T, E, n]; ti [T, E] transient index at each update; region [T, E] (-1, 0, +1);
    innovation [T, E, ny] y - C x_pred - D u before the bias is taken off.
    """

    x_hat: np.ndarray
    ti: np.ndarray
    region: np.ndarray
    innovation: np.ndarray


def filter_compensated(
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    D: np.ndarray,
    gains: Mapping[int, np.ndarray],
    y: np.ndarray,
    u: np.ndarray,
    n_x: int,
    dt: float,
    bias: BiasModel | None = None,
    x0: np.ndarray | None = None,
    u_prev: np.ndarray | None = None,
    state_scale: np.ndarray | None = None,
    ti_tau_s: float | None = None,
    ti0: np.ndarray | float = 0.0,
) -> CompensatedEstimate:
    """The stream filter with bias compensation (seed 004 eq. 5-6 and Fig. 2).

        x_pred[k] = A x_hat[k-1] + B u[k-1]
        TI[k]     = mean_i (s_i[k] (1 + x_pred_i[k] / 100) - s_i[k-1] (1 + x_hat_i[k-1] / 100)) / dt
        x_hat[k]  = x_pred[k] + K_r (y[k] - C x_pred[k] - D u[k] - b(TI[k])),  r = region(TI[k])

    over the first n_x (physical) states, which are in percent of the trim at each sample's
    condition; s [T, n_x] (``state_scale``) is trim_i(condition[k]) / (x_ref_i theta^a delta^b),
    the corrected state over its reference at 100 % (None: 1, a fixed trim). TI is then passed
    through a first-order low-pass of time constant ``ti_tau_s`` (default the bias model's;
    the on-board states carry the sensor noise the filter lets in, so the raw index chatters
    across the dead band), starting from ``ti0``. ``gains`` maps the
    region (-1, 0, +1) to the steady-state gain computed with R_b of that region; a missing
    region uses gains[0]. With ``bias`` None the filter only reports TI and the innovations
    (the learning phase). y [T, E, ny], u [T, E, nu] time-major as ``filter_stream_states``,
    which this equals bit for bit when b = 0 and every gain is gains[0].
    """
    y = np.asarray(y, float)
    if y.ndim != 3:
        raise DimensionError(
            f"y must be [n_steps, n_engines, n_sensors] (time-major), found shape {y.shape}")
    T, E, ny = y.shape
    n = np.shape(A)[0]
    A = check_shape("A", A, (n, n))
    u = np.asarray(u, float)
    nu = u.shape[-1]
    B = check_shape("B", B, (n, nu))
    if not 0 < n_x <= n:
        raise DimensionError(f"n_x must be in 1..{n}, found {n_x}")
    if dt <= 0:
        raise ValueError(f"dt must be positive, got {dt}")
    if bias is not None and bias.n_sensors != ny:
        raise DimensionError(f"the bias model has {bias.n_sensors} sensors, y has {ny}")
    if 0 not in gains:
        raise DimensionError("gains must hold the dead-band gain (key 0)")
    terms = {r: stream_input_terms(A, C, K, y, u, B, D, u_prev) for r, K in gains.items()}
    KT = {r: check_shape(f"K[{r}]", K, (n, ny)).T for r, K in gains.items()}
    s = np.ones((T, n_x)) if state_scale is None else check_shape(
        "state_scale", state_scale, (T, n_x))
    x_prev = np.zeros((E, n)) if x0 is None else np.broadcast_to(np.asarray(x0, float), (E, n))
    u_last = np.zeros((E, nu)) if u_prev is None else np.broadcast_to(
        np.asarray(u_prev, float), (E, nu))
    x = np.empty((T, E, n))
    ti = np.empty((T, E))
    region = np.zeros((T, E), dtype=int)
    innov = np.empty((T, E, ny))
    AT, BT, CT, DT = A.T, B.T, C.T, np.asarray(D, float).T
    s_prev = s[0]
    tau = (bias.ti_tau_s if bias is not None else 0.0) if ti_tau_s is None else ti_tau_s
    if tau < 0:
        raise ValueError(f"ti_tau_s must be >= 0, got {tau}")
    alpha = dt / (tau + dt)
    ti_last = np.broadcast_to(np.asarray(ti0, float), (E,))
    for k in range(T):
        xp = x_prev @ AT + u_last @ BT
        innov[k] = y[k] - xp @ CT - u[k] @ DT
        ti[k] = np.mean(
            (s[k] * (1.0 + xp[:, :n_x] / 100.0) - s_prev * (1.0 + x_prev[:, :n_x] / 100.0)) / dt,
            axis=1)
        if alpha < 1.0:
            ti[k] = ti_last + alpha * (ti[k] - ti_last)
        ti_last = ti[k]
        if bias is None:
            reg = np.zeros(E, dtype=int)
            b = None
        else:
            reg = bias.region(ti[k])
            b = bias.mean(ti[k])
        region[k] = reg
        for r in np.unique(reg):
            r = int(r)
            pre, PhiT = terms.get(r, terms[0])
            K_T = KT.get(r, KT[0])
            sel = reg == r
            if sel.all():
                step = pre[k] if b is None else pre[k] - b @ K_T
                x[k] = step + x_prev @ PhiT
            else:
                step = pre[k, sel] if b is None else pre[k, sel] - b[sel] @ K_T
                x[k, sel] = step + x_prev[sel] @ PhiT
        x_prev, u_last, s_prev = x[k], u[k], s[k]
    return CompensatedEstimate(x, ti, region, innov)
