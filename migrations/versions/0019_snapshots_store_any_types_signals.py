"""snapshots store any engine type's signals

Revision ID: 0019
Revises: 0018
Create Date: 2026-11-25 00:40:00

An engine type's parameter set comes from its models (``fleet.parameter_sets``): a type whose
models are not scheduled on the operating condition and the flight phase (a single-point
model) receives snapshots without them, and its signals need not be the catalogue's. The
operating-condition columns and ``phase`` become nullable (the check on ``phase`` lets NULL
pass), and ``other_signals`` holds, by name and in stored units, the values of signals outside
the catalogue (``N1``, ``EGT`` ...); the catalogue's signals keep their fixed columns. Existing
rows carry every column already and no other signal.

Down again, the rows the old table cannot hold (another signal, no condition or no phase) go,
with their estimates.
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = '0019'
down_revision: str | None = '0018'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

NULLABLE = ('alt_ft', 'mach', 'dtamb_k', 'power_pct')


def _unstorable_before(alias: str = "") -> str:
    """Rows the table before this migration cannot hold."""
    return (f"{alias}other_signals IS NOT NULL OR {alias}phase IS NULL OR "
            + " OR ".join(f"{alias}{c} IS NULL" for c in NULLABLE))


def upgrade() -> None:
    with op.batch_alter_table('snapshots', schema=None) as batch_op:
        batch_op.alter_column('phase', existing_type=sa.String(length=8), nullable=True)
        for column in NULLABLE:
            batch_op.alter_column(column, existing_type=sa.Double(), nullable=True)
        batch_op.add_column(sa.Column(
            'other_signals',
            sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'),
            nullable=True,
        ))


def downgrade() -> None:
    op.execute(
        "DELETE FROM estimates WHERE EXISTS (SELECT 1 FROM snapshots s WHERE "
        "s.engine_id = estimates.engine_id AND s.recorded_at = estimates.recorded_at AND ("
        + _unstorable_before("s.") + "))"
    )
    op.execute(f"DELETE FROM snapshots WHERE {_unstorable_before()}")
    with op.batch_alter_table('snapshots', schema=None) as batch_op:
        batch_op.drop_column('other_signals')
        for column in NULLABLE:
            batch_op.alter_column(column, existing_type=sa.Double(), nullable=False)
        batch_op.alter_column('phase', existing_type=sa.String(length=8), nullable=False)
