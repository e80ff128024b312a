"""Constant-gain extended Kalman filter with tuners (seed 001, Kobayashi, Simon, Litt 2005).

The nonlinear engine model runs on board with the tuners d as extra inputs
(health parameters h = V*^+ d, seed 002 eq. 11); one Kalman gain, computed
offline on the reduced-order linear model at a design point (seed 001: ground
maximum power), corrects it (seed 001 eq. 4):

    d/dt [x_hat; d] = [f(x_hat, d, u, e); 0] + K_c (y - g_y(x_hat, d, u, e))
    y_hat = g_y(x_hat, d, u, e)          z_hat = g_z(x_hat, d, u, e)

Discretised with forward Euler at the sample interval dt, and with the
steady-state gain of the discrete reduced-order model (``kalman.steady_state_gain``
on ``reduced.reduced_model``), the recursion on the a-priori estimate s- = [x-; d-] is

    r[k]     = y[k] - g_y(s-[k], u[k], e[k])                         (innovation)
    s_hat[k] = s-[k] + K r[k]                                          (a posteriori)
    s-[k+1]  = [x-[k] + dt f(s-[k], u[k], e[k]); d-[k]] + A_xq K r[k]

one evaluation of the nonlinear model per sample: the last line is seed 001
eq. 4 with K_c dt = A_xq K, the a-priori (predictor-form) gain. On a linear
plant equal to the design model (x + dt f -> A x + B u + L V*^+ d, g_y ->
C x + D u + M V*^+ d) the recursion is the steady-state filter of
``kalman.filter_stream_states`` exactly (s_hat[k] = its x_hat[k]). The
reported aux estimate is g_z at s- moved to s_hat through the design model,
z_hat = g_z(s-) + F_xq K r (exact on the linear plant).

Units. The gain works in percent of trim, as the design model does. The
engine's sensors, states and aux outputs are divided by the design point's
trim corrected to the current inlet conditions (seed 004's corrected
parameters: temperatures by theta2, pressures and thrust by delta2, speeds by
sqrt(theta2)), so one gain serves the envelope with innovations of the same
size at altitude as at sea level; tuners are already percent.

``run_cgekf`` is the generic recursion over a batch of B engines with any plant
(a callable giving x + dt f, y_hat, z_hat and the scales); ``EnginePlant`` is
the built-in nonlinear engine, evaluated batched (``turbofan.gas_path`` with
the transient simulator's chord solver, one gas-path evaluation per sample);
``LinearPlant`` is the design model itself (for checks).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from estimation.engine.atmosphere import flight_condition
from estimation.engine.design import EngineDesign, engine_design
from estimation.engine.health import HEALTH_NAMES, N_HEALTH
from estimation.engine.linearize import linearize
from estimation.engine.schedule import CORRECTION
from estimation.engine.sensors import AUX_NAMES, SENSOR_NAMES
from estimation.engine.steady import steady_state
from estimation.engine.transient import _GasPathSolver
from estimation.engine.turbofan import (
    STATE_NAMES,
    Operating,
    operating,
    outputs_from_stations,
)
from estimation.errors import DimensionError
from estimation.kalman import SteadyStateGain, steady_state_gain
from estimation.model import LinearModel
from estimation.reduced import ReducedModel, reduced_model
from estimation.stream_filter import noise_scale

__all__ = [
    "SEED001_SENSORS",
    "SEED001_TUNERS",
    "CgekfDesign",
    "CgekfResult",
    "PlantEvaluation",
    "cgekf_design",
    "run_cgekf",
    "EnginePlant",
    "LinearPlant",
    "filter_flights",
    "filter_one",
]

# seed 001 Table 2, sensor set no. 2 (XN12, XN25, P17, P25, T25, PS3, T3, T49), our names.
SEED001_SENSORS = ("Nf", "Nc", "P15", "P24", "T24", "Ps30", "T30", "T48")
# seed 001 Table 3, the tuners of the design with sensor set no. 2 (BST = our LPC).
SEED001_TUNERS = ("fan_flow", "lpc_flow", "hpc_eff", "hpc_flow", "hpt_eff", "hpt_flow",
                  "lpt_flow")
AUX_ESTIMATED = ("Fn", "T40", "SM_fan", "SM_LPC", "SM_HPC")
_TURBO = 10  # the filter's health vector: the ten component parameters (no biases)


class CgekfDesign(NamedTuple):
    """A constant-gain design: the gain and the reduced model it came from.

    K [n, ny] a-posteriori gain, K_pred = A_xq K [n, ny] a-priori gain, on the
    state [x%; d] (n = 4 + m); reduced: the reduced-order model at the design
    point (its F [nz, n] maps the state to aux outputs); gain: the DARE
    solution; model: the design LinearModel (sensors and aux selected);
    sensors, aux, tuners: names (tuners are health-parameter names, V* = rows of
    the identity); trim_x [4], trim_y [ny], trim_z [nz]: design-point trims in
    the engine's units; dt [s].
    """

    K: np.ndarray
    K_pred: np.ndarray
    reduced: ReducedModel
    gain: SteadyStateGain
    model: LinearModel
    sensors: tuple[str, ...]
    aux: tuple[str, ...]
    tuners: tuple[str, ...]
    trim_x: np.ndarray
    trim_y: np.ndarray
    trim_z: np.ndarray
    dt: float

    @property
    def n_tuners(self) -> int:
        return len(self.tuners)


class PlantEvaluation(NamedTuple):
    """One evaluation of the on-board model for a batch of B engines.

    x_next [B, nx] = x + dt f(x, d, u, e); y [B, ny] = g_y; z [B, nz] = g_z;
    scale_x [B, nx], scale_y [B, ny], scale_z [B, nz]: what 100 % is for each
    signal (the gain works on 100 * deviation / scale).
    """

    x_next: np.ndarray
    y: np.ndarray
    z: np.ndarray
    scale_x: np.ndarray
    scale_y: np.ndarray
    scale_z: np.ndarray


Plant = Callable[[int, np.ndarray, np.ndarray], PlantEvaluation]


class CgekfResult(NamedTuple):
    """CGEKF estimates over T samples of B engines, time-major.

    d_hat [T, B, m] tuners (a posteriori, percent); h_hat [T, B, 10] health
    parameters V*^+ d_hat (percent; names ``HEALTH_NAMES[:10]``); x_hat [T, B, nx]
    states (a posteriori, model units); y_hat [T, B, ny] sensor estimates
    g_y(s-) (a priori); z_hat [T, B, nz] aux estimates (a posteriori, model
    units); residual [T, B, ny] innovations y - y_hat in percent of scale;
    z_residual [T, B, nz] z_hat - z_true in percent of the truth when a truth
    was given (else NaN). Names: sensors, aux, tuners. x_next [B, nx], d_next [B, m]:
    the a-priori state after the last sample, where a following chunk of the same
    recordings continues (``run_cgekf(..., x0=x_next, d0=d_next)``).
    """

    d_hat: np.ndarray
    h_hat: np.ndarray
    x_hat: np.ndarray
    y_hat: np.ndarray
    z_hat: np.ndarray
    residual: np.ndarray
    z_residual: np.ndarray
    sensors: tuple[str, ...]
    aux: tuple[str, ...]
    tuners: tuple[str, ...]
    x_next: np.ndarray
    d_next: np.ndarray


def cgekf_design(
    sensors: Sequence[str] = SEED001_SENSORS,
    tuners: Sequence[str] = SEED001_TUNERS,
    aux: Sequence[str] = AUX_ESTIMATED,
    dt: float = 0.05,
    alt_ft: float = 0.0,
    mach: float = 0.0,
    power_pct: float = 100.0,
    q_std: float = 0.05,
    qh_std: float = 0.005,
    vstar: np.ndarray | None = None,
    Q: np.ndarray | None = None,
    Qh: np.ndarray | None = None,
    noise_interval_s: float | None = None,
) -> CgekfDesign:
    """Linearise the built-in engine at the design point and compute the constant gain.

    Design point: seed 001's ground maximum power (sea level static, ISA,
    take-off power) unless given. q_std [% per sample]: state process noise;
    qh_std [% per sample]: random walk of the health parameters (Q_h = qh_std^2 I);
    R: seed 001 Table 2 noise (``sensors.noise_std_percent``). Tuners are
    a subset of the ten component health parameters (seed 001 Table 3).
    Reduced model and gain: seed 002 eq. 4-7 and the steady-state DARE gain.

    A stored design's own choice replaces the defaults: vstar [m, 10] over the ten
    component health parameters (any V*, not only rows of the identity; ``tuners``
    then only names its rows), Q [4, 4] and Qh [10, 10] per sample at ``dt``;
    ``noise_interval_s`` the interval R holds at (``stream_filter.noise_scale``; None: per
    sample).
    """
    full = linearize(alt_ft, mach, power_pct, dt=dt)
    model = (full.select_sensors(list(sensors)).select_health(list(HEALTH_NAMES[:_TURBO]))
             .select_aux(list(aux)))
    nx = model.n_states
    if vstar is None:
        unknown = [t for t in tuners if t not in HEALTH_NAMES[:_TURBO]]
        if unknown:
            raise DimensionError(f"tuners must be component health parameters, not {unknown}")
        m = len(tuners)
        vstar = np.zeros((m, _TURBO))
        vstar[np.arange(m), [HEALTH_NAMES.index(t) for t in tuners]] = 1.0
    elif np.shape(vstar) != (len(tuners), _TURBO):
        raise DimensionError(
            f"Incompatible dimensions of vstar matrix; expected ({len(tuners)}, {_TURBO}) "
            f"but found {np.shape(vstar)}"
        )
    Q = q_std**2 * np.eye(nx) if Q is None else np.asarray(Q, float)
    Qh = qh_std**2 * np.eye(_TURBO) if Qh is None else np.asarray(Qh, float)
    red = reduced_model(model, np.asarray(vstar, float), Q, Qh)
    ss = steady_state_gain(red.A, red.C, red.Q, model.R * noise_scale(dt, noise_interval_s))
    trim = model.trim
    return CgekfDesign(
        K=ss.K, K_pred=red.A @ ss.K, reduced=red, gain=ss, model=model,
        sensors=tuple(sensors), aux=tuple(aux), tuners=tuple(tuners),
        trim_x=np.array([trim[n] for n in STATE_NAMES]),
        trim_y=np.array([trim[n] for n in sensors]),
        trim_z=np.array([trim[n] for n in aux]), dt=float(dt),
    )


def run_cgekf(
    design: CgekfDesign,
    plant: Plant,
    y: np.ndarray,
    x0: np.ndarray,
    d0: np.ndarray | None = None,
    z_true: np.ndarray | None = None,
) -> CgekfResult:
    """The CGEKF recursion (seed 001 eq. 4, discretised as in the module docstring).

    design: gain and names; plant(k, x [B, nx], d [B, m]) -> PlantEvaluation at
    sample k; y [T, B, ny] measurements in the plant's units; x0 [B, nx] the
    a-priori state at k = 0 (plant units); d0 [B, m] a-priori tuners (default 0);
    z_true [T, B, nz] optional truth for the aux residuals (percent of truth,
    seed 001 eq. 5). Health h_hat = V*^+ d_hat (seed 002 eq. 11). A NaN in y (a
    sensor that did not report) gives a NaN residual and no correction from it.
    """
    y = np.asarray(y, float)
    if y.ndim != 3 or y.shape[2] != len(design.sensors):
        raise DimensionError(
            f"y must be [n_steps, n_engines, {len(design.sensors)}] (time-major), "
            f"found {y.shape}"
        )
    T, B, ny = y.shape
    red = design.reduced
    nx, m = red.n_states, red.n_tuners
    x = np.array(np.broadcast_to(np.asarray(x0, float), (B, nx)))
    d = np.zeros((B, m)) if d0 is None else np.array(np.broadcast_to(d0, (B, m)), float)
    KT, KpT = design.K.T, design.K_pred.T
    FKT = (red.F @ design.K).T  # [ny, nz]
    nz = red.F.shape[0]
    out_d = np.empty((T, B, m))
    out_x = np.empty((T, B, nx))
    out_y = np.empty((T, B, ny))
    out_z = np.empty((T, B, nz))
    out_r = np.empty((T, B, ny))
    gaps = bool(np.isnan(y).any())
    for k in range(T):
        ev = plant(k, x, d)
        r = 100.0 * (y[k] - ev.y) / ev.scale_y
        out_r[k] = r
        if gaps:  # a sensor that did not report is not a measurement: no correction from it
            r = np.where(np.isnan(r), 0.0, r)
        post = r @ KT  # seed 001 eq. 4: the constant gain on the residual
        out_x[k] = x + ev.scale_x / 100.0 * post[:, :nx]
        out_d[k] = d + post[:, nx:]
        out_y[k] = ev.y
        out_z[k] = ev.z + ev.scale_z / 100.0 * (r @ FKT)
        step = r @ KpT
        x = ev.x_next + ev.scale_x / 100.0 * step[:, :nx]
        d = d + step[:, nx:]
    h = out_d @ red.vstar_pinv.T
    if z_true is None:
        zres = np.full_like(out_z, np.nan)
    else:
        zt = np.asarray(z_true, float)
        zres = 100.0 * (out_z - zt) / zt
    return CgekfResult(out_d, h, out_x, out_y, out_z, out_r, zres, design.sensors,
                       design.aux, design.tuners, x, d)


class LinearPlant:
    """The design's reduced-order linear model as a plant (percent units, scale 100).

    x_next = A x + L V*^+ d + B u[k], y = C x + M V*^+ d + D u[k], z = F x + N V*^+ d
    + G u[k] (u [T, B, nu] percent, or None). For checks: the CGEKF on it equals
    ``kalman.filter_stream_states`` to rounding.
    """

    def __init__(self, design: CgekfDesign, u: np.ndarray | None = None) -> None:
        self.red = design.reduced
        self.u = None if u is None else np.asarray(u, float)

    def __call__(self, k: int, x: np.ndarray, d: np.ndarray) -> PlantEvaluation:
        red = self.red
        s = np.concatenate([x, d], axis=1)
        x_next = s @ red.A[:red.n_states].T
        yy = s @ red.C.T
        zz = s @ red.F.T
        if self.u is not None:
            x_next = x_next + self.u[k] @ red.B[:red.n_states].T
            yy = yy + self.u[k] @ red.D.T
            zz = zz + self.u[k] @ red.G.T
        b = x.shape[0]
        return PlantEvaluation(x_next, yy, zz, np.full((b, x.shape[1]), 100.0),
                               np.full((b, yy.shape[1]), 100.0),
                               np.full((b, zz.shape[1]), 100.0))


def _correction(names: Sequence[str], env: np.ndarray) -> np.ndarray:
    """theta2^a delta2^b [B, n] at env [B, 3] (``schedule.CORRECTION``; 1 where absent)."""
    fc = flight_condition(env[:, 0], env[:, 1], env[:, 2])
    ab = np.array([CORRECTION.get(n, (0.0, 0.0)) for n in names])
    return fc.theta[:, None] ** ab[:, 0] * fc.delta[:, None] ** ab[:, 1]


class EnginePlant:
    """The built-in nonlinear engine as the CGEKF's on-board model, batched over B engines.

    u [T, B, 3] commands (Wf pps, VSV %, VBV %), env [T, B, 3] (alt ft, Mach,
    dTamb K): the filter's inputs at each sample. The five gas-path unknowns are
    carried from sample to sample and corrected by one chord step per
    evaluation (the transient simulator's one-pass solver, ``transient._GasPathSolver``;
    rows far from balance are solved to tolerance), so a sample costs one
    gas-path evaluation. x + dt f by forward Euler (seed 001 eq. 4).
    """

    def __init__(self, design: CgekfDesign, u: np.ndarray, env: np.ndarray,
                 engine: EngineDesign | None = None) -> None:
        self.cg = design
        self.u = np.asarray(u, float)
        self.env = np.asarray(env, float)
        self.d = engine or engine_design()
        B = self.u.shape[1]
        self.solver = _GasPathSolver(self.d, B)
        self.solver.full = True
        self.z_unknown: np.ndarray | None = None
        self.op_prev: Operating | None = None
        self.vp = design.reduced.vstar_pinv
        self.idx_y = [SENSOR_NAMES.index(n) for n in design.sensors]
        self.idx_z = [AUX_NAMES.index(n) for n in design.aux]

    def initial_state(self) -> np.ndarray:
        """A-priori states [B, 4] at k = 0: the nominal engine's steady state at the
        first sample's condition and fuel flow (the filter knows no health)."""
        ss = steady_state(self.env[0], wf=self.u[0, :, 0], health=np.zeros(N_HEALTH),
                          design=self.d)
        B = self.u.shape[1]
        self.z_unknown = ss.inner.reshape(B, 5).copy()
        return ss.x.reshape(B, 4).copy()

    def __call__(self, k: int, x: np.ndarray, d: np.ndarray) -> PlantEvaluation:
        B = x.shape[0]
        h = np.zeros((B, N_HEALTH))
        h[:, :_TURBO] = d @ self.vp.T  # seed 002 eq. 11
        op = operating(x, self.u[k], self.env[k], h)
        if self.z_unknown is None:
            self.initial_state()
        assert self.z_unknown is not None
        z0 = self.z_unknown
        if self.op_prev is not None:
            # The filter's correction and the new commands moved the states: move the
            # unknowns with them (dz/dv, kept with the chord Jacobian).
            z0 = self.solver.predict(z0, self.op_prev, op)
        self.z_unknown, st = self.solver.one_pass(op, z0)
        self.op_prev = op
        sensors, aux = outputs_from_stations(st, op)
        xdot = np.stack([st["dnf"], st["dnc"], st["dtm_hpc"], st["dtm_hpt"]], axis=1)
        cg = self.cg
        env = self.env[k]
        return PlantEvaluation(
            x + cg.dt * xdot, sensors[:, self.idx_y], aux[:, self.idx_z],
            cg.trim_x * _correction(STATE_NAMES, env),
            cg.trim_y * _correction(cg.sensors, env),
            cg.trim_z * _correction(cg.aux, env),
        )


