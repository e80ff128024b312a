"""engine types carry their limits: amber and red levels of an engine's state

Revision ID: 0011
Revises: 0010
Create Date: 2026-11-24 16:10:00

``engine_types.limits`` holds the levels a type overrides (health change, EGT margin, thrust
deficit, rate of change) and its EGT redline; NULL keeps the defaults in
``app.models.designs.LIMIT_SPECS``. Downgrade drops the column and with it any override.
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = '0011'
down_revision: str | None = '0010'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('engine_types', schema=None) as batch_op:
        batch_op.add_column(
            sa.Column(
                'limits',
                sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'),
                nullable=True,
            )
        )


def downgrade() -> None:
    # A plain DROP COLUMN (SQLite has it since 3.35): batch mode would copy engine_types into a
    # new table and drop the old one, which the foreign keys of its models and engines refuse
    # once there is data.
    op.drop_column('engine_types', 'limits')
