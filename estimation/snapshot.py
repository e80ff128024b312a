"""Snapshot-mode (ground-station) tuner filter (docs/math.md section 8).

Between snapshots the tuners follow a random walk; each snapshot is a
steady-state measurement scheduled on its own operating condition theta_j:

    q[j]  = q[j-1] + w_q,          w_q ~ N(0, s_j Q_q),  Q_q = V* Q_h V*^T
    dy[j] = G_y(theta_j) V*^+ q[j] + v[j],      v ~ N(0, diag(std_j^2))
    dy[j] = y[j] - y_trim(theta_j) - G_u(theta_j) du[j]   (percent of trim)

a time-varying Kalman filter over flights. Scheduling (G_y, trim, G_u as
functions of theta) stays with the caller, who passes the per-snapshot gains
as an array or a callable. Missing sensors (NaN in dy) are dropped from that
snapshot's update. Sensor noise is independent between sensors (diagonal R,
as in the model format). With one operating condition for the whole fleet at a
snapshot the update processes one sensor at a time on packed covariances (exact
for diagonal R, no matrix inverse); with gains per engine it is one joint update
per snapshot through batched ny x ny Cholesky factors. Both are vectorised over engines.

Arrays are engine-major: dy [n_engines, n_snapshots, ny].
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from estimation.errors import DimensionError
from estimation.stacked import SubstitutionPlan, cholesky_lower

SNAPSHOT_STATE_FORMAT = "fleethealth.snapshot-state/1"

GainSource = np.ndarray | Callable[[int], np.ndarray]


@dataclass(frozen=True, eq=False)
class SnapshotState:
    """Filter state per engine: q_hat [n_engines, m] and its covariance P [n_engines, m, m]."""

    q_hat: np.ndarray
    P: np.ndarray

    def __post_init__(self) -> None:
        q = np.array(self.q_hat, dtype=float, order="C")
        P = np.array(self.P, dtype=float, order="C")
        if q.ndim != 2:
            raise DimensionError(f"q_hat must be [n_engines, m], found shape {q.shape}")
        E, m = q.shape
        if P.shape != (E, m, m):
            raise DimensionError(
                f"Incompatible dimensions of P; expected ({E}, {m}, {m}) but found {P.shape}"
            )
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(P))):
            raise ValueError("snapshot state must be finite")
        object.__setattr__(self, "q_hat", q)
        object.__setattr__(self, "P", P)

    @classmethod
    def initial(cls, n_engines: int, P0: np.ndarray, q0: np.ndarray | None = None) -> SnapshotState:
        """Start state: q0 [m] or [n_engines, m] (default 0) with covariance P0 [m, m]
        (for example V* P_h V*^T, the fleet spread in tuner space)."""
        P0 = np.asarray(P0, float)
        m = P0.shape[0]
        q = np.zeros((n_engines, m)) if q0 is None else np.broadcast_to(q0, (n_engines, m))
        return cls(np.array(q), np.array(np.broadcast_to(P0, (n_engines, m, m))))

    @property
    def n_engines(self) -> int:
        return int(self.q_hat.shape[0])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (``fleethealth.snapshot-state/1``); floats survive a JSON round trip
        exactly (repr of a float is exact)."""
        return {
            "format": SNAPSHOT_STATE_FORMAT,
            "q_hat": self.q_hat.tolist(),
            "P": self.P.tolist(),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SnapshotState:
        if d.get("format") != SNAPSHOT_STATE_FORMAT:
            raise ValueError(
                f"format must be {SNAPSHOT_STATE_FORMAT!r}, found {d.get('format')!r}"
            )
        return cls(np.asarray(d["q_hat"], float), np.asarray(d["P"], float))

    def select(self, engines: np.ndarray | list[int]) -> SnapshotState:
        """State of a subset of engines (rows)."""
        idx = np.asarray(engines)
        return SnapshotState(self.q_hat[idx], self.P[idx])


class SnapshotResult(NamedTuple):
    """Per-snapshot a-posteriori estimates, engine-major.

    q_hat [E, S, m]; P [E, S, m, m] (None unless kept); h_hat [E, S, p] = V*^+ q_hat;
    h_std [E, S, p] (1-sigma, sqrt(diag(V*^+ P V*^+T)));
    innovation [E, S, ny] = dy - G_y V*^+ q_prior (NaN where the sensor was missing);
    state: the final SnapshotState.
    """

    q_hat: np.ndarray
    P: np.ndarray | None
    h_hat: np.ndarray
    h_std: np.ndarray
    innovation: np.ndarray
    state: SnapshotState


def snapshot_deviation(
    y: np.ndarray,
    y_trim: np.ndarray,
    G_u: np.ndarray | None = None,
    du: np.ndarray | None = None,
) -> np.ndarray:
    """dy = 100 (y - y_trim) / y_trim - G_u du (percent of trim; docs/math.md section 8).

    y, y_trim [..., ny] in engineering units; G_u [..., ny, nu]; du [..., nu] in percent.
    """
    y = np.asarray(y, float)
    y_trim = np.asarray(y_trim, float)
    dy = 100.0 * (y - y_trim) / y_trim
    if G_u is not None and du is not None:
        dy = dy - (np.asarray(G_u, float) @ np.asarray(du, float)[..., None])[..., 0]
    return dy


def tuner_pseudo_inverse(vstar: np.ndarray) -> np.ndarray:
    """V*^+ = V*^T (V* V*^T)^-1 [p, m] of V* [m, p], as the filter computes it (h = V*^+ q)."""
    V = np.asarray(vstar, float)
    return np.linalg.solve(V @ V.T, V).T


def tuner_measurement_matrix(G_y: np.ndarray, vstar: np.ndarray) -> np.ndarray:
    """H = G_y V*^+ [..., ny, m] of gains in health space G_y [..., ny, p]: the measurement
    matrix of the tuners that ``snapshot_filter`` updates with. Each snapshot's product is its
    own matrix product, so it is the same number whether taken record by record or laid out
    per engine and snapshot (``snapshot_filter(..., tuner_gains=...)``)."""
    return np.asarray(G_y, float) @ tuner_pseudo_inverse(vstar)


def snapshot_filter(
    state: SnapshotState,
    dy: np.ndarray,
    gains: GainSource | None,
    vstar: np.ndarray,
    Qq: np.ndarray,
    noise_std: np.ndarray,
    walk_scale: np.ndarray | float = 1.0,
    block: int = 1024,
    keep_covariance: bool = False,
    workers: int | None = None,
    tuner_gains: np.ndarray | None = None,
) -> SnapshotResult:
    """Time-varying tuner filter over snapshots, batched over engines (docs/math.md section 8).

    state     : SnapshotState, n_engines E, tuners m
    dy        : [E, S, ny] sensor deviations in percent of trim, NaN = missing
    gains     : G_y(theta_j) in health space, an array broadcastable to [E, S, ny, p],
                or a callable j -> array broadcastable to [E, ny, p] (the caller's
                operating-condition schedule)
    vstar     : V* [m, p]  (h_hat = V*^+ q_hat)
    Qq        : [m, m] tuner random-walk covariance per unit of walk_scale (V* Q_h V*^T)
    noise_std : sensor noise std, broadcastable to [E, S, ny] (percent of trim)
    walk_scale: broadcastable to [E, S]: multiplier of Qq before snapshot j (flights or
                hours since the previous snapshot; 0 for a second snapshot of the same
                steady state, and for padding rows whose dy are all NaN)

    block     : engines processed together (cache-sized; any value gives the same result)
    workers   : threads over engine blocks (default: the CPU count, at most 8); any
                value gives the same result
    keep_covariance: store P per snapshot (P in the result is None otherwise; the
                final P is always in ``state``)
    tuner_gains: H = G_y V*^+ per engine and snapshot [E, S, ny, m], computed by the
                caller (``tuner_measurement_matrix``, for instance record by record before
                the records are laid out) and read instead of multiplying ``gains`` laid
                out that way: the same numbers; ``gains`` is then not read

    Each snapshot: predict P += s_j Qq, then update with each present sensor in
    turn (scalar Kalman update, exact for diagonal R).
    """
    dy = np.asarray(dy, float)
    if dy.ndim != 3:
        raise DimensionError(f"dy must be [n_engines, n_snapshots, ny], found shape {dy.shape}")
    E, S, ny = dy.shape
    if E != state.n_engines:
        raise DimensionError(f"dy has {E} engines but the state has {state.n_engines}")
    V = np.asarray(vstar, float)
    m, p = V.shape
    if state.q_hat.shape[1] != m:
        raise DimensionError(f"state has {state.q_hat.shape[1]} tuners but V* has {m} rows")
    Vp = tuner_pseudo_inverse(V)  # V*^+ [p, m]
    if workers is None:
        workers = min(8, os.cpu_count() or 1)
    Qq = np.asarray(Qq, float)
    if Qq.shape != (m, m):
        raise DimensionError(
            f"Incompatible dimensions of Qq; expected ({m}, {m}) but found {Qq.shape}"
        )
    var = np.broadcast_to(np.asarray(noise_std, float) ** 2, (E, S, ny))
    scale = np.broadcast_to(np.asarray(walk_scale, float), (E, S))
    G_all: np.ndarray | None = None  # gains laid out per engine and snapshot
    HV_all: np.ndarray | None = None  # ... or their H V*^+ (``tuner_gains``)
    if tuner_gains is not None:
        HV_all = np.asarray(tuner_gains, float)
        if HV_all.shape != (E, S, ny, m):
            raise DimensionError(
                f"tuner_gains must be ({E}, {S}, {ny}, {m}), found {HV_all.shape}"
            )
    elif gains is None:
        raise ValueError("snapshot_filter needs gains or tuner_gains")
    elif callable(gains):
        gain_at = gains
    else:
        G_arr = np.asarray(gains, float)
        if G_arr.shape[-2:] != (ny, p):
            raise DimensionError(
                f"gains must end in ({ny}, {p}) (sensors, health), found {G_arr.shape}"
            )
        if G_arr.ndim == 2:  # one operating condition throughout

            def gain_at(j: int) -> np.ndarray:
                return G_arr

        elif G_arr.ndim == 3:  # [S, ny, p]: per snapshot, the same for every engine
            G_arr = np.broadcast_to(G_arr, (S, ny, p))

            def gain_at(j: int) -> np.ndarray:
                return G_arr[j]

        else:
            G_all = np.broadcast_to(G_arr, (E, S, ny, p))
            G_every = G_all

            def gain_at(j: int) -> np.ndarray:
                return G_every[:, j]

    # Tuner-major working layout per block of engines (q [m, B], P [m, m, B]): every
    # operation is a contiguous elementwise sweep over engines, and a block stays in
    # cache through the sensor loop.
    q_res = np.empty((E, S, m))
    P_res = np.empty((E, S, m, m)) if keep_covariance else None
    h_std = np.empty((E, S, p))
    innov = np.empty((E, S, ny))
    q_end = np.empty((E, m))
    P_end = np.empty((E, m, m))
    W_diag = (Vp[:, :, None] * Vp[:, None, :]).reshape(p, m * m)
    # Gains laid out per engine and snapshot are read per block (``run_block``).
    laid_out = G_all is not None or HV_all is not None
    G_steps = [] if laid_out else [np.asarray(gain_at(j), float) for j in range(S)]
    for j, G in enumerate(G_steps):
        if G.shape[-2:] != (ny, p):
            raise DimensionError(
                f"gains at snapshot {j}: expected (..., {ny}, {p}), found {G.shape}"
            )

    shared_all = not laid_out and all(G.ndim == 2 for G in G_steps)
    if shared_all:
        HV_steps = [G @ Vp for G in G_steps]  # [ny, m] per snapshot, fleet-wide
        packed = _PackedUpdate(m, Vp, Qq, HV_steps)

    def run_block(c0: int, c1: int) -> None:
        if shared_all:
            packed.run(
                c0, c1, state, dy, var, scale, q_res, P_res, h_std, innov, q_end, P_end
            )
            return
        # Per-engine gains: one joint update per snapshot, batched over the block's engines.
        # K = P H^T (H P H^T + R)^-1 with a missing sensor's row of H zeroed (its column of K
        # is then exactly zero): the same posterior as the scalar updates in turn, in a few
        # dozen array operations a snapshot instead of a dozen per sensor. H P H^T + R is
        # factored (one LAPACK Cholesky per matrix, cheaper than a general solve) and K applied
        # through the factor (``estimation.stacked``). Every product is
        # taken per engine and snapshot as for that snapshot alone (stacked products,
        # elementwise substitution), so a record's numbers do not depend on its block or run.
        Bn = c1 - c0
        q = state.q_hat[c0:c1].copy()  # [Bn, m]; always a copy: the state is not mutated
        P = state.P[c0:c1].copy()  # [Bn, m, m]
        sym = np.empty_like(P)
        dy_b, var_b, scale_b = dy[c0:c1], var[c0:c1], scale[c0:c1]
        # What does not depend on the recursion, for a window of the block's snapshots at
        # once (elementwise, the same numbers as snapshot by snapshot; about 8 MB a window):
        # the sensors present, the walk's covariance s_j Qq and, when the gains are laid out
        # per engine and snapshot, H V*^+ (the same stacked product as one snapshot's) with a
        # missing sensor's row zeroed.
        window = max(1, (8 << 20) // (8 * Bn * (m * m + 2 * ny * m + ny)))
        q_blk = q_res[c0:c1]
        innov_blk = innov[c0:c1]
        P_blk = P_res[c0:c1] if P_res is not None else None
        # After an engine's last snapshot with a sensor present or a walk (the padding rows of
        # an engine with fewer snapshots than the block's longest) a step leaves q and P as
        # they are, bit for bit: P += 0 Qq, no sensor gives K = 0, and P, symmetric, is its
        # own symmetrised value; the innovations are the NaN of the missing sensors. Each
        # step therefore updates only the engines up to the last one with a live snapshot
        # there (all of them unless the caller puts the shorter engines last).
        live = np.isfinite(dy_b).any(axis=2) | (scale_b != 0)  # [Bn, S]
        ends = (np.where(live.any(axis=1), S - np.argmax(live[:, ::-1], axis=1), 0) if S
                else np.zeros(Bn, dtype=np.int64))
        updated = np.zeros(S, dtype=np.int64)  # engines updated at each step: a prefix
        # The update's buffers and views per number of engines updated (``_StepSpace``).
        spaces: dict[int, _StepSpace] = {}
        for b in np.flatnonzero(ends):
            updated[: ends[b]] = b + 1
        n_updated = updated.tolist()
        # A singular H P H^T + R leaves NaN (raised below, as numpy's solve raises), not a
        # warning per snapshot.
        with np.errstate(invalid="ignore"):
            for j in range(S):
                w = j % window
                if w == 0:
                    w1 = min(S, j + window)
                    present_w = np.isfinite(dy_b[:, j:w1])  # [Bn, window, ny]
                    walk_w = scale_b[:, j:w1, None, None] * Qq  # [Bn, window, m, m]
                    if HV_all is not None:
                        HV_w = HV_all[c0:c1, j:w1]  # [Bn, window, ny, m]
                        Hm_w = HV_w * present_w[..., None]
                    elif G_all is not None:
                        HV_w = G_all[c0:c1, j:w1] @ Vp  # [Bn, window, ny, m]
                        Hm_w = HV_w * present_w[..., None]
                present = present_w[:, w]
                if laid_out:
                    HV, Hm = HV_w[:, w], Hm_w[:, w]
                else:
                    G = G_steps[j]
                    if G.ndim == 3:
                        G = np.broadcast_to(G, (E, ny, p))[c0:c1]
                    HV = np.broadcast_to(G @ Vp, (Bn, ny, m))  # [Bn, ny, m]
                    Hm = HV * present[:, :, None]  # [Bn, ny, m]
                nb = n_updated[j]
                if nb == Bn:
                    walk_j, dy_j = walk_w[:, w], dy_b[:, j]
                    var_j, innov_j = var_b[:, j], innov_blk[:, j]
                else:
                    innov_blk[nb:, j] = dy_b[nb:, j]  # NaN - HV q is the NaN
                    walk_j, dy_j = walk_w[:nb, w], dy_b[:nb, j]
                    var_j, innov_j = var_b[:nb, j], innov_blk[:nb, j]
                    HV, Hm, present = HV[:nb], Hm[:nb], present[:nb]
                if nb:
                    ws = spaces.get(nb)
                    if ws is None:
                        ws = spaces[nb] = _StepSpace(q[:nb], P[:nb], sym[:nb], ny)
                    ws.update(walk_j, HV, Hm, present, dy_j, var_j, innov_j)
                q_blk[:, j] = q
                if P_blk is not None:
                    P_blk[:, j] = P
                else:
                    # diag(V*^+ P V*^+T) = W vec(P), W[p, (a, b)] = Vp[p, a] Vp[p, b]: one GEMM
                    h_var = P.reshape(-1, m * m) @ W_diag.T
                    h_std[c0:c1, j] = np.sqrt(np.maximum(h_var, 0.0))
        if P_blk is not None and S:
            # The same GEMM rows for every snapshot of the block at once.
            h_var = (P_blk.reshape(-1, m * m) @ W_diag.T).reshape(Bn, S, p)
            h_std[c0:c1] = np.sqrt(np.maximum(h_var, 0.0))
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(P))):
            raise np.linalg.LinAlgError("Singular matrix")
        q_end[c0:c1] = q
        P_end[c0:c1] = P

    # Blocks are independent and write disjoint rows, so they may run on threads
    # (numpy releases the GIL inside its loops); the result does not depend on it.
    bounds = [(c0, min(E, c0 + block)) for c0 in range(0, E, block)]
    n_workers = max(1, min(workers, len(bounds)))
    if n_workers == 1:
        for c0, c1 in bounds:
            run_block(c0, c1)
    else:
        with ThreadPoolExecutor(max_workers=n_workers) as pool:
            for future in [pool.submit(run_block, c0, c1) for c0, c1 in bounds]:
                future.result()
    if S == 0:
        q_end, P_end = state.q_hat.copy(), state.P.copy()
    return SnapshotResult(
        q_res, P_res, q_res @ Vp.T, h_std, innov, SnapshotState(q_end, P_end)
    )


