"""Optimal tuner search and combined sensor + tuner selection (seed 003).

  1. optimal tuners, 10 health parameters, 6 sensors, 6 tuners: target <= 2 s.
     Peer in the same run: scipy BFGS over the full 6 x 10 V* with scipy's
     Schur DARE and Lyapunov solver per evaluation and scipy's own
     finite-difference gradient (the straightforward implementation), from the
     same start; its time and the SSEE it reaches are printed.
  2. combined sensor and tuner selection: base suite of 5 sensors plus every
     subset of 6 optional ones (64 suites), each with best-subset and optimal
     tuners: target <= 60 s. Prints seed 003's table (SSEE against number of
     sensors, subset against optimal tuners).
  3. the same on the built-in engine's cruise model (35,000 ft, Mach 0.8, cruise
     power; 4 states with metal temperatures, first 10 health parameters): base
     Nf, Nc, T24, Ps30, T48 plus every subset of T30, P24, T50, P50, P15, P30
     (P30 with Ps30 and T30 makes some suites redundant: their m = n_y tuners are
     unobservable and they drop out). Target <= 60 s. Peer in the same run: each
     suite designed on its own from its best subset/SVD start (no start carried
     over from neighbouring suites).

Run from the repository root:  .venv/bin/python bench/bench_tuner_search.py
"""

from __future__ import annotations

import argparse
import itertools
import time

import _common  # noqa: F401  (pins BLAS threads)
import numpy as np
import scipy.optimize
from _common import ROOT  # noqa: F401  (puts the repository on sys.path)

from estimation import evaluate, tuners
from estimation.errors import UnobservableDesignError
from estimation.theory import error_problem
from tests.estimation.models import reference_model, reference_noise

BASE = ["Nf", "Nc", "T24", "Ps30", "T48"]
OPTIONAL = ["T30", "P24", "T50", "P50", "P15", "T15"]


def scipy_peer(model, noise, V0: np.ndarray, max_seconds: float) -> tuple[float, float, int]:
    """BFGS on flattened V* with one scipy DARE + Lyapunov solve per evaluation."""
    m, p = V0.shape
    count = 0
    t0 = time.perf_counter()

    def f(v: np.ndarray) -> float:
        nonlocal count
        count += 1
        if time.perf_counter() - t0 > max_seconds:
            raise TimeoutError
        try:
            d = tuners.design_filter(model, v.reshape(m, p), noise["Q"], noise["Qh"], noise["Ph"])
        except (UnobservableDesignError, np.linalg.LinAlgError, ValueError):
            return 1e6
        return d.theory.ssee_health

    best = [f(V0.ravel())]

    def tracked(v: np.ndarray) -> float:
        val = f(v)
        best[0] = min(best[0], val)
        return val

    try:
        scipy.optimize.minimize(tracked, V0.ravel(), method="BFGS", options={"maxiter": 500})
    except TimeoutError:
        pass
    return time.perf_counter() - t0, best[0], count


