"""Fixed-step closed-loop transient simulation, vectorised over a batch of engines.

Every engine of the batch has its own health (13 parameters with the actuator
biases), its own flight (operating condition against time) and its own sensor
noise; one call steps them all together.

Integration (step dt, 15 ms by default, seed 002's update rate): the
controller samples the sensors at t_k and its commands are held over
[t_k, t_k+1) (zero-order hold, as a digital engine control does); the sample is
taken from the previous step's second stage, which sits at t_k to O(dt^2), so
it costs no extra evaluation. The plant is advanced by Heun's method
(explicit RK2) with the commands held:

    k1 = f(x_k, u_k, e(t_k)),  k2 = f(x_k + dt k1, u_k, e(t_k+1)),
    x_k+1 = x_k + dt/2 (k1 + k2).

The plant's eigenvalues lie between -0.005 and about -4 1/s over the envelope,
so |lambda dt| < 0.1 at 15 ms, well inside RK2's stability interval (-2, 0).
The gas path is quasi-steady: its five unknowns are re-solved at every stage
by a chord iteration (Newton with a Jacobian kept per engine and refreshed
only when the iteration slows), started from the previous stage's solution,
so a step costs two or three gas-path evaluations instead of a full Newton
solve with finite-difference Jacobians. The first stage starts from the
previous second stage (same time), the second from the first, each moved by
the change of states and commands through dz/dv = -J^-1 df/dv (kept with the
Jacobian, v = Nf, Nc, TMHPC, TMHPT, Wf, VSV, VBV), so that with sensor noise
(which moves the commands, hence k1, from step to step) the prediction stays
within the one-pass limit and full solves are rare.

In one-pass mode the first stage of a step that is not recorded is not
evaluated: the previous second stage sat at the same time, at x_k + O(dt^2)
and the previous commands, so k1 = k2_prev + dk/dv (v_k - v2_prev) with the
total sensitivity dk/dv = dk/dv|z + dk/dz dz/dv kept with the Jacobian (a
Jacobian-reusing first stage; the error is second order in the change, mostly
the command change of one step). A step then costs about one gas-path
evaluation; against the gas path converged at both stages it keeps every
sensor within 0.06 noise standard deviations through a slam to take-off
(tests/estimation/engine/test_transient_one.py).

Sensors are recorded at t_k, at the states and commands of the first stage.
Only recorded stages compute every station; the others stop at the state
derivatives and the sensors the controller reads.

A small batch (B <= FLOATS_BATCH) runs by default engine by engine on Python
floats (``transient_one.py``): the same cycle, control law, steps and noise on
the ``SCALAR`` namespace, about 15 times less CPU per engine than numpy on
one-element arrays, equal to rounding.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from estimation.engine.atmosphere import PSI, RANKINE, flight_condition
from estimation.engine.controller import (
    DEFAULT_GAINS,
    ControllerGains,
    ControllerState,
    control_step,
    initial_state,
)
from estimation.engine.design import EngineDesign, engine_design
from estimation.engine.errors import EngineConvergenceError
from estimation.engine.flight import FlightProfile, OperatingPoint, condition_at
from estimation.engine.health import N_HEALTH
from estimation.engine.sensors import SENSOR_NAMES
from estimation.engine.steady import steady_state
from estimation.engine.turbofan import (
    Operating,
    gas_path,
    operating,
    operating_variables,
    outputs_from_stations,
)

DT_DEFAULT = 0.015  # s, seed 002's update rate
# The sensors the controller reads.
_NF, _NC, _T24, _PS30 = (SENSOR_NAMES.index(n) for n in ("Nf", "Nc", "T24", "Ps30"))
# Gas-path solution per stage: rows whose relative flow mismatch exceeds
# _CHORD_POLISH get at least one chord correction, and corrections go on
# until it is below _CHORD_TOL. At rest the mismatch thus falls below 1e-12
# (the rest point is the steady-state solver's); in a transient one
# correction (contraction about 1e-3 per correction) usually suffices.
_CHORD_TOL = 2e-6
_CHORD_POLISH = 1e-12
_CHORD_MAX = 6
# One-pass mode: the unknowns are carried from stage to stage as fast states,
# relaxed by one chord correction per evaluation (a real-time engine model's
# "one iteration per pass"); at rest they converge to the balance. Rows whose
# mismatch at the prediction exceeds _ONE_PASS_LIMIT (a command kick) are
# solved to tolerance: sensors stay within a fifth of the smallest noise.
_ONE_PASS_LIMIT = 3e-4
_REFRESH_EVERY = 200
_FD_EPS = 1e-7
_N_SENS = 7  # sensitivities of the unknowns: 4 states and 3 commands
_DERIVATIVES = ("dnf", "dnc", "dtm_hpc", "dtm_hpt")
# Batches of at most this many engines run engine by engine on Python floats
# (``transient_one.py``): numpy's cost per step is mostly per call, nearly whatever the batch.
FLOATS_BATCH = 16

Schedule = Callable[[float], OperatingPoint]


class TransientResult(NamedTuple):
    """Recorded samples of a batch of B engines at T recorded times.

    time_s [T]; x [T, B, 4] states (Nf, Nc rpm; TMHPC, TMHPT degR); u [T, B, 3]
    commands (Wf pps, VSV %, VBV %); sensors [T, B, 12] true values; measured
    [T, B, 12] what the sensors read (with noise; equal to ``sensors`` without);
    aux [T, B, 6] (Fn lbf, T40 degR, stall margins %, BPR); condition: the
    operating condition, arrays [T, B]; limited [T, B] (-1 deceleration limit,
    +1 acceleration limit, 0 free). Names and units of sensors and aux in
    ``sensors.py`` (SENSOR_NAMES, AUX_NAMES).
    """

    time_s: np.ndarray
    x: np.ndarray
    u: np.ndarray
    sensors: np.ndarray
    measured: np.ndarray
    aux: np.ndarray
    condition: OperatingPoint
    limited: np.ndarray


class _GasPathSolver:
    """Chord iteration on the five gas-path unknowns, one Jacobian inverse per engine."""

    def __init__(self, design: EngineDesign, b: int) -> None:
        self.d = design
        self.jinv: np.ndarray | None = None
        self.dzdu = np.zeros((b, 5, _N_SENS))
        self.dkdv = np.zeros((b, 4, _N_SENS))
        self.b = b
        self.evaluations = 0
        self.calls = 0
        # Every station (a recorded sample) or only what the step needs.
        self.full = True

    def _refresh(self, op: Operating, z: np.ndarray, rows: np.ndarray) -> None:
        """Jacobians by forward differences in one stacked call: d residual / d z
        (kept inverted) and dz/dv = -J^-1 d residual / dv in the states and commands
        v = (Nf, Nc, TMHPC, TMHPT, Wf, VSV, VBV)."""
        n = z.shape[1]
        k = rows.size
        sub = op.take(rows)
        base = np.arange(k)
        m = n + 1
        stacked = sub.take(np.tile(base, m + _N_SENS))
        zs = np.concatenate([z[rows]] + [z[rows] + _FD_EPS * np.eye(n)[j] for j in range(n)]
                            + [z[rows]] * _N_SENS)
        dv = np.stack([_FD_EPS * np.maximum(np.abs(sub.nf), 1.0),
                       _FD_EPS * np.maximum(np.abs(sub.nc), 1.0),
                       _FD_EPS * np.maximum(np.abs(sub.tm_hpc), 1.0),
                       _FD_EPS * np.maximum(np.abs(sub.tm_hpt), 1.0),
                       _FD_EPS * np.maximum(np.abs(sub.wf), 1e-3),
                       np.full(k, 1e-4), np.full(k, 1e-4)], axis=1)
        fields = [f.copy() for f in operating_variables(stacked)]
        for c in range(_N_SENS):
            fields[c][(m + c) * k:(m + c + 1) * k] += dv[:, c]
        nf, nc, tm_hpc, tm_hpt, wf, vsv, vbv = fields
        stacked = stacked._replace(nf=nf, nc=nc, tm_hpc=tm_hpc, tm_hpt=tm_hpt, wf=wf,
                                   vsv=vsv, vbv=vbv)
        r_flat, st = gas_path(stacked, zs, self.d, stations=False)
        r = r_flat.reshape(m + _N_SENS, k, n)
        q = np.stack([st[name] for name in _DERIVATIVES], axis=-1).reshape(m + _N_SENS, k, 4)
        self.evaluations += 1
        jac = np.transpose((r[1:m] - r[0]) / _FD_EPS, (1, 2, 0))
        ru = np.transpose((r[m:] - r[0]) / dv.T[:, :, None], (1, 2, 0))  # [k, n, 7]
        kz = np.transpose((q[1:m] - q[0]) / _FD_EPS, (1, 2, 0))  # [k, 4, n]
        kv = np.transpose((q[m:] - q[0]) / dv.T[:, :, None], (1, 2, 0))  # [k, 4, 7]
        # The Jacobian is reused over many steps, so its inverse (5 x 5, well
        # conditioned: flows over design against betas and pressure ratios) is
        # kept rather than re-solving a factorisation each time.
        inv = np.linalg.inv(jac)
        if self.jinv is None:
            self.jinv = np.repeat(inv[:1], self.b, axis=0)
            self.dzdu = np.zeros((self.b, n, _N_SENS))
        self.jinv[rows] = inv
        dzdv = -np.einsum("bij,bjk->bik", inv, ru)
        self.dzdu[rows] = dzdv
        self.dkdv[rows] = kv + np.einsum("bij,bjk->bik", kz, dzdv)

    def derivatives_moved(self, k: np.ndarray, op_from: Operating, op_to: Operating
                          ) -> np.ndarray:
        """State derivatives k [B, 4] after a change of states and commands, on the
        balanced gas path: k + dk/dv (v_to - v_from), dk/dv = dk/dv|z + dk/dz dz/dv."""
        v0, v1 = operating_variables(op_from), operating_variables(op_to)
        dv = np.stack([b - a for a, b in zip(v0, v1, strict=True)], axis=1)
        return k + np.einsum("bij,bj->bi", self.dkdv, dv)

    def predict(self, z: np.ndarray, op_from: Operating, op_to: Operating) -> np.ndarray:
        """Unknowns after a change of states and commands: z + dz/dv (v_to - v_from)
        (the flight condition's drift over a step is left to the correction)."""
        if self.jinv is None:
            return z
        v0, v1 = operating_variables(op_from), operating_variables(op_to)
        dv = np.stack([b - a for a, b in zip(v0, v1, strict=True)], axis=1)
        return z + np.einsum("bij,bj->bi", self.dzdu, dv)

    def solve(self, op: Operating, z0: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Chord iterations until every row's mismatch is below _CHORD_TOL (at least one
        correction where it exceeds _CHORD_POLISH)."""
        z = z0.copy()
        if self.jinv is None:
            self._refresh(op, z, np.arange(self.b))
        res, st = gas_path(op, z, self.d, stations=self.full)
        self.evaluations += 1
        return self._converge(op, z, res, st, np.ones(self.b, dtype=bool))

    def _converge(
        self, op: Operating, z: np.ndarray, res: np.ndarray, st: dict[str, np.ndarray],
        rows_in: np.ndarray,
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        all_rows = np.arange(self.b)
        for it in range(_CHORD_MAX):
            err = np.max(np.abs(res), axis=1)
            bad = rows_in & ~(err <= (_CHORD_POLISH if it == 0 else _CHORD_TOL))
            if not bad.any():
                return z, st
            rows = all_rows[bad]
            if it >= 3:
                self._refresh(op, z, rows)
            assert self.jinv is not None
            z[rows] -= np.einsum("bij,bj->bi", self.jinv[rows], res[rows])
            if rows.size == self.b:
                res, st = gas_path(op, z, self.d, stations=self.full)
            else:
                res_b, st_b = gas_path(op.take(rows), z[rows], self.d, stations=self.full)
                res[rows] = res_b
                for key, val in st_b.items():
                    st[key][rows] = val
            self.evaluations += 1
        err = np.max(np.abs(res), axis=1)
        bad = np.flatnonzero(rows_in & ~(err <= _CHORD_TOL))
        if bad.size:
            raise EngineConvergenceError(
                f"gas path did not converge in the transient for engines {bad[:10].tolist()} "
                f"(max relative flow mismatch {err[bad].max():.2e})"
            )
        return z, st

    def one_pass(
        self, op: Operating, z0: np.ndarray
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Evaluate at z0 and return the chord-corrected unknowns for the next stage.

        The stations are those at z0 (flow mismatch of order the prediction
        error); rows further off than _ONE_PASS_LIMIT are solved to tolerance
        instead (row by row, so a batch gives each engine what it alone gets).
        The Jacobian is refreshed every _REFRESH_EVERY calls.
        """
        self.calls += 1
        if self.jinv is None or self.calls % _REFRESH_EVERY == 0:
            self._refresh(op, z0, np.arange(self.b))
        res, st = gas_path(op, z0, self.d, stations=self.full)
        self.evaluations += 1
        assert self.jinv is not None
        z = z0 - np.einsum("bij,bj->bi", self.jinv, res)
        far = np.max(np.abs(res), axis=1) > _ONE_PASS_LIMIT
        if far.any():
            z[far] = z0[far]
            z, st = self._converge(op, z, res, st, far)
        return z, st


def schedule_of(profile: FlightProfile) -> Schedule:
    """The operating condition against time of a batch of flights, as a schedule."""
    return lambda t: condition_at(profile, t)


def _broadcast(cond: OperatingPoint, b: int) -> OperatingPoint:
    return OperatingPoint(*(np.broadcast_to(np.asarray(c, float), (b,)) for c in cond))


def _env(cond: OperatingPoint) -> np.ndarray:
    return np.stack([cond.alt_ft, cond.mach, cond.dtamb_k], axis=-1)


def simulate(
    schedule: Schedule | FlightProfile,
    t_end: float,
    health: np.ndarray | None = None,
    dt: float = DT_DEFAULT,
    record_every: int = 1,
    noise_std: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
    gains: ControllerGains = DEFAULT_GAINS,
    design: EngineDesign | None = None,
    x0: np.ndarray | None = None,
    gas_path_solution: str = "one_pass",
    on_progress: Callable[[float], None] | None = None,
    scalar_path: bool = True,
) -> TransientResult:
    """Simulate a batch of engines in closed loop from rest at the schedule's start.

    schedule: a FlightProfile of B flights, or a function t -> OperatingPoint of
    arrays [B]. t_end [s]: the last step ends at or before t_end. health:
    [13] or [B, 13] percent (None: nominal). dt [s]: fixed step. record_every:
    keep every n-th step (t = 0, n dt, 2 n dt, ...). noise_std [12]: sensor
    noise standard deviations in sensor units; the controller then reads noisy
    sensors, as on the engine (rng required). Engines start at the steady state
    of their condition at t = 0 (steady-state solver, same health), with the
    controller holding it; x0 [4] or [B, 4] then replaces the states (a
    disturbed start). gas_path_solution: "converged" solves the gas path to a
    relative flow mismatch of 2e-6 at every stage; "one_pass" (default, about
    half the cost) evaluates it once per stage at the predicted unknowns and
    carries one chord correction to the next stage, so the mismatch is of the
    order of the prediction error in a transient and vanishes at rest.
    on_progress(fraction) is called every 1000 steps and at the end.
    scalar_path: a batch of at most FLOATS_BATCH engines runs the same cycle,
    control law, steps and noise engine by engine on Python floats
    (``transient_one.py``, an order of magnitude faster than numpy on small
    arrays; equal to rounding); False keeps it on numpy arrays.
    """
    if gas_path_solution not in ("converged", "one_pass"):
        raise ValueError(f"gas_path_solution must be 'converged' or 'one_pass', "
                         f"got {gas_path_solution!r}")
    d = design or engine_design()
    sched = schedule_of(schedule) if isinstance(schedule, FlightProfile) else schedule
    if dt <= 0 or record_every < 1:
        raise ValueError(f"dt must be positive and record_every >= 1, got {dt}, {record_every}")
    cond0 = sched(0.0)
    h_in = np.zeros(N_HEALTH) if health is None else np.asarray(health, dtype=float)
    b = max(max(int(np.size(c)) for c in cond0), int(np.atleast_2d(h_in).shape[0]))
    cond0 = _broadcast(cond0, b)
    h = np.broadcast_to(np.atleast_2d(h_in), (b, N_HEALTH)).copy()
    if noise_std is not None and rng is None:
        raise ValueError("noise_std needs rng (a numpy Generator)")

    ss = steady_state(_env(cond0), power=cond0.power_pct, health=h, design=d)
    x = ss.x.reshape(b, 4).copy()
    if x0 is not None:
        x = np.broadcast_to(np.asarray(x0, dtype=float), (b, 4)).copy()
    u = ss.u.reshape(b, 3).copy()
    z = ss.inner.reshape(b, 5).copy()
    ys = ss.sensors.reshape(b, -1)
    ctrl: ControllerState = initial_state(
        u[:, 0], ys[:, _NF], ys[:, _NC], ys[:, _T24], ys[:, _PS30], d
    )
    y_ctrl = ys.copy()  # what the controller samples at t_k, before its noise

    n_steps = int(np.floor(t_end / dt + 1e-9))
    n_rec = n_steps // record_every + 1
    ny = ys.shape[1]
    rec_t = np.round(np.arange(n_rec) * (record_every * dt), 9)  # clean decimal times
    rec_x = np.empty((n_rec, b, 4))
    rec_u = np.empty((n_rec, b, 3))
    rec_y = np.empty((n_rec, b, ny))
    rec_m = np.empty((n_rec, b, ny))
    rec_aux = np.empty((n_rec, b, ss.aux.reshape(b, -1).shape[1]))
    rec_cond = np.empty((4, n_rec, b))
    rec_lim = np.zeros((n_rec, b), dtype=np.int8)

    if b <= FLOATS_BATCH and scalar_path:
        from estimation.engine.transient_one import ScalarGasPath, run_engines, scalar_schedule

        solvers = [ScalarGasPath(d, (h[e] / 100.0).tolist(), _CHORD_TOL, _CHORD_POLISH,
                                 _CHORD_MAX, _ONE_PASS_LIMIT, _REFRESH_EVERY, _FD_EPS, engine=e)
                   for e in range(b)]
        ctrls = [ControllerState(float(ctrl.integrator[e]), ctrl.sensed[e].tolist())  # type: ignore[arg-type]
                 for e in range(b)]
        run_engines(
            [scalar_schedule(schedule, e) for e in range(b)], n_steps, dt, record_every,
            x.tolist(), z.tolist(), ys.tolist(), ctrls, noise_std, rng, gains, d, solvers,
            gas_path_solution == "one_pass",
            dict(x=rec_x, u=rec_u, y=rec_y, m=rec_m, aux=rec_aux, cond=rec_cond, lim=rec_lim),
            on_progress, (_NF, _NC, _T24, _PS30),
        )
        return TransientResult(
            rec_t, rec_x, rec_u, rec_y, rec_m, rec_aux, OperatingPoint(*rec_cond), rec_lim
        )
    solver = _GasPathSolver(d, b)
    solve = solver.one_pass if gas_path_solution == "one_pass" else solver.solve
    reuse = gas_path_solution == "one_pass"
    k2 = np.zeros((b, 4))  # the last second stage's derivatives
    z2 = z
    op2: Operating | None = None
    cond = cond_next = cond0
    for k in range(n_steps + 1):
        t = k * dt
        if k > 0:
            cond = cond_next
        noise = 0.0 if rng is None or noise_std is None else (
            rng.standard_normal(y_ctrl.shape) * noise_std
        )
        meas_ctrl = y_ctrl + noise
        fc = flight_condition(cond.alt_ft, cond.mach, cond.dtamb_k)
        ctrl, out = control_step(
            ctrl, cond.power_pct, cond.mach, fc.theta, fc.delta, meas_ctrl[:, _NF],
            meas_ctrl[:, _NC], meas_ctrl[:, _T24], meas_ctrl[:, _PS30], dt, gains, d,
        )
        u = out.u
        op = operating(x, u, _env(cond), h)
        recorded = k % record_every == 0
        solver.full = recorded
        if op2 is None or recorded or not reuse:
            # The last second stage sat at this time and nearly these states, with
            # the previous commands: start from it, moved by the change.
            z1, st = solve(op, z2 if op2 is None else solver.predict(z2, op2, op))
            base_z, base_op = z1, op
            k1 = np.stack([st["dnf"], st["dnc"], st["dtm_hpc"], st["dtm_hpt"]], axis=1)
        else:
            # One-pass, not recorded: the last second stage's derivatives and
            # unknowns moved to (x_k, u_k) through the kept sensitivities stand
            # for the first stage (no gas-path evaluation).
            # (The second stage's unknowns are predicted from that stage directly.)
            base_z, base_op = z2, op2
            k1 = solver.derivatives_moved(k2, op2, op)
        if recorded:
            y, aux = outputs_from_stations(st, op)
            i = k // record_every
            rec_x[i], rec_u[i], rec_y[i], rec_m[i], rec_aux[i] = x, u, y, y + noise, aux
            rec_cond[:, i] = cond
            rec_lim[i] = out.limited
        if on_progress is not None and (k % 1000 == 0 or k == n_steps):
            on_progress(k / max(n_steps, 1))
        if k == n_steps:
            break
        cond_next = _broadcast(sched(t + dt), b)
        op2 = operating(x + dt * k1, u, _env(cond_next), h)
        solver.full = False
        # The second stage differs from the first by dt k1 in the states only: the
        # unknowns move by dz/dx dt k1 (a noisy command moves k1, so extrapolating the
        # last step's stage-to-stage change in time would carry last step's noise).
        z2, st2 = solve(op2, solver.predict(base_z, base_op, op2))
        k2 = np.stack([st2["dnf"], st2["dnc"], st2["dtm_hpc"], st2["dtm_hpt"]], axis=1)
        x = x + 0.5 * dt * (k1 + k2)
        # The second stage sits at t_k+1 with x_k + dt k1 = x_k+1 + O(dt^2): its
        # sensors are the controller's next sample (commands applied without delay).
        y_ctrl[:, _NF], y_ctrl[:, _NC] = op2.nf, op2.nc
        y_ctrl[:, _T24], y_ctrl[:, _PS30] = st2["t24"] * RANKINE, st2["ps30"] / PSI
    return TransientResult(
        rec_t, rec_x, rec_u, rec_y, rec_m, rec_aux, OperatingPoint(*rec_cond), rec_lim
    )
