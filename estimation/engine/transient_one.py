"""The closed-loop transient of ``transient.simulate`` for a small batch, engine by engine
on Python floats.

A small batch spends nearly all its time in numpy's per-call overhead (about
150 calls on small arrays per gas-path evaluation). Here the same
cycle (``turbofan.gas_path_columns``), atmosphere and control law
(``controller.control_step``) run with the ``SCALAR`` namespace of ``xp.py``,
and the integration, the chord iteration and its Jacobian refresh follow
``transient.simulate`` and its ``_GasPathSolver`` step by step, so the
trajectory of every engine equals its row of the batch to rounding, sensor noise
included (tests/estimation/engine/test_transient_one.py).
The 5 x 5 inverse Jacobian is applied as nested lists; it is computed with
numpy (one call per refresh).

Where ``math`` raises (a log or square root of a negative number, which only a
diverging iterate reaches) the evaluation is redone with numpy, which gives
nan and the batched path's convergence error.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable, Generator, Sequence
from typing import Any

import numpy as np

from estimation.engine.atmosphere import LBM, PSI, RANKINE, FlightCondition, flight_condition
from estimation.engine.controller import ControllerGains, ControllerState, scalar_control_law
from estimation.engine.design import EngineDesign
from estimation.engine.errors import EngineConvergenceError
from estimation.engine.flight import FlightProfile, OperatingPoint
from estimation.engine.turbofan import (
    Operating,
    gas_path,
    gas_path_columns,
    operating_variables,
    outputs_from_stations,
)
from estimation.engine.xp import SCALAR, SCALAR_ERRORS

Vector = list[float]


def _operating(*fields: Any) -> Operating:
    """Operating of one engine on floats: nf, nc, tm_hpc, tm_hpt, wf, vsv, vbv, fc
    (health is taken from the solver, not from here)."""
    return Operating(*fields, None)  # type: ignore[arg-type,call-arg]
_BLOCK = 1000  # steps the engines advance together (noise drawn, progress reported)
_DERIVATIVES = ("dnf", "dnc", "dtm_hpc", "dtm_hpt")


def _sensitivity_steps(op: Operating, eps: float) -> tuple[float, ...]:
    """Forward-difference steps in Nf, Nc, TMHPC, TMHPT, Wf (relative) and VSV, VBV
    (absolute, % open): the same as ``transient._GasPathSolver._refresh``."""
    return (eps * max(abs(float(op.nf)), 1.0), eps * max(abs(float(op.nc)), 1.0),
            eps * max(abs(float(op.tm_hpc)), 1.0), eps * max(abs(float(op.tm_hpt)), 1.0),
            eps * max(abs(float(op.wf)), 1e-3), 1e-4, 1e-4)
Stations = dict[str, Any]


def _change(a: Operating, b: Operating) -> tuple[float, ...]:
    """b - a in the gas path's states and commands (``operating_variables``' order)."""
    return (b.nf - a.nf, b.nc - a.nc, b.tm_hpc - a.tm_hpc, b.tm_hpt - a.tm_hpt,
            b.wf - a.wf, b.vsv - a.vsv, b.vbv - a.vbv)


def scalar_schedule(schedule: FlightProfile | Callable[[float], OperatingPoint], row: int = 0
                    ) -> Callable[[float], tuple[float, float, float, float]]:
    """Operating condition (alt ft, Mach, dTamb K, power %) of the batch's flight ``row``
    against time (a condition given for one flight holds for all of them).

    For a FlightProfile: ``flight.condition_at``'s interpolation on floats.
    """
    if not isinstance(schedule, FlightProfile):
        def call(t: float) -> tuple[float, float, float, float]:
            c = schedule(t)
            a, m, dt_, p = (_element(v, row) for v in c)
            return a, m, dt_, p
        return call
    ts = schedule.time_s.tolist()
    alt, mach, power = (v[min(row, v.shape[0] - 1)].tolist()
                        for v in (schedule.alt_ft, schedule.mach, schedule.power_pct))
    dtamb = _element(schedule.dtamb_k, row)
    last = len(ts) - 2

    def at(t: float) -> tuple[float, float, float, float]:
        tt = min(max(t, ts[0]), ts[-1])
        i = min(max(bisect_right(ts, tt) - 1, 0), last)
        w = (tt - ts[i]) / (ts[i + 1] - ts[i])
        return (alt[i] + w * (alt[i + 1] - alt[i]), mach[i] + w * (mach[i + 1] - mach[i]),
                dtamb, power[i] + w * (power[i + 1] - power[i]))
    return at


def _element(v: Any, row: int) -> float:
    flat = np.asarray(v, dtype=float).reshape(-1)
    return float(flat[row if flat.size > 1 else 0])


class ScalarGasPath:
    """``transient._GasPathSolver`` for one engine on floats (same steps and thresholds)."""

    def __init__(self, design: EngineDesign, hs: Vector,
                 chord_tol: float, chord_polish: float, chord_max: int,
                 one_pass_limit: float, refresh_every: int, fd_eps: float,
                 engine: int = 0) -> None:
        self.d = design
        self.engine = engine  # its row in the batch (error messages)
        self.hs = hs  # health / 100, floats
        self.jinv: list[Vector] | None = None
        self.dzdu: list[Vector] = [[0.0] * 7 for _ in range(5)]
        self.dkdv: list[Vector] = [[0.0] * 7 for _ in range(4)]
        self.tol, self.polish, self.max_iter = chord_tol, chord_polish, chord_max
        self.limit, self.every, self.eps = one_pass_limit, refresh_every, fd_eps
        self.calls = 0
        self.evaluations = 0
        # Every station (a recorded sample) or only what the step needs.
        self.full = True

    def evaluate(self, op: Operating, z: Vector, full: bool | None = None
                 ) -> tuple[Vector, Stations]:
        self.evaluations += 1
        try:
            return gas_path_columns(op, z, self.hs, self.d, True, False, SCALAR,
                                    self.full if full is None else full)
        except SCALAR_ERRORS:
            return self._numpy(op, z)

    def _numpy(self, op: Operating, z: Vector) -> tuple[Vector, Stations]:
        one: list[Any] = [np.array([v]) for v in op[:7]]
        fc = FlightCondition(*(np.array([v]) for v in op.fc))
        with np.errstate(all="ignore"):
            h = 100.0 * np.array([self.hs])  # [1, 13] percent
            res, st = gas_path(Operating(*one, fc, h), np.array([z]), self.d)  # type: ignore[call-arg,misc]
        return res[0].tolist(), {k: float(np.asarray(v).reshape(-1)[0]) for k, v in st.items()}

    def _refresh(self, op: Operating, z: Vector) -> None:
        """Forward-difference Jacobians in the unknowns and in the states and commands
        (Nf, Nc, TMHPC, TMHPT, Wf, VSV, VBV): J kept inverted, dz/dv = -J^-1 df/dv."""
        eps = self.eps
        r0, s0 = self.evaluate(op, z, False)
        k0 = [s0[n] for n in _DERIVATIVES]
        jac = np.empty((5, 5))
        kz = np.empty((4, 5))
        for j in range(5):
            zj = list(z)
            zj[j] = zj[j] + eps
            rj, sj = self.evaluate(op, zj, False)
            jac[:, j] = [(rj[i] - r0[i]) / eps for i in range(5)]
            kz[:, j] = [(sj[n] - k0[i]) / eps for i, n in enumerate(_DERIVATIVES)]
        steps = _sensitivity_steps(op, eps)
        ru = np.empty((5, 7))
        kv = np.empty((4, 7))
        for c in range(7):
            v = [float(a) for a in operating_variables(op)]
            v[c] += steps[c]
            rc, sc = self.evaluate(_operating(*v, op.fc), z, False)
            ru[:, c] = [(rc[i] - r0[i]) / steps[c] for i in range(5)]
            kv[:, c] = [(sc[n] - k0[i]) / steps[c] for i, n in enumerate(_DERIVATIVES)]
        inv = np.linalg.inv(jac)
        dzdv = -(inv @ ru)
        self.jinv = inv.tolist()
        self.dzdu = dzdv.tolist()
        self.dkdv = (kv + kz @ dzdv).tolist()

    def derivatives_moved(self, k: Vector, op_from: Operating, op_to: Operating) -> Vector:
        """State derivatives after a change of states and commands, on the balanced gas
        path: k + dk/dv (v_to - v_from), dk/dv = dk/dv|z + dk/dz dz/dv."""
        d0, d1, d2, d3, d4, d5, d6 = _change(op_from, op_to)
        k0, k1, k2, k3 = k
        g, h, e, f = self.dkdv  # rows written out: a loop over zip costs as much as the sums
        return [k0 + (g[0] * d0 + g[1] * d1 + g[2] * d2 + g[3] * d3 + g[4] * d4
                      + g[5] * d5 + g[6] * d6),
                k1 + (h[0] * d0 + h[1] * d1 + h[2] * d2 + h[3] * d3 + h[4] * d4
                      + h[5] * d5 + h[6] * d6),
                k2 + (e[0] * d0 + e[1] * d1 + e[2] * d2 + e[3] * d3 + e[4] * d4
                      + e[5] * d5 + e[6] * d6),
                k3 + (f[0] * d0 + f[1] * d1 + f[2] * d2 + f[3] * d3 + f[4] * d4
                      + f[5] * d5 + f[6] * d6)]

    def predict(self, z: Vector, op_from: Operating, op_to: Operating) -> Vector:
        """Unknowns after a change of states and commands: z + dz/dv (v_to - v_from),
        v = (Nf, Nc, TMHPC, TMHPT, Wf, VSV, VBV) (the flight condition's drift over a
        step is left to the correction)."""
        if self.jinv is None:
            return z
        d0, d1, d2, d3, d4, d5, d6 = _change(op_from, op_to)
        z0, z1, z2, z3, z4 = z
        g, h, e, f, c = self.dzdu
        return [z0 + (g[0] * d0 + g[1] * d1 + g[2] * d2 + g[3] * d3 + g[4] * d4
                      + g[5] * d5 + g[6] * d6),
                z1 + (h[0] * d0 + h[1] * d1 + h[2] * d2 + h[3] * d3 + h[4] * d4
                      + h[5] * d5 + h[6] * d6),
                z2 + (e[0] * d0 + e[1] * d1 + e[2] * d2 + e[3] * d3 + e[4] * d4
                      + e[5] * d5 + e[6] * d6),
                z3 + (f[0] * d0 + f[1] * d1 + f[2] * d2 + f[3] * d3 + f[4] * d4
                      + f[5] * d5 + f[6] * d6),
                z4 + (c[0] * d0 + c[1] * d1 + c[2] * d2 + c[3] * d3 + c[4] * d4
                      + c[5] * d5 + c[6] * d6)]

    def _chord(self, z: Vector, res: Vector) -> Vector:
        assert self.jinv is not None
        r0, r1, r2, r3, r4 = res
        z0, z1, z2, z3, z4 = z
        a, b, c, e, f = self.jinv
        return [z0 - (a[0] * r0 + a[1] * r1 + a[2] * r2 + a[3] * r3 + a[4] * r4),
                z1 - (b[0] * r0 + b[1] * r1 + b[2] * r2 + b[3] * r3 + b[4] * r4),
                z2 - (c[0] * r0 + c[1] * r1 + c[2] * r2 + c[3] * r3 + c[4] * r4),
                z3 - (e[0] * r0 + e[1] * r1 + e[2] * r2 + e[3] * r3 + e[4] * r4),
                z4 - (f[0] * r0 + f[1] * r1 + f[2] * r2 + f[3] * r3 + f[4] * r4)]

    def solve(self, op: Operating, z0: Vector) -> tuple[Vector, Stations]:
        z = list(z0)
        if self.jinv is None:
            self._refresh(op, z)
        res, st = self.evaluate(op, z)
        return self._converge(op, z, res, st)

    def _converge(self, op: Operating, z: Vector, res: Vector, st: Stations
                  ) -> tuple[Vector, Stations]:
        for it in range(self.max_iter):
            err = max(map(abs, res))
            if err <= (self.polish if it == 0 else self.tol):
                return z, st
            if it >= 3:
                self._refresh(op, z)
            z = self._chord(z, res)
            res, st = self.evaluate(op, z)
        err = max(map(abs, res))
        if not err <= self.tol:
            raise EngineConvergenceError(
                f"gas path did not converge in the transient for engines [{self.engine}] "
                f"(max relative flow mismatch {err:.2e})"
            )
        return z, st

    def one_pass(self, op: Operating, z0: Vector) -> tuple[Vector, Stations]:
        self.calls += 1
        if self.jinv is None or self.calls % self.every == 0:
            self._refresh(op, z0)
        res, st = self.evaluate(op, z0)
        if max(map(abs, res)) > self.limit:
            return self._converge(op, list(z0), res, st)
        return self._chord(z0, res), st


def run_engines(
    scheds: Sequence[Callable[[float], tuple[float, float, float, float]]],
    n_steps: int, dt: float, record_every: int,
    x: list[Vector], z: list[Vector], y_ctrl: list[list[Any]], ctrl: Sequence[ControllerState],
    noise_std: np.ndarray | None, rng: np.random.Generator | None,
    gains: ControllerGains, d: EngineDesign, solvers: Sequence[ScalarGasPath], one_pass: bool,
    rec: dict[str, np.ndarray], on_progress: Callable[[float], None] | None,
    idx: tuple[int, int, int, int],
) -> None:
    """The step loop of ``transient.simulate`` for a small batch, engine by engine on floats;
    fills the record arrays ``rec`` (keys x, u, y, m, aux, cond, lim, shapes as there).

    The engines advance together by blocks of ``_BLOCK`` steps: each block's sensor noise is
    drawn for all of them at once, [steps, B, 12], the same numbers in the same order as the
    batch path's one draw of [B, 12] per step, and exactly as many. on_progress(fraction) is
    called before every block and at the end.
    """
    b = len(scheds)
    noisy = rng is not None and noise_std is not None
    ns = np.broadcast_to(np.asarray(noise_std, float), (b, 12)) if noisy else None
    runs = [_engine_steps(e, scheds[e], n_steps, dt, record_every, x[e], z[e], y_ctrl[e],
                          ctrl[e], gains, d, solvers[e], one_pass, rec, idx)
            for e in range(b)]
    for run in runs:
        next(run)  # to its first block
    for start in range(0, n_steps + 1, _BLOCK):
        if on_progress is not None:
            on_progress(start / max(n_steps, 1))
        size = min(_BLOCK, n_steps + 1 - start)
        noise = None
        if noisy:
            assert rng is not None and ns is not None
            noise = rng.standard_normal((size, b, 12)) * ns
        for e, run in enumerate(runs):
            try:
                run.send(None if noise is None else noise[:, e])
            except StopIteration:
                pass
    if on_progress is not None:
        on_progress(1.0)


def _engine_steps(
    engine: int, sched: Callable[[float], tuple[float, float, float, float]],
    n_steps: int, dt: float, record_every: int,
    x: Vector, z: Vector, y_ctrl: list[Any], ctrl: ControllerState,
    gains: ControllerGains, d: EngineDesign, solver: ScalarGasPath, one_pass: bool,
    rec: dict[str, np.ndarray], idx: tuple[int, int, int, int],
) -> Generator[None, np.ndarray | None, None]:
    """One engine's steps, a generator: at the start of every block of ``_BLOCK`` steps it
    waits for the block's sensor noise [steps, 12] (None: none) and fills row ``engine`` of
    the records."""
    i_nf, i_nc, i_t24, i_ps30 = idx
    # The four sensors the controller reads (the rest of y_ctrl is not used).
    y_nf, y_nc, y_t24, y_ps30 = y_ctrl[i_nf], y_ctrl[i_nc], y_ctrl[i_t24], y_ctrl[i_ps30]
    solve = solver.one_pass if one_pass else solver.solve
    # One-pass: the first stage of a step that is not recorded reuses the last
    # second stage (moved by the sensitivities) instead of a gas-path evaluation.
    reuse = one_pass
    k2: Any = [0.0] * 4  # the last second stage's derivatives
    rec_x, rec_u, rec_y, rec_m = rec["x"], rec["u"], rec["y"], rec["m"]
    rec_aux, rec_cond, rec_lim = rec["aux"], rec["cond"], rec["lim"]
    half = 0.5 * dt
    z2 = z
    op2: Operating | None = None
    law = scalar_control_law(dt, gains, d)
    integ: float = ctrl.integrator  # type: ignore[assignment]
    sensed: Vector = ctrl.sensed  # type: ignore[assignment]
    cond = sched(0.0)
    fc: Any = flight_condition(cond[0], cond[1], cond[2], SCALAR)  # floats in the fields
    fc_key = cond[:3]  # the flight condition is recomputed only when these move
    block: np.ndarray | None = None
    noise_rows: list[Vector] = []
    for k in range(n_steps + 1):
        t = k * dt
        j = k % _BLOCK
        if j == 0:
            block = yield
            noise_rows = [] if block is None else block.tolist()
        if block is not None:
            noise = block[j]
            nz = noise_rows[j]
            m_nf, m_nc = y_nf + nz[i_nf], y_nc + nz[i_nc]
            m_t24, m_ps30 = y_t24 + nz[i_t24], y_ps30 + nz[i_ps30]
        else:
            noise = None
            m_nf, m_nc, m_t24, m_ps30 = y_nf, y_nc, y_t24, y_ps30
        integ, sensed, u, limited = law(integ, sensed, cond[3], cond[1], fc.theta, fc.delta,
                                        m_nf, m_nc, m_t24, m_ps30)
        wf = u[0] * LBM
        op = _operating(x[0], x[1], x[2] / RANKINE, x[3] / RANKINE, wf, u[1], u[2], fc)
        recorded = k % record_every == 0
        solver.full = recorded
        if op2 is None or recorded or not reuse:
            z1, st = solve(op, z2 if op2 is None else solver.predict(z2, op2, op))
            base_z, base_op = z1, op
            k1 = [st["dnf"], st["dnc"], st["dtm_hpc"], st["dtm_hpt"]]
        else:
            # The last second stage sat at this time, at x_k + O(dt^2) and the
            # previous commands: its derivatives and unknowns moved to (x_k, u_k)
            # through the kept sensitivities stand for the first stage.
            # (The second stage's unknowns are predicted from that stage directly.)
            base_z, base_op = z2, op2
            k1 = solver.derivatives_moved(k2, op2, op)
        if recorded:
            y, aux = outputs_from_stations(st, op, SCALAR)
            i = k // record_every
            rec_x[i, engine], rec_u[i, engine], rec_y[i, engine] = x, u, y
            rec_aux[i, engine] = aux
            rec_m[i, engine] = y if noise is None else np.add(y, noise)
            rec_cond[:, i, engine] = cond
            rec_lim[i, engine] = limited
        if k == n_steps:
            break
        cond = sched(t + dt)
        if cond[:3] != fc_key:
            fc = flight_condition(cond[0], cond[1], cond[2], SCALAR)
            fc_key = cond[:3]
        x0, x1, x2, x3 = x
        a0, a1, a2, a3 = k1
        xs = [x0 + dt * a0, x1 + dt * a1, x2 + dt * a2, x3 + dt * a3]
        op2 = _operating(xs[0], xs[1], xs[2] / RANKINE, xs[3] / RANKINE, wf, u[1], u[2], fc)
        solver.full = False
        # The second stage differs from the first by dt k1 in the states only: the
        # unknowns move by dz/dx dt k1 (a noisy command moves k1, so extrapolating the
        # last step's stage-to-stage change in time would carry last step's noise).
        z2, st2 = solve(op2, solver.predict(base_z, base_op, op2))
        k2 = [st2["dnf"], st2["dnc"], st2["dtm_hpc"], st2["dtm_hpt"]]
        b0, b1, b2, b3 = k2
        x = [x0 + half * (a0 + b0), x1 + half * (a1 + b1), x2 + half * (a2 + b2),
             x3 + half * (a3 + b3)]
        # The controller's next sample: the sensors it reads at the second stage.
        y_nf, y_nc = op2.nf, op2.nc
        y_t24, y_ps30 = st2["t24"] * RANKINE, st2["ps30"] / PSI
