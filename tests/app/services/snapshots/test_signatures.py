"""The pipeline's fault signatures of a chunk (``run._signatures_t``, laid out record-last and
computed over runs of records): the term-by-term sums of each record alone, bit for bit, and the
estimator's matrix product to rounding."""

from __future__ import annotations

import numpy as np

from app.services.snapshots import estimator, run
from estimation.tuners import svd_vstar
from tests.estimation.models import reference_model


def test_chunk_signatures_equal_each_record_alone() -> None:
    model = reference_model()
    est = estimator.build_estimator(0, model, {"vstar": svd_vstar(model, 6).tolist()})
    ny, p, nu = len(est.sensor_columns), model.n_health, len(est.input_columns)
    rng = np.random.default_rng(7)
    n = run.SIGNATURE_BLOCK + 37  # across a block's end
    G_y, G_u = rng.normal(size=(2, n // 2 + 1, ny, p)), rng.normal(size=(2, n // 2 + 1, ny, nu))
    flat_y, flat_u = G_y.reshape(-1, ny, p), G_u.reshape(-1, ny, nu)
    got = run._signatures_t(est, flat_y, flat_u).transpose(2, 0, 1).reshape(
        2, n // 2 + 1, ny, -1)
    one = run._signatures_t(est, G_y[1, 5][None], G_u[1, 5][None])[:, :, 0]  # a record alone
    alone = np.zeros_like(one)
    for j in range(p):
        alone += G_y[1, 5, :, j, None] * est.S_full[j]
    for k, b in enumerate(est.bias_inputs):
        alone += G_u[1, 5, :, b, None] * est.S_full[p + k]
    assert got[1, 5].tobytes() == one.tobytes() == alone.tobytes()
    np.testing.assert_allclose(got, est.fault_signatures(G_y, G_u), rtol=1e-12, atol=1e-12)
