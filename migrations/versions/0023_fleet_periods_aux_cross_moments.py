"""fleet periods keep the engines' aux-by-health moments

Revision ID: 0023
Revises: 0022
Create Date: 2026-12-07 09:00:00

The design's calibration now corrects the aux outputs (thrust, stall margins) on the health
estimates, as it corrects the level. The fleet deterioration shows the calibrated aux means,
exact from what the fleet periods sum, and their spread over engines, which needs the
covariance of each engine's aux and health means: a fleet period's squares now also sum each
aux value times each health value (``app.services.snapshots.buckets.second_moments``). No
column changes: the squares' blobs are rewritten from the engines' periods; downgrade writes
back the form of 0022 (the health values' products, then the aux values' squares).
"""
from collections.abc import Sequence

import numpy as np
from alembic import op
from sqlalchemy.orm import Session

revision: str = '0023'
down_revision: str | None = '0022'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def _form_0022(mean: np.ndarray, p: int) -> np.ndarray:
    from estimation.uncertainty import pair_products

    return np.concatenate([pair_products(mean[..., :p]), np.square(mean[..., p:])], axis=-1)


def upgrade() -> None:
    from app.services.snapshots.buckets import rebuild_fleets, second_moments

    rebuild_fleets(Session(bind=op.get_bind()), second_moments)


def downgrade() -> None:
    from app.services.snapshots.buckets import rebuild_fleets

    rebuild_fleets(Session(bind=op.get_bind()), _form_0022)