class _StepSpace:
    """The per-engine update of the first nb engines of a block (``q`` [nb, m], ``P``
    [nb, m, m] and ``sym``, a working array like P: views of the block's), snapshot after
    snapshot. Its working arrays and every view of them are made once, and the products are
    written into them with ``out`` (the same products, no allocation or indexing a snapshot):
    P H^T [nb, m, ny], the innovation covariance [nb, ny, ny] and its diagonal, the forward
    substitution (``SubstitutionPlan``), its result engines first [nb, ny, m + 1], the
    changes of q [nb, 1, m] and P [nb, m, m], and the predicted deviations H V*^+ q
    [nb, ny]."""

    def __init__(self, q: np.ndarray, P: np.ndarray, sym: np.ndarray, ny: int):
        nb, m = q.shape
        self.q, self.P, self.sym = q, P, sym
        self.P_T = P.transpose(0, 2, 1)
        self.Hq = np.empty((nb, ny))
        self.PHt = np.empty((nb, m, ny))
        self.PHt_T = self.PHt.transpose(2, 1, 0)  # [ny, m, nb], as the substitution takes it
        self.Sm = np.empty((nb, ny, ny))
        self.Sm_diag = self.Sm.reshape(nb, ny * ny)[:, :: ny + 1]
        self.plan = plan = SubstitutionPlan(ny, m + 1, nb)
        self.Y_HP, self.Y_r = plan.X[:, :m], plan.X[:, m]  # L^-1 [H P, resid], engines last
        self.Y_T = plan.X.transpose(2, 0, 1)
        self.Y_b = np.empty((nb, ny, m + 1))
        self.Y_P = self.Y_b[:, :, :m]
        self.Y_P_T = self.Y_P.transpose(0, 2, 1)
        self.Y_rb = self.Y_b[:, None, :, m]
        self.dq = np.empty((nb, 1, m))
        self.dq_rows = self.dq[:, 0]
        self.dP = np.empty((nb, m, m))

    def update(self, walk: np.ndarray, HV: np.ndarray, Hm: np.ndarray, present: np.ndarray,
               dy: np.ndarray, var: np.ndarray, innov: np.ndarray) -> None:
        """One snapshot of the nb engines: predict P += walk, write the innovations ``innov``
        = dy - HV q, then update q and P in place. HV [nb, ny, m] = H V*^+, Hm the same with a
        missing sensor's row zeroed, ``present`` [nb, ny]."""
        q, P = self.q, self.P
        add, subtract, multiply, matmul, copyto = (np.add, np.subtract, np.multiply,
                                                   np.matmul, np.copyto)
        # (Outputs given by position: the same operations, without parsing a keyword a call.)
        add(P, walk, P)
        subtract(dy, np.einsum("bim,bm->bi", HV, q, out=self.Hq), innov)
        PHt = matmul(P, Hm.transpose(0, 2, 1), self.PHt)  # [nb, m, ny]
        matmul(Hm, PHt, self.Sm)
        add(self.Sm_diag, var, self.Sm_diag)  # + R on the diagonal
        # Y = L^-1 [H P, resid] with Sm = L L^T, engines last: q += Y_P^T Y_r and
        # P -= Y_P^T Y_P (K = P H^T Sm^-1 through the factor).
        copyto(self.Y_HP, self.PHt_T)
        copyto(self.Y_r, np.where(present, innov, 0.0).T)
        plan = self.plan
        cholesky_lower(self.Sm, out=plan.L_stack)
        plan.run()
        # [nb, ny, m + 1], laid out alike whatever nb (the products' BLAS use).
        copyto(self.Y_b, self.Y_T)
        matmul(self.Y_rb, self.Y_P, self.dq)
        add(q, self.dq_rows, q)
        subtract(P, matmul(self.Y_P_T, self.Y_P, self.dP), P)
        add(P, self.P_T, self.sym)
        multiply(0.5, self.sym, P)


