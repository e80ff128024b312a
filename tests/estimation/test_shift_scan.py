"""Batched detector pieces against the same quantities computed one record at a time."""

from __future__ import annotations

import numpy as np
import pytest

from estimation.shift_scan import level_scan, sliding_baselines


def test_sliding_baselines_equal_the_mean_of_each_window() -> None:
    series = np.random.default_rng(1).normal(size=(120, 6))
    bases = sliding_baselines(series, 30)
    assert bases.shape == (91, 6)
    for i in (0, 17, 90):
        assert np.array_equal(bases[i], np.mean(series[i : i + 30], axis=0))
    assert sliding_baselines(series[:10], 30).shape == (0, 6)


@pytest.mark.parametrize(("m", "n_faults"), [(4, 8), (6, 12), (10, 19)])
def test_level_scan_equals_one_solve_per_record_and_a_batch_of_one_bit_for_bit(
    m: int, n_faults: int
) -> None:
    rng = np.random.default_rng(m)
    K = 200
    A = rng.normal(size=(K, m, m))
    P = A @ A.transpose(0, 2, 1) + np.eye(m)
    shift = rng.normal(size=(K, m))
    H = rng.normal(size=(m, n_faults))
    scan = level_scan(shift, P, H)
    for k in range(K):
        # Against a solve per record (seed 002 eq. 21-23 without an inverse).
        X = np.linalg.solve(P[k], np.column_stack([shift[k], H]))
        distance = float(shift[k] @ X[:, 0])
        proj = H.T @ X[:, 0]
        f = proj / np.einsum("ij,ij->j", H, X[:, 1:])
        np.testing.assert_allclose(scan.distance[k], distance, rtol=1e-10)
        np.testing.assert_allclose(scan.f[k], f, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(scan.wssr[k], np.maximum(distance - proj * f, 0.0),
                                   rtol=1e-8, atol=1e-8 * distance)
        # A batch of one gives the batch's numbers bit for bit: re-runs must not depend on
        # which records share a call.
        one = level_scan(shift[k : k + 1], P[k : k + 1], H)
        assert one.distance[0] == scan.distance[k]
        assert np.array_equal(one.wssr[0], scan.wssr[k]) and np.array_equal(one.f[0], scan.f[k])


def test_level_scan_checks_shapes() -> None:
    with pytest.raises(ValueError, match="P must be"):
        level_scan(np.zeros((3, 2)), np.zeros((3, 3, 3)), np.zeros((2, 1)))


@pytest.mark.parametrize("dof", [1, 2, 9, 19, 219, 1999])
def test_a_sensor_space_threshold_reads_back_to_its_degrees_of_freedom(dof: int) -> None:
    """``sensor_fit_dof`` inverts the sensor-space isolation threshold (an event stored before
    its degrees of freedom were): SENSOR_WSSR_MARGIN chi2_0.999(dof) -> dof."""
    from scipy import stats

    from estimation.shift_detector import (
        SENSOR_ISOLATION_LEVEL,
        SENSOR_WSSR_MARGIN,
        sensor_fit_dof,
    )

    threshold = SENSOR_WSSR_MARGIN * float(stats.chi2.ppf(SENSOR_ISOLATION_LEVEL, dof))
    assert sensor_fit_dof(threshold) == dof
