"""EGT windows: each engine's median dEGT over its last records, kept by the pipeline

Revision ID: 0021
Revises: 0020
Create Date: 2026-11-25 07:00:00

The fleet status read each engine's last 51 estimates with their snapshots (~71,400 rows for
1,392 engines) to check the EGT margin and the rate of change. The rate of change now reads
the one estimate 50 records back by its key, and the estimation pipeline keeps, per engine and
built-in design, the median dEGT of the last 20 records with the filter state it was taken at
(``app.services.snapshots.egt``): the status reads one row per engine.
The upgrade takes every built-in design's windows from the stored estimates and snapshots;
downgrade drops the table.
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.orm import Session

revision: str = '0021'
down_revision: str | None = '0020'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        'egt_windows',
        sa.Column('engine_id', sa.Integer(), nullable=False),
        sa.Column('design_id', sa.Integer(), nullable=False),
        sa.Column('n_records', sa.Integer(), nullable=False),
        sa.Column('last_recorded_at', sa.DateTime(timezone=True), nullable=True),
        sa.Column('fingerprint', sa.String(length=64), nullable=False),
        sa.Column('median', sa.Float(), nullable=True),
        sa.ForeignKeyConstraint(['design_id'], ['estimator_designs.id'], name=op.f('fk_egt_windows_design_id_estimator_designs'), ondelete='CASCADE'),
        sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_egt_windows_engine_id_engines'), ondelete='CASCADE'),
        sa.PrimaryKeyConstraint('engine_id', 'design_id', name=op.f('pk_egt_windows')),
    )
    op.create_index(op.f('ix_egt_windows_design_id'), 'egt_windows', ['design_id'], unique=False)
    # Fill from the estimates and snapshots already stored (the code of this revision's time).
    from app.services.snapshots.egt import rebuild

    session = Session(bind=op.get_bind())
    rebuild(session)
    session.flush()


def downgrade() -> None:
    op.drop_index(op.f('ix_egt_windows_design_id'), table_name='egt_windows')
    op.drop_table('egt_windows')