def filter_flights(
    design: CgekfDesign,
    y: np.ndarray,
    u: np.ndarray,
    env: np.ndarray,
    z_true: np.ndarray | None = None,
    engine: EngineDesign | None = None,
) -> CgekfResult:
    """The CGEKF over recorded flights of the built-in engine, batched.

    y [T, B, ny] measured sensors (``design.sensors``, engine units), u [T, B, 3]
    commands, env [T, B, 3] (alt ft, Mach, dTamb K), sampled every ``design.dt``;
    z_true [T, B, nz] optional aux truth. Starts from the nominal engine's steady
    state at the first sample with zero tuners. One engine (B = 1) runs on the
    float path ``filter_one``.
    """
    if np.shape(y)[1:2] == (1,):  # one engine: the float path (same recursion, faster)
        res, _ = filter_one(design, np.asarray(y, float)[:, 0], np.asarray(u, float)[:, 0],
                            np.asarray(env, float)[:, 0], engine=engine)
        if z_true is not None:
            zt = np.asarray(z_true, float)
            res = res._replace(z_residual=100.0 * (res.z_hat - zt) / zt)
        return res
    plant = EnginePlant(design, u, env, engine)
    x0 = plant.initial_state()
    return run_cgekf(design, plant, y, x0, z_true=z_true)


