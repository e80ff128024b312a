"""fleet periods keep the second moments of the engines' health means

Revision ID: 0022
Revises: 0021
Create Date: 2026-11-29 12:00:00

The fleet deterioration showed the mean of the engines' health estimates as stored, while the
engine pages and the fleet status show the design's calibrated level (a correction that is
straight or curved in the estimates). A fleet period now sums, besides each engine's period
mean, the products of its health values (i <= j) in place of their squares, so that the
fleet deterioration applies the calibration to the fleet's means and to their spread
(``app.services.snapshots.buckets.second_moments``; the form of this revision, which 0023
extends, is ``_form_0022``). No column changes: the squares' blobs are rewritten from the
engines' periods; downgrade writes the squares back.
"""
from collections.abc import Sequence

import numpy as np
from alembic import op
from sqlalchemy.orm import Session

revision: str = '0022'
down_revision: str | None = '0021'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def _form_0022(mean: np.ndarray, p: int) -> np.ndarray:
    """The health values' products (i <= j), then the aux values' squares."""
    from estimation.uncertainty import pair_products

    return np.concatenate([pair_products(mean[..., :p]), np.square(mean[..., p:])], axis=-1)


def upgrade() -> None:
    from app.services.snapshots.buckets import rebuild_fleets

    rebuild_fleets(Session(bind=op.get_bind()), _form_0022)


def downgrade() -> None:
    from app.services.snapshots.buckets import rebuild_fleets

    rebuild_fleets(Session(bind=op.get_bind()), lambda mean, p: np.square(mean))