def main() -> None:
    print(_common.load_line())
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer-seconds", type=float, default=60.0)
    ap.add_argument("--no-cruise-peer", action="store_true", help="skip the per-suite peer")
    args = ap.parse_args()

    model = reference_model()
    noise = reference_noise(model)
    problem = error_problem(model, noise["Q"], noise["Qh"], noise["Ph"])
    print("optimal tuner search: 10 health parameters, 6 sensors, 6 tuners")
    rng = np.random.default_rng(0)
    starts = [("best of subset/SVD", tuners._start(model, problem, 6))]
    starts += [(f"random start {i + 1}", rng.standard_normal((6, 10))) for i in range(2)]
    worst = 0.0
    for label, V0 in starts:
        start = tuners.design_filter(model, V0, **noise).theory.ssee_health
        t0 = time.perf_counter()
        design = tuners.optimal_tuners(model, 6, noise["Q"], noise["Qh"], noise["Ph"], start=V0)
        t_opt = time.perf_counter() - t0
        worst = max(worst, t_opt)
        t_peer, f_peer, n_peer = scipy_peer(model, noise, V0, args.peer_seconds)
        stopped = ", time limit" if t_peer >= args.peer_seconds else ""
        print(f"  {label}: SSEE at start {start:.4f}")
        print(f"    ours   {t_opt:8.3f} s  SSEE {design.theory.ssee_health:.4f}")
        print(
            f"    scipy  {t_peer:8.3f} s  SSEE {f_peer:.4f}  {n_peer} evaluations, "
            f"{t_peer / t_opt:.0f}x ours{stopped}"
        )
    print(f"target <= 2 s: slowest {worst:.3f} s -> {'PASS' if worst <= 2.0 else 'FAIL'}")

    big = reference_model(extra_sensors=6)
    big_noise = reference_noise(big)
    t0 = time.perf_counter()
    rows = evaluate.sensor_table(big, BASE, OPTIONAL, **big_noise)
    t_sel = time.perf_counter() - t0
    print(f"\ncombined sensor and tuner selection: {len(BASE)} base + 2^{len(OPTIONAL)} suites")
    print(f"  {'sensors':>7}  {'subset SSEE':>11}  {'optimal SSEE':>12}  optimal suite adds")
    for r in rows:
        added = [s for s in r.optimal_sensors if s not in BASE]
        print(f"  {r.n_sensors:7d}  {r.subset_ssee:11.2f}  {r.optimal_ssee:12.2f}  {added}")
    print(f"target <= 60 s: {t_sel:.1f} s -> {'PASS' if t_sel <= 60.0 else 'FAIL'}")
    cruise_selection(not args.no_cruise_peer)


CRUISE_BASE = ["Nf", "Nc", "T24", "Ps30", "T48"]
CRUISE_OPTIONAL = ["T30", "P24", "T50", "P50", "P15", "P30"]


def cruise_selection(with_peer: bool) -> None:
    from estimation.engine.linearize import linearize

    model = linearize(35000.0, 0.8, 85.0)  # cruise, as tests/estimation/test_evaluate.py
    model = model.select_health(model.health_names[:10])
    nx = model.n_states
    noise = {"Q": np.eye(nx) * 1e-4, "Qh": np.eye(10) * 1e-4, "Ph": np.eye(10) * 4.0}
    t0 = time.perf_counter()
    rows = evaluate.sensor_table(model, CRUISE_BASE, CRUISE_OPTIONAL, **noise)
    t_sel = time.perf_counter() - t0
    print(
        f"\ncruise model ({nx} states): {len(CRUISE_BASE)} base + 2^{len(CRUISE_OPTIONAL)} suites"
    )
    print(f"  {'sensors':>7}  {'subset SSEE':>11}  {'optimal SSEE':>12}  optimal suite adds")
    for r in rows:
        added = [s for s in r.optimal_sensors if s not in CRUISE_BASE]
        print(f"  {r.n_sensors:7d}  {r.subset_ssee:11.2f}  {r.optimal_ssee:12.2f}  {added}")
    if with_peer:
        t0 = time.perf_counter()
        per_suite = []
        for r in range(len(CRUISE_OPTIONAL) + 1):
            for extra in itertools.combinations(CRUISE_OPTIONAL, r):
                per_suite += tuners.sensor_selection(
                    model, CRUISE_BASE + list(extra), [], **noise
                )
        t_peer = time.perf_counter() - t0
        best_peer = tuners.best_suites(per_suite)
        worst = max(
            (best_peer[r.n_sensors].optimal_objective - r.optimal_ssee)
            / best_peer[r.n_sensors].optimal_objective
            for r in rows
        )
        print(
            f"  per-suite peer {t_peer:.1f} s ({t_peer / t_sel:.1f}x ours); "
            f"ours lower SSEE by up to {100 * worst:.3f} % per size"
        )
    print(f"target <= 60 s: {t_sel:.1f} s -> {'PASS' if t_sel <= 60.0 else 'FAIL'}")


if __name__ == "__main__":
    main()
