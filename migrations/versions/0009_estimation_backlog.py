"""estimation backlog: the engines with snapshots to estimate, marked as uploads store them

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-22 10:20:00

The estimation job found its work by counting, per engine, the stored records up to the last
one processed against the records processed: an index count whose cost grows with each
engine's history (0.16 s a pass on 100 engines with 3,000 records each, seconds on a fleet of
long histories). Uploads now add a mark for each engine they store rows of (``estimation_backlog``)
in their own transaction, and the job deletes the marks it read in the transaction that stores
the engine's estimates.

Upgrade marks every engine that has snapshots without an estimate under its type's active
design (from its earliest such snapshot), so nothing stored before the upgrade is left out.
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0009'
down_revision: str | None = '0008'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('estimation_backlog',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_id', sa.Integer(), nullable=False),
    sa.Column('earliest', sa.DateTime(timezone=True), nullable=True),
    sa.Column('rows', sa.Integer(), nullable=True),
    sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_estimation_backlog_engine_id_engines'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_estimation_backlog_operator_id_operators'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_estimation_backlog'))
    )
    with op.batch_alter_table('estimation_backlog', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_estimation_backlog_engine_id'), ['engine_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_estimation_backlog_operator_id'), ['operator_id'], unique=False)
    op.execute(
        "INSERT INTO estimation_backlog (operator_id, engine_id, earliest, rows) "
        "SELECT e.operator_id, e.id, min(s.recorded_at), NULL "
        "FROM engines e JOIN snapshots s ON s.engine_id = e.id "
        "WHERE NOT EXISTS (SELECT 1 FROM estimates x JOIN estimator_designs d "
        "ON d.id = x.design_id AND d.active AND d.engine_type_id = e.engine_type_id "
        "WHERE x.engine_id = s.engine_id AND x.recorded_at = s.recorded_at) "
        "GROUP BY e.id, e.operator_id"
    )


def downgrade() -> None:
    with op.batch_alter_table('estimation_backlog', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_estimation_backlog_operator_id'))
        batch_op.drop_index(batch_op.f('ix_estimation_backlog_engine_id'))
    op.drop_table('estimation_backlog')