def filter_one(
    design: CgekfDesign,
    y: np.ndarray,
    u: np.ndarray,
    env: np.ndarray,
    d0: np.ndarray | None = None,
    state: Mapping[str, Any] | None = None,
    x0: np.ndarray | None = None,
    engine: EngineDesign | None = None,
) -> tuple[CgekfResult, dict[str, Any]]:
    """``run_cgekf`` with ``EnginePlant`` for one engine, on Python floats.

    One engine batched as B = 1 spends its time in numpy's per-call overhead on
    one-element arrays; here the same recursion (module docstring) runs with the
    scalar gas path of the transient simulator (``transient_one.ScalarGasPath``,
    the same chord steps, thresholds and Jacobian refresh cycle as
    ``transient._GasPathSolver``) and the gain applied as nested lists, so it
    equals the batched run to rounding.

    y [T, ny], u [T, 3], env [T, 3] as in ``filter_flights`` for one engine;
    d0 [m] a-priori tuners (default 0); state: the plant state returned by a
    previous call, to continue a recording, with x0 [4] its a-priori states
    (``result.x_next[0]``); without it, the nominal engine's steady state at the
    first sample. Returns the result (arrays [T, 1, ...]) and the plant state after
    the last sample, JSON-ready: gas-path unknowns ``z``, chord Jacobian inverse
    ``jinv`` and sensitivities ``dzdu``, ``dkdv``, the refresh cycle's ``calls``
    and the states, commands and environment of the last sample ``prev``.
    Continuing from it gives bit for bit what an uninterrupted call gives.
    """
    from operator import mul

    from estimation.engine.atmosphere import LBM, RANKINE
    from estimation.engine.transient import (
        _CHORD_MAX,
        _CHORD_POLISH,
        _CHORD_TOL,
        _FD_EPS,
        _ONE_PASS_LIMIT,
        _REFRESH_EVERY,
    )
    from estimation.engine.transient_one import ScalarGasPath, _operating
    from estimation.engine.xp import SCALAR

    y = np.asarray(y, float)
    u = np.asarray(u, float)
    env = np.asarray(env, float)
    ny = len(design.sensors)
    if y.ndim != 2 or y.shape[1] != ny:
        raise DimensionError(f"y must be [n_steps, {ny}] for one engine, found {y.shape}")
    T = y.shape[0]
    red = design.reduced
    nx, m = red.n_states, red.n_tuners
    nz = red.F.shape[0]
    eng = engine or engine_design()
    solver = ScalarGasPath(eng, [0.0] * N_HEALTH, _CHORD_TOL, _CHORD_POLISH, _CHORD_MAX,
                           _ONE_PASS_LIMIT, _REFRESH_EVERY, _FD_EPS)
    d = [0.0] * m if d0 is None else [float(v) for v in np.reshape(d0, m)]
    prev_op: Operating | None = None
    if state is None:
        plant = EnginePlant(design, u[:1, None, :], env[:1, None, :], eng)
        x = plant.initial_state()[0].tolist()
        assert plant.z_unknown is not None
        z = plant.z_unknown[0].tolist()
    else:
        if x0 is None:
            raise DimensionError("x0 (the a-priori states) must come with a plant state")
        x = [float(v) for v in np.reshape(x0, nx)]
        z = [float(v) for v in np.reshape(state["z"], 5)]
        if state["jinv"] is not None:
            solver.jinv = [[float(v) for v in row] for row in np.reshape(state["jinv"], (5, 5))]
        solver.dzdu = [[float(v) for v in row] for row in np.reshape(state["dzdu"], (5, 7))]
        solver.dkdv = [[float(v) for v in row] for row in np.reshape(state["dkdv"], (4, 7))]
        solver.calls = int(state["calls"])
        if state["prev"] is not None:
            px, pu, pe = (np.reshape(a, -1).tolist() for a in state["prev"])
            prev_op = _operating(px[0], px[1], px[2] / RANKINE, px[3] / RANKINE, pu[0] * LBM,
                                 pu[1], pu[2], flight_condition(pe[0], pe[1], pe[2], SCALAR))
    # Constants of the loop as lists: the gain rows (a-posteriori gain K, a-priori gain
    # K_pred, aux gain F K) and V*^+ without its zeros. The products are summed in Python, in
    # a fixed order: a BLAS product of a small matrix may round differently from call to call
    # (with the vector's memory alignment), and a continued recording must equal one run.
    KK = np.vstack([design.K, design.K_pred, red.F @ design.K]).tolist()
    n = nx + m
    Vp = [[(j, v) for j, v in enumerate(row) if v != 0.0] for row in red.vstar_pinv.tolist()]

    def health(d: list[float]) -> list[float]:
        return [sum([v * d[j] for j, v in row]) for row in Vp]

    dt = design.dt
    idx_y = [SENSOR_NAMES.index(n) for n in design.sensors]
    idx_z = [AUX_NAMES.index(n) for n in design.aux]

    def exponents(names: Sequence[str], trims: np.ndarray) -> list[tuple[float, float, float]]:
        return [(float(t), *CORRECTION.get(n, (0.0, 0.0))) for n, t in zip(names, trims,
                                                                          strict=True)]

    cx = exponents(STATE_NAMES, design.trim_x)
    cy = exponents(design.sensors, design.trim_y)
    cz = exponents(design.aux, design.trim_z)
    prev: tuple[list[float], list[float], list[float]] | None = None
    out_d, out_x, out_y, out_z, out_r = [], [], [], [], []
    yl, ul, el = y.tolist(), u.tolist(), env.tolist()
    pad = [0.0] * (N_HEALTH - _TURBO)
    last_e: list[float] | None = None
    fc: Any = None
    sx = sy = sz = [0.0]
    h = health(d)
    for k in range(T):
        # seed 002 eq. 11: the ten component health parameters h = V*^+ d, percent.
        solver.hs = [v / 100.0 for v in h] + pad
        uk, ek = ul[k], el[k]
        if ek != last_e:  # the condition and the corrected scales (constant in level flight)
            fc = flight_condition(ek[0], ek[1], ek[2], SCALAR)
            th, de = fc.theta, fc.delta
            sx = [t * th**a * de**b for t, a, b in cx]
            sy = [t * th**a * de**b for t, a, b in cy]
            sz = [t * th**a * de**b for t, a, b in cz]
            last_e = ek
        op = _operating(x[0], x[1], x[2] / RANKINE, x[3] / RANKINE, uk[0] * LBM, uk[1], uk[2],
                        fc)
        if prev_op is not None:
            z = solver.predict(z, prev_op, op)
        z, st = solver.one_pass(op, z)
        prev_op, prev = op, (x, uk, ek)
        sensors, aux = outputs_from_stations(st, op, SCALAR)
        yk = yl[k]
        y_hat = [sensors[i] for i in idx_y]
        r = [100.0 * (a - b) / c for a, b, c in zip(yk, y_hat, sy, strict=True)]
        rc = [0.0 if v != v else v for v in r]  # a sensor that did not report: no correction
        g = [sum(map(mul, row, rc)) for row in KK]  # seed 001 eq. 4: K r, K_pred r, F K r
        out_r.append(r)
        out_x.append([x[i] + sx[i] / 100.0 * g[i] for i in range(nx)])
        out_d.append([d[i] + g[nx + i] for i in range(m)])
        out_y.append(y_hat)
        out_z.append([aux[idx_z[i]] + sz[i] / 100.0 * g[2 * n + i] for i in range(nz)])
        xdot = (st["dnf"], st["dnc"], st["dtm_hpc"], st["dtm_hpt"])
        x = [x[i] + dt * xdot[i] + sx[i] / 100.0 * g[n + i] for i in range(nx)]
        d = [d[i] + g[n + nx + i] for i in range(m)]
        h = health(d)

    def arr(rows: list[Any], width: int) -> np.ndarray:
        return np.array(rows, float).reshape(T, 1, width)

    d_hat = arr(out_d, m)
    z_hat = arr(out_z, nz)
    result = CgekfResult(d_hat, d_hat @ red.vstar_pinv.T, arr(out_x, nx), arr(out_y, ny), z_hat,
                         arr(out_r, ny), np.full_like(z_hat, np.nan), design.sensors,
                         design.aux, design.tuners, np.array([x]), np.array([d]))
    jinv = solver.jinv
    new_state = {"z": [list(z)], "jinv": None if jinv is None else [jinv],
                 "dzdu": [solver.dzdu], "dkdv": [solver.dkdv], "calls": solver.calls,
                 "prev": [[list(a)] for a in prev] if prev is not None
                 else None if state is None else state["prev"]}
    return result, new_state
