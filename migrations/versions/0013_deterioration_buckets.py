"""deterioration buckets: per-engine and fleet weekly and monthly sums of the health and aux
estimates

Revision ID: 0013
Revises: 0012
Create Date: 2026-11-24 20:00:00

The fleet deterioration read every estimate of a design (21 s at 2M rows). The estimation
pipeline now keeps, per engine, design and week or month, the count and the sums of the health
and auxiliary values, and per design and period the sums over engines of their period means
and of their squares (``app.services.snapshots.buckets``); the fleet deterioration reads the
latter, one row per period.
The upgrade fills the table from the stored estimates, engine by engine; downgrade drops it.
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.orm import Session

revision: str = '0013'
down_revision: str | None = '0012'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        'deterioration_buckets',
        sa.Column('design_id', sa.Integer(), nullable=False),
        sa.Column('period', sa.String(length=8), nullable=False),
        sa.Column('engine_id', sa.Integer(), nullable=False),
        sa.Column('start', sa.DateTime(timezone=True), nullable=False),
        sa.Column('operator_id', sa.Integer(), nullable=False),
        sa.Column('n', sa.Integer(), nullable=False),
        sa.Column('sums', sa.LargeBinary(), nullable=False),
        sa.CheckConstraint("period IN ('week', 'month')", name=op.f('ck_deterioration_buckets_period')),
        sa.ForeignKeyConstraint(['design_id'], ['estimator_designs.id'], name=op.f('fk_deterioration_buckets_design_id_estimator_designs'), ondelete='CASCADE'),
        sa.PrimaryKeyConstraint('design_id', 'period', 'engine_id', 'start', name=op.f('pk_deterioration_buckets')),
    )
    op.create_table(
        'fleet_periods',
        sa.Column('design_id', sa.Integer(), nullable=False),
        sa.Column('period', sa.String(length=8), nullable=False),
        sa.Column('start', sa.DateTime(timezone=True), nullable=False),
        sa.Column('operator_id', sa.Integer(), nullable=False),
        sa.Column('n_engines', sa.Integer(), nullable=False),
        sa.Column('sums', sa.LargeBinary(), nullable=False),
        sa.Column('squares', sa.LargeBinary(), nullable=False),
        sa.CheckConstraint("period IN ('week', 'month')", name=op.f('ck_fleet_periods_period')),
        sa.ForeignKeyConstraint(['design_id'], ['estimator_designs.id'], name=op.f('fk_fleet_periods_design_id_estimator_designs'), ondelete='CASCADE'),
        sa.PrimaryKeyConstraint('design_id', 'period', 'start', name=op.f('pk_fleet_periods')),
    )
    # Fill from the estimates already stored (the code of this revision's time, engine by engine).
    from app.models.estimates import EstimateLayout
    from app.services.snapshots.buckets import rebuild

    session = Session(bind=op.get_bind())
    states = session.execute(sa.text(
        "SELECT operator_id, design_id, engine_id, layout FROM filter_states ORDER BY design_id, engine_id"
    )).all()
    for operator_id, design_id, engine_id, layout in states:
        doc = layout if isinstance(layout, dict) else __import__('json').loads(layout)
        layout = EstimateLayout.from_dict(doc)
        # Blobs of float32 numbers until 0020.
        rebuild(session, operator_id=operator_id, design_id=design_id, layout=layout,
                engine_ids=[engine_id], decode=layout.unpack)
    session.flush()


def downgrade() -> None:
    op.drop_table('fleet_periods')
    op.drop_table('deterioration_buckets')