class _PackedUpdate:
    """Engine-block update for fleet-wide gains (one operating condition per snapshot for
    all engines, the ground-station batch), on packed covariances.

    P is stored as its upper triangle, Pp [T, B] with T = m (m + 1) / 2, so a
    covariance costs 21 numbers instead of 36 for m = 6 and stays symmetric by
    construction (no symmetrising pass). With h shared by the block, P h is one
    GEMM, Ph = M_h Pp with M_h [m, T] the map from packed P to P h, precomputed
    per snapshot and sensor; the rank-one downdate P - P h h^T P / s is, for
    each row a of the upper triangle (contiguous in Pp), Pp[row a] -= (P h)[a] k[a:].
    Same scalar sequential updates as the general path (exact for diagonal R).
    """

    def __init__(self, m: int, Vp: np.ndarray, Qq: np.ndarray, HV_steps: list[np.ndarray]):
        self.m = m
        self.ia, self.ib = np.triu_indices(m)
        starts = np.concatenate([[0], np.cumsum(np.arange(m, 0, -1))])
        self.rows = [(a, int(starts[a]), int(starts[a + 1])) for a in range(m)]
        T = self.ia.size
        t = np.arange(T)
        off = self.ia != self.ib
        self.Qp = np.ascontiguousarray(Qq[self.ia, self.ib])[:, None]  # [T, 1]
        # diag(V*^+ P V*^+T) from packed P: off-diagonal entries count twice.
        self.Wp = Vp[:, self.ia] * Vp[:, self.ib] * np.where(off, 2.0, 1.0)  # [p, T]
        self.HV = HV_steps
        self.Mh = []
        for HV in HV_steps:
            ny = HV.shape[0]
            Mh = np.zeros((ny, m, T))
            Mh[:, self.ia, t] = HV[:, self.ib]
            Mh[:, self.ib[off], t[off]] = HV[:, self.ia[off]]
            self.Mh.append(Mh)

    def unpack(self, Pp: np.ndarray) -> np.ndarray:
        """Packed [T, B] -> full [B, m, m]."""
        B = Pp.shape[1]
        P = np.empty((B, self.m, self.m))
        P[:, self.ia, self.ib] = Pp.T
        P[:, self.ib, self.ia] = Pp.T
        return P

    def run(
        self,
        c0: int,
        c1: int,
        state: SnapshotState,
        dy: np.ndarray,
        var: np.ndarray,
        scale: np.ndarray,
        q_res: np.ndarray,
        P_res: np.ndarray | None,
        h_std: np.ndarray,
        innov: np.ndarray,
        q_end: np.ndarray,
        P_end: np.ndarray,
    ) -> None:
        m, ia, ib = self.m, self.ia, self.ib
        Bn = c1 - c0
        q = state.q_hat[c0:c1].T.copy(order="C")  # [m, Bn]; the state is not mutated
        Pp = np.ascontiguousarray(state.P[c0:c1][:, ia, ib].T)  # [T, Bn]
        Ph = np.empty((m, Bn))
        k = np.empty((m, Bn))
        dq = np.empty((m, Bn))
        down = np.empty((m, Bn))
        for j, HV in enumerate(self.HV):
            ny = HV.shape[0]
            Pp += self.Qp * scale[c0:c1, j]
            y_j = np.ascontiguousarray(dy[c0:c1, j].T)  # [ny, Bn]
            innov[c0:c1, j] = (y_j - HV @ q).T
            var_j = np.ascontiguousarray(var[c0:c1, j].T)
            finite = np.isfinite(y_j)
            all_present = bool(finite.all())
            for i in range(ny):
                present = finite[i]
                if not all_present and not present.any():
                    continue
                h = HV[i]
                np.dot(self.Mh[j][i], Pp, out=Ph)  # P h
                s_i = h @ Ph + var_j[i]
                resid = y_j[i] - h @ q
                np.divide(Ph, s_i, out=k)
                if not all_present:
                    resid = np.where(present, resid, 0.0)
                    k *= present
                np.multiply(k, resid, out=dq)
                q += dq
                for a, r0, r1 in self.rows:  # P - P h h^T P / s, row a of the upper triangle
                    w = down[: r1 - r0]
                    np.multiply(k[a:], Ph[a], out=w)
                    Pp[r0:r1] -= w
            q_res[c0:c1, j] = q.T
            if P_res is not None:
                P_res[c0:c1, j] = self.unpack(Pp)
            h_var = self.Wp @ Pp
            h_std[c0:c1, j] = np.sqrt(np.maximum(h_var, 0.0)).T
        q_end[c0:c1] = q.T
        P_end[c0:c1] = self.unpack(Pp)
