"""Transient bias compensation on the built-in nonlinear engine (seed 004's test cases).

The "real" engine is ``estimation.engine.transient.simulate`` (spools and both metal
temperatures, heat soak). The on-board model is the engine linearised at one condition with
the HPC metal temperature folded into a quasi-steady state (``soaked_model``: the seed's Table 3
keeps the spools and one HPT metal temperature of the real engine's seven states), so its
steady-state gains are exact and its transients are not: the model-plant mismatch.

A flight here is a power schedule of holds and steps at one flight condition, sampled at dt;
the sensors and commands become percent deviations from the nominal engine's steady state at
each sample's condition and power (solved, not interpolated). The filter is the stream filter
(steady-state gains, ``estimation.bias.filter_compensated``) on tuners of the subset method.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from estimation.bias import BiasModel, correction_factor, filter_compensated, fit_bias
from estimation.engine.atmosphere import flight_condition
from estimation.engine.flight import OperatingPoint
from estimation.engine.health import HEALTH_NAMES, N_HEALTH
from estimation.engine.linearize import linearize
from estimation.engine.sensors import noise_std
from estimation.engine.steady import steady_state
from estimation.engine.transient import simulate
from estimation.kalman import steady_state_gain
from estimation.model import LinearModel
from estimation.reduced import reduced_model

TUNERS = ("fan_eff", "lpc_eff", "hpc_eff", "hpt_eff", "lpt_eff")
SPOOL_EXPONENT = 0.5  # corrected speed N / sqrt(theta); metal temperature T / theta
STATE_EXPONENTS = {"Nf": 0.5, "Nc": 0.5, "TMHPC": 1.0, "TMHPT": 1.0}


def soaked_model(model: LinearModel, fold: Sequence[str]) -> LinearModel:
    """The model with states ``fold`` at their quasi-steady value
    x2 = (I - A22)^-1 (A21 x1 + B2 u + L2 h) in every equation: same steady-state gains,
    none of the folded states' dynamics."""
    names = model.state_names
    idx2 = np.array([names.index(n) for n in fold])
    idx1 = np.array([i for i in range(model.n_states) if i not in idx2])
    A = model.A
    S = np.linalg.solve(np.eye(len(idx2)) - A[np.ix_(idx2, idx2)],
                        np.hstack([A[np.ix_(idx2, idx1)], model.B[idx2], model.L[idx2]]))
    n1, nu = len(idx1), model.n_inputs
    Sx, Su, Sh = S[:, :n1], S[:, n1:n1 + nu], S[:, n1 + nu:]
    A12 = A[np.ix_(idx1, idx2)]
    C2, F2 = model.C[:, idx2], model.F[:, idx2]
    return replace(
        model, states=tuple(model.states[int(i)] for i in idx1),
        A=A[np.ix_(idx1, idx1)] + A12 @ Sx, B=model.B[idx1] + A12 @ Su,
        L=model.L[idx1] + A12 @ Sh, C=model.C[:, idx1] + C2 @ Sx, D=model.D + C2 @ Su,
        M=model.M + C2 @ Sh, F=model.F[:, idx1] + F2 @ Sx, G=model.G + F2 @ Su,
        N=model.N + F2 @ Sh,
        trim={k: v for k, v in model.trim.items() if k not in fold},
    )


@dataclass(frozen=True)
class Flight:
    """One simulated flight in the filter's terms: dy [T, ny], du [T, nu] percent of the nominal
    trim; scale [T, n_x] corrected trim states over their reference; truth h [13]; power [T]."""

    dy: np.ndarray
    du: np.ndarray
    scale: np.ndarray
    health: np.ndarray
    power: np.ndarray
    dt: float


