"""Stream filter: 1000 engines x 2000 steps, 8 states (2 spools + 6 tuners), 6 sensors.

Compares, in one run:
  ours        estimation.kalman.filter_stream_states (steady-state gain, batched)
  numpy       plain closed-loop recursion, one matrix product per step over the
              batch: [x | y_k] @ [Phi^T; K^T] into a preallocated buffer
  filterpy    KalmanFilter predict/update loop per engine (subset, scaled to 1000)
  simdkalman  batch Kalman filter (subset, scaled to 1000)

Target: ours within 1.5x of plain numpy. Also checks that all four agree on the
estimates (filterpy and simdkalman start from the steady-state covariance, so
their gains equal ours from the first step).

Run from the repository root:  .venv/bin/python bench/bench_stream_filter.py
"""

from __future__ import annotations

import argparse

import numpy as np
import simdkalman
from _common import best_time, reference_design
from filterpy.kalman import KalmanFilter

from estimation.kalman import filter_stream_states


def plain_numpy(PhiT: np.ndarray, KT: np.ndarray, y: np.ndarray) -> np.ndarray:
    T, E, ny = y.shape
    n = PhiT.shape[0]
    W = np.vstack([PhiT, KT])  # [n + ny, n]
    buf = np.zeros((E, n + ny))
    out = np.empty((T, E, n))
    for k in range(T):
        buf[:, n:] = y[k]
        np.matmul(buf, W, out=out[k])
        buf[:, :n] = out[k]
    return out


def filterpy_run(A, C, Q, R, P0, y_engine: np.ndarray) -> np.ndarray:
    """x_hat per step for one engine with filterpy's predict/update (a-posteriori)."""
    n, ny = A.shape[0], C.shape[0]
    kf = KalmanFilter(dim_x=n, dim_z=ny)
    kf.F, kf.H, kf.Q, kf.R = A.copy(), C.copy(), Q.copy(), R.copy()
    kf.x = np.zeros(n)
    kf.P = P0.copy()  # prior at step 0 = steady-state prior: constant gain
    out = np.empty((y_engine.shape[0], n))
    # filterpy updates then predicts; ours predicts from x_hat[-1] = 0 then updates,
    # and with x = 0 the first prediction is 0 either way.
    for k in range(y_engine.shape[0]):
        if k > 0:
            kf.predict()
        kf.update(y_engine[k])
        out[k] = kf.x
    return out


def simdkalman_run(A, C, Q, R, P0, y_em: np.ndarray) -> np.ndarray:
    """Filtered means [E, T, n] with simdkalman (engine-major data)."""
    kf = simdkalman.KalmanFilter(A, Q, C, R)
    # simdkalman's initial value is the prior of step 0, like ours.
    r = kf.compute(
        y_em, 0, initial_value=np.zeros(A.shape[0]), initial_covariance=P0,
        smoothed=False, filtered=True, states=True, covariances=False, observations=False,
    )
    return r.filtered.states.mean


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engines", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--filterpy-engines", type=int, default=3)
    ap.add_argument("--simdkalman-engines", type=int, default=100)
    args = ap.parse_args()

    model, noise, design = reference_design()
    red = design.reduced
    A, C, K = red.A, red.C, design.gain
    n, ny = A.shape[0], C.shape[0]
    E, T = args.engines, args.steps
    rng = np.random.default_rng(0)
    y = rng.standard_normal((T, E, ny)) * model.sensor_noise_std + rng.normal(0, 1, (E, ny))
    Phi = (np.eye(n) - K @ C) @ A
    PhiT, KT = np.ascontiguousarray(Phi.T), np.ascontiguousarray(K.T)
    steps = E * T
    print(f"stream filter: {E} engines x {T} steps, {n} states, {ny} sensors")

    t_ours = best_time(lambda: filter_stream_states(A, C, K, y))
    t_np = best_time(lambda: plain_numpy(PhiT, KT, y))
    ours = filter_stream_states(A, C, K, y)
    ref = plain_numpy(PhiT, KT, y)
    diff_np = float(np.max(np.abs(ours - ref)))

    fe = min(args.filterpy_engines, E)
    fp_out = []
    t_fp_sub = best_time(
        lambda: fp_out.append(
            [filterpy_run(A, C, red.Q, model.R, design.P_prior, y[:, e]) for e in range(fe)]
        ),
        repeat=1,
    )
    t_fp = t_fp_sub * E / fe
    diff_fp = float(np.max(np.abs(np.stack(fp_out[-1], axis=1) - ours[:, :fe])))

    se = min(args.simdkalman_engines, E)
    y_em = np.ascontiguousarray(y[:, :se].transpose(1, 0, 2))
    sk_out = []
    t_sk_sub = best_time(
        lambda: sk_out.append(simdkalman_run(A, C, red.Q, model.R, design.P_prior, y_em)),
        repeat=1,
    )
    t_sk = t_sk_sub * E / se
    diff_sk = float(np.max(np.abs(sk_out[-1].transpose(1, 0, 2) - ours[:, :se])))

    def row(name: str, t: float, note: str = "") -> None:
        print(
            f"  {name:<11} {t:9.4f} s  {1e6 * t / steps:8.4f} us/engine-step  "
            f"{t / t_np:8.2f}x numpy  {note}"
        )

    row("ours", t_ours, f"max |diff| vs numpy {diff_np:.1e}")
    row("numpy", t_np)
    row("filterpy", t_fp, f"({fe} engines scaled; max |diff| {diff_fp:.1e})")
    row("simdkalman", t_sk, f"({se} engines scaled; max |diff| {diff_sk:.1e})")
    ok = t_ours <= 1.5 * t_np
    print(f"target ours <= 1.5x numpy: {t_ours / t_np:.2f}x -> {'PASS' if ok else 'FAIL'}")
    print(f"filterpy / ours = {t_fp / t_ours:.0f}x, simdkalman / ours = {t_sk / t_ours:.0f}x")


if __name__ == "__main__":
    main()
