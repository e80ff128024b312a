"""Snapshot filter throughput: engine-snapshots per second, batched over engines.

Compares, in one run (6 tuners, 6 sensors, 10 health parameters):
  ours        estimation.snapshot.snapshot_filter (sequential scalar updates,
              tuner-major layout, vectorised over engines)
  numpy       plain batched matrix-form update per snapshot: S = H P H^T + R,
              K = P H^T S^-1 by np.linalg.solve over the engine batch
  filterpy    KalmanFilter predict/update per engine (subset, scaled)

Target: ours >= 1e6 engine-snapshots per second. The estimates of all three
are compared.

Run from the repository root:  .venv/bin/python bench/bench_snapshot_filter.py
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import best_time, reference_design
from filterpy.kalman import KalmanFilter

from estimation.snapshot import SnapshotState, snapshot_filter


def plain_numpy(q0, P0, dy, H, Qq, R):
    """Batched matrix-form Kalman filter over snapshots: q [E, m], P [E, m, m]."""
    E, S, ny = dy.shape
    q, P = q0.copy(), P0.copy()
    out = np.empty((E, S, q.shape[1]))
    HT = H.T
    for j in range(S):
        P = P + Qq
        PHt = P @ HT  # [E, m, ny]
        Sm = H @ PHt + R  # [E, ny, ny]
        K = np.linalg.solve(Sm, np.swapaxes(PHt, 1, 2)).transpose(0, 2, 1)  # [E, m, ny]
        resid = dy[:, j] - q @ HT
        q = q + np.einsum("emn,en->em", K, resid)
        P = P - K @ np.swapaxes(PHt, 1, 2)
        P = 0.5 * (P + np.swapaxes(P, 1, 2))
        out[:, j] = q
    return out


def filterpy_run(q0, P0, dy_engine, H, Qq, R):
    m, ny = H.shape[1], H.shape[0]
    kf = KalmanFilter(dim_x=m, dim_z=ny)
    kf.F, kf.H, kf.Q, kf.R = np.eye(m), H.copy(), Qq.copy(), R.copy()
    kf.x, kf.P = q0.copy(), P0.copy()
    out = np.empty((dy_engine.shape[0], m))
    for j in range(dy_engine.shape[0]):
        kf.predict()
        kf.update(dy_engine[j])
        out[j] = kf.x
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engines", type=int, default=20000)
    ap.add_argument("--snapshots", type=int, default=100)
    ap.add_argument("--filterpy-engines", type=int, default=20)
    args = ap.parse_args()

    model, noise, design = reference_design()
    Gy, _ = model.steady_state_gains()
    V = design.vstar
    Vp = design.reduced.vstar_pinv
    m = V.shape[0]
    Qq = V @ noise["Qh"] @ V.T * 100.0  # a flight's worth of random walk
    P0 = V @ noise["Ph"] @ V.T
    E, S = args.engines, args.snapshots
    rng = np.random.default_rng(0)
    q_true = rng.multivariate_normal(np.zeros(m), P0, size=E)
    dy = (q_true @ (Gy @ Vp).T)[:, None, :] + rng.standard_normal(
        (E, S, model.n_sensors)
    ) * model.sensor_noise_std
    H = Gy @ Vp
    R = model.R
    n = E * S
    print(f"snapshot filter: {E} engines x {S} snapshots, {m} tuners, {model.n_sensors} sensors")

    def ours():
        # A fresh start state per run: the filter must not depend on earlier runs.
        state = SnapshotState.initial(E, P0)
        return snapshot_filter(state, dy, Gy, V, Qq, model.sensor_noise_std)

    q0 = np.zeros((E, m))
    P0E = np.broadcast_to(P0, (E, m, m)).copy()
    t_ours = best_time(ours)
    t_np = best_time(lambda: plain_numpy(q0, P0E, dy, H, Qq, R))
    res = ours()
    ref = plain_numpy(q0, P0E, dy, H, Qq, R)
    diff_np = float(np.max(np.abs(res.q_hat - ref)))
    fe = min(args.filterpy_engines, E)
    fp = []
    t_fp = best_time(
        lambda: fp.append([filterpy_run(q0[e], P0, dy[e], H, Qq, R) for e in range(fe)]),
        repeat=1,
    ) * E / fe
    diff_fp = float(np.max(np.abs(np.stack(fp[-1]) - res.q_hat[:fe])))

    for name, t, note in (
        ("ours", t_ours, f"max |diff| vs numpy {diff_np:.1e}"),
        ("numpy", t_np, ""),
        ("filterpy", t_fp, f"({fe} engines scaled; max |diff| {diff_fp:.1e})"),
    ):
        print(
            f"  {name:<9} {t:9.3f} s  {n / t:12.3e} engine-snapshots/s  "
            f"{t / t_ours:7.2f}x ours  {note}"
        )
    ok = n / t_ours >= 1e6
    print(f"target >= 1e6 engine-snapshots/s: {n / t_ours:.3e} -> {'PASS' if ok else 'FAIL'}")


if __name__ == "__main__":
    main()
