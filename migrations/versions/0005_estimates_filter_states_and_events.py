"""estimates, filter states and events

Revision ID: 0005
Revises: 0003
Create Date: 2026-11-22 04:45:26.225572
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = '0005'
down_revision: str | None = '0003'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('events',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_id', sa.Integer(), nullable=False),
    sa.Column('design_id', sa.Integer(), nullable=False),
    sa.Column('seq', sa.Integer(), nullable=False),
    sa.Column('detected_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('kind', sa.String(length=16), nullable=False),
    sa.Column('fault', sa.String(length=64), nullable=True),
    sa.Column('magnitude', sa.Float(), nullable=True),
    sa.Column('statistic', sa.Float(), nullable=False),
    sa.Column('wssr', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('shift', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('status', sa.String(length=16), nullable=False),
    sa.Column('acknowledged_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('acknowledged_by', sa.Integer(), nullable=True),
    sa.Column('closed_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('closed_by', sa.Integer(), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.CheckConstraint("kind IN ('shift', 'isolated_fault')", name=op.f('ck_events_kind')),
    sa.CheckConstraint("status IN ('open', 'acknowledged', 'closed')", name=op.f('ck_events_status')),
    sa.ForeignKeyConstraint(['acknowledged_by'], ['api_keys.id'], name=op.f('fk_events_acknowledged_by_api_keys'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['closed_by'], ['api_keys.id'], name=op.f('fk_events_closed_by_api_keys'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['design_id'], ['estimator_designs.id'], name=op.f('fk_events_design_id_estimator_designs'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_events_engine_id_engines'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_events_operator_id_operators'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_events')),
    sa.UniqueConstraint('engine_id', 'design_id', 'seq', name=op.f('uq_events_engine_id_design_id_seq'))
    )
    with op.batch_alter_table('events', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_events_design_id'), ['design_id'], unique=False)
        batch_op.create_index('ix_events_operator_status_detected', ['operator_id', 'status', 'detected_at'], unique=False)

    op.create_table('filter_checkpoints',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('engine_id', sa.Integer(), nullable=False),
    sa.Column('design_id', sa.Integer(), nullable=False),
    sa.Column('seq', sa.Integer(), nullable=False),
    sa.Column('last_recorded_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('last_snapshot_id', sa.BigInteger().with_variant(sa.Integer(), 'sqlite'), nullable=False),
    sa.Column('state', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.ForeignKeyConstraint(['design_id'], ['estimator_designs.id'], name=op.f('fk_filter_checkpoints_design_id_estimator_designs'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_filter_checkpoints_engine_id_engines'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_filter_checkpoints')),
    sa.UniqueConstraint('engine_id', 'design_id', 'seq', name=op.f('uq_filter_checkpoints_engine_id_design_id_seq'))
    )
    with op.batch_alter_table('filter_checkpoints', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_filter_checkpoints_design_id'), ['design_id'], unique=False)

    op.create_table('filter_states',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_id', sa.Integer(), nullable=False),
    sa.Column('design_id', sa.Integer(), nullable=False),
    sa.Column('layout', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('state', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('n_records', sa.Integer(), nullable=False),
    sa.Column('last_recorded_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('last_snapshot_id', sa.BigInteger().with_variant(sa.Integer(), 'sqlite'), nullable=True),
    sa.Column('updated_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['design_id'], ['estimator_designs.id'], name=op.f('fk_filter_states_design_id_estimator_designs'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_filter_states_engine_id_engines'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_filter_states_operator_id_operators'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_filter_states')),
    sa.UniqueConstraint('engine_id', 'design_id', name=op.f('uq_filter_states_engine_id_design_id'))
    )
    with op.batch_alter_table('filter_states', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_filter_states_design_id'), ['design_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_filter_states_operator_id'), ['operator_id'], unique=False)

    op.create_table('event_comments',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('event_id', sa.Integer(), nullable=False),
    sa.Column('author_key_id', sa.Integer(), nullable=True),
    sa.Column('author', sa.String(length=200), nullable=False),
    sa.Column('body', sa.Text(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['author_key_id'], ['api_keys.id'], name=op.f('fk_event_comments_author_key_id_api_keys'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['event_id'], ['events.id'], name=op.f('fk_event_comments_event_id_events'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_event_comments'))
    )
    with op.batch_alter_table('event_comments', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_event_comments_event_id'), ['event_id'], unique=False)

    op.create_table('estimates',
    sa.Column('id', sa.BigInteger().with_variant(sa.Integer(), 'sqlite'), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_id', sa.Integer(), nullable=False),
    sa.Column('design_id', sa.Integer(), nullable=False),
    sa.Column('snapshot_id', sa.BigInteger().with_variant(sa.Integer(), 'sqlite'), nullable=False),
    sa.Column('seq', sa.Integer(), nullable=False),
    sa.Column('recorded_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('phase', sa.String(length=16), nullable=False),
    sa.Column('packed', sa.LargeBinary(), nullable=False),
    sa.ForeignKeyConstraint(['design_id'], ['estimator_designs.id'], name=op.f('fk_estimates_design_id_estimator_designs'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_estimates_engine_id_engines'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_estimates_operator_id_operators'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['snapshot_id'], ['snapshots.id'], name=op.f('fk_estimates_snapshot_id_snapshots'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_estimates')),
    sa.UniqueConstraint('engine_id', 'design_id', 'seq', name=op.f('uq_estimates_engine_id_design_id_seq')),
    sa.UniqueConstraint('snapshot_id', 'design_id', name=op.f('uq_estimates_snapshot_id_design_id'))
    )
    with op.batch_alter_table('estimates', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_estimates_design_id'), ['design_id'], unique=False)



def downgrade() -> None:
    with op.batch_alter_table('estimates', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_estimates_design_id'))

    op.drop_table('estimates')
    with op.batch_alter_table('event_comments', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_event_comments_event_id'))

    op.drop_table('event_comments')
    with op.batch_alter_table('filter_states', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_filter_states_operator_id'))
        batch_op.drop_index(batch_op.f('ix_filter_states_design_id'))

    op.drop_table('filter_states')
    with op.batch_alter_table('filter_checkpoints', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_filter_checkpoints_design_id'))

    op.drop_table('filter_checkpoints')
    with op.batch_alter_table('events', schema=None) as batch_op:
        batch_op.drop_index('ix_events_operator_status_detected')
        batch_op.drop_index(batch_op.f('ix_events_design_id'))

    op.drop_table('events')
