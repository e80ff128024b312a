"""stream estimates and stream filter states

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-22 05:48:59.590406
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = '0006'
down_revision: str | None = '0005'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('stream_estimates',
    sa.Column('id', sa.BigInteger().with_variant(sa.Integer(), 'sqlite'), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_id', sa.Integer(), nullable=False),
    sa.Column('design_id', sa.Integer(), nullable=False),
    sa.Column('recording_id', sa.Integer(), nullable=False),
    sa.Column('window', sa.Integer(), nullable=False),
    sa.Column('t_s', sa.Double(), nullable=False),
    sa.Column('n', sa.Integer(), nullable=False),
    sa.Column('packed', sa.LargeBinary(), nullable=False),
    sa.ForeignKeyConstraint(['design_id'], ['estimator_designs.id'], name=op.f('fk_stream_estimates_design_id_estimator_designs'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_stream_estimates_engine_id_engines'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_stream_estimates_operator_id_operators'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['recording_id'], ['stream_recordings.id'], name=op.f('fk_stream_estimates_recording_id_stream_recordings'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_stream_estimates')),
    sa.UniqueConstraint('recording_id', 'design_id', 'window', name=op.f('uq_stream_estimates_recording_id_design_id_window'))
    )
    with op.batch_alter_table('stream_estimates', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_stream_estimates_design_id'), ['design_id'], unique=False)

    op.create_table('stream_filter_states',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_id', sa.Integer(), nullable=False),
    sa.Column('design_id', sa.Integer(), nullable=False),
    sa.Column('recording_id', sa.Integer(), nullable=False),
    sa.Column('started_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('window', sa.Integer(), nullable=False),
    sa.Column('n_samples', sa.Integer(), nullable=False),
    sa.Column('restart_sample', sa.Integer(), nullable=False),
    sa.Column('n_segments', sa.Integer(), nullable=False),
    sa.Column('layout', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('state', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['design_id'], ['estimator_designs.id'], name=op.f('fk_stream_filter_states_design_id_estimator_designs'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_stream_filter_states_engine_id_engines'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_stream_filter_states_operator_id_operators'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['recording_id'], ['stream_recordings.id'], name=op.f('fk_stream_filter_states_recording_id_stream_recordings'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_stream_filter_states')),
    sa.UniqueConstraint('recording_id', 'design_id', name=op.f('uq_stream_filter_states_recording_id_design_id'))
    )
    with op.batch_alter_table('stream_filter_states', schema=None) as batch_op:
        batch_op.create_index('ix_stream_filter_states_engine_design_started', ['engine_id', 'design_id', 'started_at'], unique=False)
        batch_op.create_index(batch_op.f('ix_stream_filter_states_operator_id'), ['operator_id'], unique=False)



def downgrade() -> None:
    with op.batch_alter_table('stream_filter_states', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_stream_filter_states_operator_id'))
        batch_op.drop_index('ix_stream_filter_states_engine_design_started')

    op.drop_table('stream_filter_states')
    with op.batch_alter_table('stream_estimates', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_stream_estimates_design_id'))

    op.drop_table('stream_estimates')
