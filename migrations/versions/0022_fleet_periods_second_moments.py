"""fleet periods keep the second moments of the engines' health means

Revision ID: 0022
Revises: 0021
Create Date: 2026-11-29 12:00:00

The fleet deterioration showed the mean of the engines' health estimates as stored, while the
engine pages and the fleet status show the design's calibrated level (a correction that is
straight or curved in the estimates). A fleet period now sums, besides each engine's period
mean, the products of its health values (i <= j) in place of their squares, so that the
fleet deterioration applies the calibration to the fleet's means and to their spread
(``app.services.snapshots.buckets.second_moments``). No column changes: the squares' blobs
are rewritten from the engines' periods; downgrade writes the squares back.
"""
import json
from collections.abc import Callable, Sequence

import numpy as np
import sqlalchemy as sa
from alembic import op
from sqlalchemy.orm import Session

revision: str = '0022'
down_revision: str | None = '0021'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def _rewrite(moments: Callable[[np.ndarray, int], np.ndarray] | None) -> None:
    from app.models.estimates import EstimateLayout
    from app.services.snapshots.buckets import rebuild_fleet, second_moments

    session = Session(bind=op.get_bind())
    designs = session.execute(sa.text(
        "SELECT DISTINCT design_id FROM fleet_periods ORDER BY design_id")).scalars().all()
    for design_id in designs:
        layout = session.execute(sa.text(
            "SELECT layout FROM filter_states WHERE design_id = :d LIMIT 1"), {"d": design_id}
        ).scalar()
        if layout is None:
            continue
        doc = layout if isinstance(layout, dict) else json.loads(layout)
        rebuild_fleet(session, design_id=design_id, p=len(EstimateLayout.from_dict(doc).health),
                      moments=moments or second_moments)
    session.flush()


def upgrade() -> None:
    _rewrite(None)


def downgrade() -> None:
    _rewrite(lambda mean, p: np.square(mean))
