"""Speed of the built-in engine model: steady state, linearisation, evaluations.

Targets (issue 3): steady-state point <= 20 ms, linearisation <= 0.5 s. Peers
measured in the same run: scipy.optimize.root (hybr) on the same steady-state
equations, and one engine against a batch of 1000 for the model evaluation.

    .venv/bin/python bench/bench_engine.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import _common  # noqa: F401  (pins BLAS threads)
import numpy as np
from scipy.optimize import root

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation.engine.design import engine_design
from estimation.engine.linearize import linearize
from estimation.engine.schedule import build_schedule
from estimation.engine.steady import _guess, _operating, steady_state
from estimation.engine.turbofan import as_batch, evaluate, gas_path, operating


def best_of(fn, repeat: int = 5, number: int = 1) -> float:
    """Best wall time of ``repeat`` runs of ``number`` calls, per call [s]."""
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t) / number)
    return min(times)


def scipy_steady(env: np.ndarray, power: float) -> np.ndarray:
    """The same power-mode steady-state equations solved by scipy's hybr."""
    from estimation.engine.actuators import demanded_corrected_fan_speed
    from estimation.engine.atmosphere import flight_condition

    d = engine_design()
    fc = flight_condition(env[0], env[1], env[2])
    nf = demanded_corrected_fan_speed(power, d.nf, env[1]) * np.sqrt(fc.theta)
    h = np.zeros((1, 13))

    def fun(v: np.ndarray) -> np.ndarray:
        fcr = tuple(np.atleast_1d(a) for a in fc)
        op = _operating(fcr, h, np.atleast_1d(nf), np.atleast_1d(v[5] * d.nc),
                        np.atleast_1d(v[6] * d.wf))
        res, st = gas_path(op, v[None, :5], d, heat=False, scheduled_actuators=True)
        return np.concatenate([res[0], st["lp_balance"], st["hp_balance"]])

    v0 = _guess(np.atleast_1d(nf / np.sqrt(fc.theta) / d.nf), env[None], d)[0]
    sol = root(fun, v0, method="hybr", options={"xtol": 1e-12})
    if not sol.success:
        raise RuntimeError(sol.message)
    return sol.x


def main() -> None:
    print(_common.load_line())
    steady_state(np.zeros(3), power=100.0)  # builds the cached guess line once
    cruise = np.array([35000.0, 0.8, 0.0])
    print("engine model benchmark (best of 5)")
    t_ss = best_of(lambda: steady_state(cruise, power=85.0))
    t_ss_idle = best_of(lambda: steady_state(np.array([40000.0, 0.85, 0.0]), power=0.0))
    t_scipy = best_of(lambda: scipy_steady(cruise, 85.0))
    print(f"steady state, cruise 85 %:          {t_ss * 1e3:7.2f} ms  (target 20 ms: "
          f"{'PASS' if t_ss <= 0.020 else 'FAIL'}; scipy hybr peer {t_scipy * 1e3:.2f} ms, "
          f"ratio {t_scipy / t_ss:.1f}x)")
    print(f"steady state, 40 kft M0.85 idle:    {t_ss_idle * 1e3:7.2f} ms  (target 20 ms: "
          f"{'PASS' if t_ss_idle <= 0.020 else 'FAIL'})")
    envs = np.column_stack([np.linspace(0, 40000, 200), np.linspace(0, 0.85, 200),
                            np.zeros(200)])
    powers = np.linspace(0, 100, 200)
    t_ss_b = best_of(lambda: steady_state(envs, power=powers), repeat=3)
    print(f"steady state, batch of 200 points:  {t_ss_b * 1e3:7.2f} ms  "
          f"({t_ss_b / 200 * 1e3:.3f} ms per point, {t_ss / (t_ss_b / 200):.0f}x faster)")
    t_lin = best_of(lambda: linearize(35000.0, 0.8, 85.0))
    print(f"linearisation (trim + 80 points):   {t_lin * 1e3:7.2f} ms  (target 500 ms: "
          f"{'PASS' if t_lin <= 0.5 else 'FAIL'}, {t_lin / 0.5:.3f} of budget)")

    d = engine_design()
    ss = steady_state(cruise, power=85.0)
    for b in (1, 1000):
        x2, u2, e2, h2, _ = as_batch(np.tile(ss.x, (b, 1)), ss.u, ss.env, ss.health)
        op = operating(x2, u2, e2, h2)
        z = np.tile(ss.inner, (b, 1))
        t_gp = best_of(lambda op=op, z=z: gas_path(op, z, d), number=20)
        xp = np.tile(ss.x * 1.001, (b, 1))
        gz = np.tile(ss.inner, (b, 1))
        t_ev = best_of(lambda xp=xp, gz=gz: evaluate(xp, ss.u, ss.env, ss.health, guess=gz),
                       number=5)
        if b == 1:
            gp1, ev1 = t_gp, t_ev
        print(f"B={b:5d}: gas path {t_gp * 1e3:6.3f} ms ({t_gp / b * 1e6:7.2f} us/engine, "
              f"{gp1 * b / t_gp:6.1f}x vs one at a time); full evaluate with Newton "
              f"{t_ev * 1e3:6.2f} ms ({t_ev / b * 1e6:7.2f} us/engine, "
              f"{ev1 * b / t_ev:6.1f}x)")
    # A transient step: warm start and kept Jacobian (chord), tol 1e-8, one
    # evaluation per step of a 2500 s flight at 15 ms (an RK2 step takes two).
    steps = 2500.0 / 0.015
    for b in (1, 1000):
        xb = np.tile(ss.x, (b, 1))
        first = evaluate(xb, ss.u, ss.env, ss.health, guess=np.tile(ss.inner, (b, 1)),
                         with_jacobian=True)
        ub = np.tile(ss.u * np.array([1.005, 1.0, 1.0]), (b, 1))
        state = {"x": xb.copy(), "z": first.inner}

        def step(ub=ub, first=first, state=state) -> None:
            ev = evaluate(state["x"], ub, ss.env, ss.health, guess=state["z"],
                          jacobian_inv=first.jacobian_inv, tol=1e-8)
            state["z"] = ev.inner
            state["x"] = state["x"] + 0.015 * ev.xdot

        t_step = best_of(step, number=50)
        print(f"B={b:5d}: transient evaluation (chord) {t_step * 1e3:6.3f} ms per step, "
              f"{t_step / b * 1e6:7.2f} us/engine; 2500 s flight at 15 ms: "
              f"{t_step * steps / b:8.2f} s per engine (one evaluation per step)")
    t_sched = best_of(lambda: build_schedule(), repeat=1)
    print(f"schedule build, 125 nodes:          {t_sched:7.2f} s")


if __name__ == "__main__":
    main()
