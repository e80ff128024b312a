"""Snapshot-mode tuner filter: against a textbook filter, closed form, restart, blocks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.snapshot import (
    SnapshotState,
    snapshot_deviation,
    snapshot_filter,
    tuner_measurement_matrix,
)
from estimation.stacked import SubstitutionPlan, cholesky_lower, forward_substitute

E, S, NY, P, M = 7, 12, 5, 8, 4


def _case(seed: int = 0, missing: float = 0.15):
    rng = np.random.default_rng(seed)
    V = rng.standard_normal((M, P))
    G = rng.standard_normal((E, S, NY, P))  # a different operating condition per snapshot
    dy = rng.standard_normal((E, S, NY))
    dy[rng.random((E, S, NY)) < missing] = np.nan
    dy[0, 3] = np.nan  # a snapshot with no sensor at all
    std = rng.uniform(0.3, 1.0, NY)
    scale = rng.uniform(0.0, 2.0, (E, S))
    Qq = np.diag(rng.uniform(0.01, 0.1, M))
    P0 = np.eye(M) * 2.0
    return V, G, dy, std, scale, Qq, P0


def _textbook(V, G, dy, std, scale, Qq, P0):
    """One engine at a time, full vector update with the missing rows dropped."""
    Vp = np.linalg.pinv(V)
    q_out = np.zeros((E, S, M))
    P_out = np.zeros((E, S, M, M))
    for e in range(E):
        q, Pm = np.zeros(M), P0.copy()
        for j in range(S):
            Pm = Pm + scale[e, j] * Qq
            keep = np.isfinite(dy[e, j])
            if keep.any():
                H = (G[e, j] @ Vp)[keep]
                R = np.diag(std[keep] ** 2)
                Sm = H @ Pm @ H.T + R
                K = np.linalg.solve(Sm, H @ Pm).T
                q = q + K @ (dy[e, j, keep] - H @ q)
                Pm = (np.eye(M) - K @ H) @ Pm @ (np.eye(M) - K @ H).T + K @ R @ K.T  # Joseph
            q_out[e, j], P_out[e, j] = q, Pm
    return q_out, P_out


def test_batched_scalar_updates_equal_textbook_filter_with_dropped_rows():
    V, G, dy, std, scale, Qq, P0 = _case()
    res = snapshot_filter(
        SnapshotState.initial(E, P0), dy, G, V, Qq, std, walk_scale=scale, keep_covariance=True
    )
    q_ref, P_ref = _textbook(V, G, dy, std, scale, Qq, P0)
    np.testing.assert_allclose(res.q_hat, q_ref, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(res.P, P_ref, rtol=1e-9, atol=1e-11)
    Vp = np.linalg.pinv(V)
    np.testing.assert_allclose(res.h_hat, q_ref @ Vp.T, rtol=1e-9, atol=1e-11)
    h_var = np.einsum("pa,esab,pb->esp", Vp, P_ref, Vp)
    np.testing.assert_allclose(res.h_std, np.sqrt(h_var), rtol=1e-8)
    np.testing.assert_array_equal(np.isnan(res.innovation), np.isnan(dy))


def test_restart_from_serialised_state_equals_uninterrupted():
    V, G, dy, std, scale, Qq, P0 = _case(1)
    start = SnapshotState.initial(E, P0)
    whole = snapshot_filter(start, dy, G, V, Qq, std, walk_scale=scale, keep_covariance=True)
    first = snapshot_filter(
        start, dy[:, :5], G[:, :5], V, Qq, std, walk_scale=scale[:, :5], keep_covariance=True
    )
    saved = json.loads(json.dumps(first.state.to_dict()))
    second = snapshot_filter(
        SnapshotState.from_dict(saved), dy[:, 5:], G[:, 5:], V, Qq, std, walk_scale=scale[:, 5:],
        keep_covariance=True,
    )
    np.testing.assert_array_equal(np.concatenate([first.q_hat, second.q_hat], 1), whole.q_hat)
    np.testing.assert_array_equal(np.concatenate([first.P, second.P], 1), whole.P)
    np.testing.assert_array_equal(second.state.P, whole.state.P)


def test_engine_blocks_and_callable_gains_give_the_same_result():
    V, G, dy, std, scale, Qq, P0 = _case(2)
    start = SnapshotState.initial(E, P0)
    ref = snapshot_filter(start, dy, G, V, Qq, std, walk_scale=scale, block=1024)
    small = snapshot_filter(start, dy, lambda j: G[:, j], V, Qq, std, walk_scale=scale, block=3)
    np.testing.assert_allclose(small.q_hat, ref.q_hat, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(small.state.P, ref.state.P, rtol=1e-13, atol=1e-14)
    # One engine alone equals the same engine inside the batch.
    one = snapshot_filter(start.select([4]), dy[4:5], G[4:5], V, Qq, std, walk_scale=scale[4:5])
    np.testing.assert_allclose(one.q_hat[0], ref.q_hat[4], rtol=1e-13, atol=1e-14)


def test_without_random_walk_the_filter_is_the_bayesian_least_squares_posterior():
    V, G, dy, std, _, Qq, P0 = _case(3, missing=0.0)
    res = snapshot_filter(SnapshotState.initial(E, P0), dy, G, V, Qq, std, walk_scale=0.0)
    Vp = np.linalg.pinv(V)
    Rinv = np.diag(std**-2)
    for e in range(E):
        info = np.linalg.inv(P0)
        vec = np.zeros(M)
        for j in range(S):
            if not np.all(np.isfinite(dy[e, j])):
                continue
            H = G[e, j] @ Vp
            info += H.T @ Rinv @ H
            vec += H.T @ Rinv @ dy[e, j]
        np.testing.assert_allclose(res.q_hat[e, -1], np.linalg.solve(info, vec), rtol=1e-8)
        np.testing.assert_allclose(res.state.P[e], np.linalg.inv(info), rtol=1e-8, atol=1e-12)


def test_state_checks_and_deviation():
    with pytest.raises(ValueError, match="P"):
        SnapshotState(np.zeros((2, 3)), np.zeros((2, 3, 2)))
    with pytest.raises(ValueError, match="format"):
        SnapshotState.from_dict({"q_hat": [[0.0]], "P": [[[1.0]]]})
    y_trim = np.array([100.0, 600.0])
    G_u = np.array([[0.5], [1.0]])
    du = np.array([2.0])
    dy = snapshot_deviation(y_trim * np.array([1.02, 0.99]), y_trim, G_u, du)
    np.testing.assert_allclose(dy, [2.0 - 1.0, -1.0 - 2.0])


def test_one_operating_condition_for_all_engines_equals_per_engine_gains():
    V, G, dy, std, scale, Qq, P0 = _case(4)
    shared = G[0, 0]  # [ny, p]
    start = SnapshotState.initial(E, P0)
    a = snapshot_filter(start, dy, shared, V, Qq, std, walk_scale=scale, block=4)
    b = snapshot_filter(
        start, dy, np.broadcast_to(shared, G.shape).copy(), V, Qq, std, walk_scale=scale
    )
    np.testing.assert_allclose(a.q_hat, b.q_hat, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(a.h_std, b.h_std, rtol=1e-12)
    np.testing.assert_allclose(a.innovation, b.innovation, rtol=1e-12, atol=1e-13)


def test_threads_and_per_snapshot_shared_gains_do_not_change_the_result():
    V, G, dy, std, scale, Qq, P0 = _case(5)
    per_step = G[0]  # [S, ny, p]: one operating condition per snapshot for the whole fleet
    start = SnapshotState.initial(E, P0)
    one = snapshot_filter(start, dy, per_step, V, Qq, std, walk_scale=scale, block=2, workers=1)
    many = snapshot_filter(start, dy, per_step, V, Qq, std, walk_scale=scale, block=2, workers=3)
    np.testing.assert_array_equal(one.q_hat, many.q_hat)
    np.testing.assert_array_equal(one.state.P, many.state.P)
    full = snapshot_filter(
        start, dy, np.broadcast_to(per_step, G.shape).copy(), V, Qq, std, walk_scale=scale
    )
    np.testing.assert_allclose(one.q_hat, full.q_hat, rtol=1e-12, atol=1e-13)


def test_fleet_wide_gains_restart_equals_uninterrupted_and_keeps_covariances():
    """The packed path (one operating condition per snapshot for the whole fleet)."""
    V, G, dy, std, scale, Qq, P0 = _case(6)
    per_step = G[0]  # [S, ny, p]
    start = SnapshotState.initial(E, P0)
    whole = snapshot_filter(start, dy, per_step, V, Qq, std, walk_scale=scale, keep_covariance=True)
    first = snapshot_filter(
        start, dy[:, :5], per_step[:5], V, Qq, std, walk_scale=scale[:, :5], keep_covariance=True
    )
    saved = json.loads(json.dumps(first.state.to_dict()))
    second = snapshot_filter(
        SnapshotState.from_dict(saved), dy[:, 5:], per_step[5:], V, Qq, std,
        walk_scale=scale[:, 5:], keep_covariance=True,
    )
    np.testing.assert_array_equal(np.concatenate([first.q_hat, second.q_hat], 1), whole.q_hat)
    np.testing.assert_array_equal(np.concatenate([first.P, second.P], 1), whole.P)
    np.testing.assert_array_equal(second.state.P, whole.state.P)
    # Against the textbook filter (full vector update, Joseph form) on the same gains.
    q_ref, P_ref = _textbook(V, np.broadcast_to(per_step, G.shape), dy, std, scale, Qq, P0)
    np.testing.assert_allclose(whole.q_hat, q_ref, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(whole.P, P_ref, rtol=1e-9, atol=1e-11)
    np.testing.assert_array_equal(whole.P, np.swapaxes(whole.P, -1, -2))  # symmetric by storage


@pytest.mark.parametrize("shorter_last", [True, False])
def test_padding_after_an_engines_last_snapshot_leaves_its_numbers_bit_for_bit(
    shorter_last: bool,
) -> None:
    """Engines of different lengths in one call, each padded after its last snapshot (no
    sensor, no walk), the shorter ones laid out last (the steps there update only the
    engines before them) or first: every engine's estimates, covariances and innovations
    equal its run alone bit for bit (its 1-sigma to rounding: one GEMM over the rows), its
    padding rows repeat its last estimate and covariance, their innovations are NaN."""
    V, G, dy, std, scale, Qq, P0 = _case(5)
    lengths = [12, 12, 9, 7, 7, 3, 0] if shorter_last else [0, 3, 7, 12, 7, 9, 12]
    start = SnapshotState(np.random.default_rng(6).standard_normal((E, M)),
                          np.broadcast_to(P0, (E, M, M)).copy())
    for e, n in enumerate(lengths):
        dy[e, n:] = np.nan
        scale[e, n:] = 0.0
    got = snapshot_filter(start, dy, G, V, Qq, std, walk_scale=scale, keep_covariance=True)
    assert got.P is not None
    for e, n in enumerate(lengths):
        one = snapshot_filter(start.select([e]), dy[e : e + 1, :n], G[e : e + 1, :n], V, Qq,
                              std, walk_scale=scale[e : e + 1, :n], keep_covariance=True)
        assert one.P is not None
        for mine, alone in ((got.q_hat[e, :n], one.q_hat[0]), (got.P[e, :n], one.P[0]),
                            (got.innovation[e, :n], one.innovation[0])):
            assert mine.tobytes() == alone.tobytes()
        np.testing.assert_allclose(got.h_std[e, :n], one.h_std[0], rtol=1e-14, atol=0)
        last_q = one.state.q_hat[0]
        last_P = one.state.P[0]
        assert (got.q_hat[e, n:] == last_q).all() and (got.P[e, n:] == last_P).all()
        assert np.isnan(got.innovation[e, n:]).all()
        assert got.state.q_hat[e].tobytes() == last_q.tobytes()
        assert got.state.P[e].tobytes() == last_P.tobytes()


@pytest.mark.parametrize("engines_per_block", [7, 3])
def test_tuner_gains_laid_out_by_the_caller_give_the_gains_numbers_bit_for_bit(
    engines_per_block: int,
) -> None:
    """The measurement matrix H = G_y V*^+ taken record by record before the records are laid
    out (as the pipeline does, ``tuner_measurement_matrix``) and handed in as ``tuner_gains``
    filters to the same numbers as the gains in health space laid out, bit for bit: each
    product is its own matrix's, however the records are stacked."""
    V, G, dy, std, scale, Qq, P0 = _case(7)
    lengths = [12, 11, 9, 9, 5, 2, 0]
    for e, n in enumerate(lengths):
        dy[e, n:] = np.nan
        scale[e, n:] = 0.0
    start = SnapshotState.initial(E, P0)
    # Record by record: each engine's records one after the other, padding left out.
    records = np.concatenate([G[e, :n] for e, n in enumerate(lengths)])
    H_records = tuner_measurement_matrix(records, V)
    H = np.zeros((E, S, NY, M))
    at = 0
    for e, n in enumerate(lengths):
        H[e, :n] = H_records[at : at + n]
        at += n
    want = snapshot_filter(start, dy, G, V, Qq, std, walk_scale=scale, keep_covariance=True,
                           block=engines_per_block)
    got = snapshot_filter(start, dy, None, V, Qq, std, walk_scale=scale, keep_covariance=True,
                          block=engines_per_block, tuner_gains=H)
    for name in ("q_hat", "P", "h_hat", "h_std", "innovation"):
        assert getattr(got, name).tobytes() == getattr(want, name).tobytes(), name
    assert got.state.q_hat.tobytes() == want.state.q_hat.tobytes()
    assert got.state.P.tobytes() == want.state.P.tobytes()
    with pytest.raises(ValueError, match="gains or tuner_gains"):
        snapshot_filter(start, dy, None, V, Qq, std)


def test_substitution_plan_equals_forward_substitution_bit_for_bit() -> None:
    """The plan's views made once, run again and again on new factors and right-hand sides,
    give ``forward_substitute``'s numbers."""
    rng = np.random.default_rng(3)
    n, r, K = 6, 4, 9
    plan = SubstitutionPlan(n, r, K)
    for _ in range(3):
        A = rng.standard_normal((K, n, n))
        A = A @ A.transpose(0, 2, 1) + n * np.eye(n)
        X = rng.standard_normal((n, r, K))
        cholesky_lower(A, out=plan.L_stack)
        plan.X[...] = X
        want = forward_substitute(np.ascontiguousarray(plan.L), X.copy())
        assert plan.run().tobytes() == want.tobytes()