def power_schedule(levels: Sequence[float], hold_s: float, ramp_s: float = 2.0):
    """Power % at time t: holds of ``hold_s`` at each level, linear ramps of ``ramp_s``."""
    lv = np.asarray(levels, float)

    def power(t: float) -> float:
        i = min(int(t // hold_s), len(lv) - 1)
        into = t - i * hold_s
        if i == 0 or into >= ramp_s:
            return float(lv[i])
        return float(lv[i - 1] + (lv[i] - lv[i - 1]) * into / ramp_s)

    return power


def simulate_flight(
    levels: Sequence[float], hold_s: float, alt_ft: float, mach: float, health: np.ndarray,
    rng: np.random.Generator, state_names: Sequence[str], x_ref: np.ndarray, dt: float = 0.1,
) -> Flight:
    """A flight of power holds at (alt, Mach) with sensor noise, as filter deviations."""
    pw = power_schedule(levels, hold_s)

    def sched(t: float) -> OperatingPoint:
        return OperatingPoint(np.array([alt_ft]), np.array([mach]), np.array([0.0]),
                              np.array([pw(t)]))

    t_end = hold_s * len(levels)
    env0 = np.array([alt_ft, mach, 0.0])
    trim0 = steady_state(env0, power=float(levels[0]), health=np.zeros(N_HEALTH))
    res = simulate(sched, t_end, health=health, dt=dt, rng=rng,
                   noise_std=noise_std(trim0.sensors))
    power = np.array([pw(t) for t in res.time_s])
    env = np.tile(env0, (power.size, 1))
    nominal = steady_state(env, power=power, health=np.zeros((power.size, N_HEALTH)))
    dy = 100.0 * (res.measured[:, 0] - nominal.sensors) / nominal.sensors
    du = 100.0 * (res.u[:, 0] - nominal.u) / np.where(np.abs(nominal.u) > 1e-9, nominal.u, 1.0)
    fc = flight_condition(np.array([alt_ft]), np.array([mach]), np.array([0.0]))
    order = ("Nf", "Nc", "TMHPC", "TMHPT")
    cols = [order.index(n) for n in state_names]
    a = np.array([STATE_EXPONENTS[n] for n in state_names])
    corr = correction_factor(np.full(power.size, fc.theta[0]), np.full(power.size, fc.delta[0]),
                             a, np.zeros_like(a))
    scale = nominal.x[:, cols] / corr / x_ref
    return Flight(dy, du, scale, np.asarray(health, float), power, dt)


@dataclass(frozen=True)
class OnBoard:
    """The on-board filter at one condition: reduced model matrices, gains per region."""

    model: LinearModel
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    Q: np.ndarray
    Vp: np.ndarray
    n_x: int


def on_board(alt_ft: float, mach: float, power: float, dt: float,
             fold: Sequence[str] = ("TMHPC",), qh_std: float = 0.003) -> OnBoard:
    """The soaked linear model at (alt, Mach, power) at sample interval dt with subset tuners."""
    full = linearize(alt_ft, mach, power, dt=dt)
    model = soaked_model(full, fold)
    vstar = np.eye(N_HEALTH)[[HEALTH_NAMES.index(n) for n in TUNERS]]
    red = reduced_model(model, vstar, np.eye(model.n_states) * 0.01**2,
                        np.eye(N_HEALTH) * qh_std**2)
    return OnBoard(model, red.A, red.B, red.C, red.D, red.Q, red.vstar_pinv, model.n_states)


def gains_for(ob: OnBoard, bias: BiasModel | None, use_covariance: bool = True,
              freeze_tuners: bool = False) -> dict[int, np.ndarray]:
    """Steady-state gain per region: R_b of the region (R when ``use_covariance`` is off, the
    seed's "hybrid" setting of its Fig. 10)."""
    R = ob.model.R
    out = {0: steady_state_gain(ob.A, ob.C, ob.Q, R).K}
    if bias is not None and use_covariance:
        for r in bias.regions():
            out[r] = steady_state_gain(ob.A, ob.C, ob.Q, bias.covariance(r, R)).K
    if freeze_tuners:
        for K in out.values():
            K[ob.n_x:] = 0.0
    return out


def run(ob: OnBoard, f: Flight, bias: BiasModel | None, use_covariance: bool = True,
        freeze_tuners: bool = False, start_at_truth: bool = True,
        ti_tau_s: float | None = None):
    """The filter over one flight; returns (CompensatedEstimate, h_hat [T, m])."""
    gains = gains_for(ob, bias, use_covariance, freeze_tuners)
    m = len(TUNERS)
    x0 = np.zeros(ob.n_x + m)
    if start_at_truth:
        x0[ob.n_x:] = f.health[[HEALTH_NAMES.index(n) for n in TUNERS]]
    est = filter_compensated(ob.A, ob.B, ob.C, ob.D, gains, f.dy[:, None, :], f.du[:, None, :],
                             ob.n_x, f.dt, bias=bias, x0=x0, u_prev=f.du[0],
                             state_scale=f.scale, ti_tau_s=ti_tau_s)
    return est, est.x_hat[:, 0, ob.n_x:]


def learn(ob: OnBoard, flights: Sequence[Flight], ti_star: float,
          ti_tau_s: float) -> BiasModel:
    """Bias model from healthy flights: innovations of the filter with the tuners held at zero
    (seed 004: residuals of the model at nominal health) against the transient index."""
    ti, r = [], []
    for f in flights:
        est, _ = run(ob, f, None, freeze_tuners=True, start_at_truth=False, ti_tau_s=ti_tau_s)
        ti.append(est.ti[:, 0])
        r.append(est.innovation[:, 0])
    return fit_bias(np.concatenate(ti), np.concatenate(r), ob.model.R,
                    ob.model.sensor_names, ti_star=ti_star, ti_tau_s=ti_tau_s)


def windows(power: np.ndarray, dt: float, during_s: float, after_s: float) -> np.ndarray:
    """0 steady, 1 during (within during_s of a power change), 2 after (the next after_s)."""
    change = np.flatnonzero(np.abs(np.diff(power)) > 1e-9) + 1
    since = np.full(power.size, np.inf)
    t = np.arange(power.size) * dt
    for c in change:
        sel = t >= t[c]
        since[sel] = np.minimum(since[sel], t[sel] - t[c])
    return np.where(since < during_s, 1, np.where(since < during_s + after_s, 2, 0))


def errors(h_hat: np.ndarray, f: Flight, win: np.ndarray) -> tuple[float, float, float]:
    """RMS health error (percent, over the tuned parameters) in steady, during, after."""
    truth = f.health[[HEALTH_NAMES.index(n) for n in TUNERS]]
    e2 = np.mean((h_hat - truth) ** 2, axis=1)
    return tuple(float(np.sqrt(np.mean(e2[win == w]))) if np.any(win == w) else np.nan
                 for w in (0, 1, 2))  # type: ignore[return-value]
