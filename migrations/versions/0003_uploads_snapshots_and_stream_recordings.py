"""uploads, snapshots and stream recordings

Snapshots keep one DOUBLE PRECISION column per signal (fast COPY loads and trend reads);
the unique (engine_id, recorded_at) key makes a snapshot sent twice store nothing. Only
engine_id is a foreign key on snapshots: each one costs a row-locking check per COPYed row.

Revision ID: 0003
Revises: 0004
Create Date: 2026-11-22 04:44:49.427816
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = '0003'
down_revision: str | None = '0004'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('stream_recordings',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_id', sa.Integer(), nullable=False),
    sa.Column('aircraft_id', sa.Integer(), nullable=False),
    sa.Column('position', sa.SmallInteger(), nullable=False),
    sa.Column('flight_id', sa.String(length=64), nullable=True),
    sa.Column('started_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('dt_s', sa.Double(), nullable=False),
    sa.Column('status', sa.String(length=8), nullable=False),
    sa.Column('n_samples', sa.Integer(), nullable=False),
    sa.Column('n_chunks', sa.Integer(), nullable=False),
    sa.Column('signals', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('path', sa.String(length=300), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('closed_at', sa.DateTime(timezone=True), nullable=True),
    sa.CheckConstraint("status IN ('open', 'closed')", name=op.f('ck_stream_recordings_status')),
    sa.CheckConstraint('dt_s > 0', name=op.f('ck_stream_recordings_dt')),
    sa.ForeignKeyConstraint(['aircraft_id'], ['aircraft.id'], name=op.f('fk_stream_recordings_aircraft_id_aircraft')),
    sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_stream_recordings_engine_id_engines')),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_stream_recordings_operator_id_operators'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_stream_recordings')),
    sa.UniqueConstraint('engine_id', 'started_at', name=op.f('uq_stream_recordings_engine_id_started_at'))
    )
    with op.batch_alter_table('stream_recordings', schema=None) as batch_op:
        batch_op.create_index('ix_stream_recordings_operator_started', ['operator_id', 'started_at'], unique=False)

    op.create_table('uploads',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('api_key_id', sa.Integer(), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('kind', sa.String(length=16), nullable=False),
    sa.Column('content_format', sa.String(length=16), nullable=False),
    sa.Column('checksum', sa.String(length=64), nullable=False),
    sa.Column('idempotency_key', sa.String(length=200), nullable=True),
    sa.Column('status', sa.String(length=16), nullable=False),
    sa.Column('rows_received', sa.Integer(), nullable=False),
    sa.Column('rows_stored', sa.Integer(), nullable=False),
    sa.Column('rows_duplicate', sa.Integer(), nullable=False),
    sa.Column('bytes_received', sa.BigInteger(), nullable=False),
    sa.Column('message', sa.String(length=500), nullable=False),
    sa.Column('errors', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('affected', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('recording_id', sa.Integer(), nullable=True),
    sa.CheckConstraint("kind IN ('snapshots', 'stream', 'stream_chunk')", name=op.f('ck_uploads_kind')),
    sa.CheckConstraint("status IN ('stored', 'rejected')", name=op.f('ck_uploads_status')),
    sa.ForeignKeyConstraint(['api_key_id'], ['api_keys.id'], name=op.f('fk_uploads_api_key_id_api_keys'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_uploads_operator_id_operators'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['recording_id'], ['stream_recordings.id'], name=op.f('fk_uploads_recording_id_stream_recordings'), ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_uploads'))
    )
    with op.batch_alter_table('uploads', schema=None) as batch_op:
        batch_op.create_index('ix_uploads_operator_checksum', ['operator_id', 'checksum'], unique=False)
        batch_op.create_index('ix_uploads_operator_created', ['operator_id', 'created_at'], unique=False)
        batch_op.create_index('uq_uploads_operator_idempotency_key', ['operator_id', 'idempotency_key'], unique=True, sqlite_where=sa.text("status = 'stored'"), postgresql_where=sa.text("status = 'stored'"))

    op.create_table('snapshots',
    sa.Column('id', sa.BigInteger().with_variant(sa.Integer(), 'sqlite'), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_id', sa.Integer(), nullable=False),
    sa.Column('aircraft_id', sa.Integer(), nullable=False),
    sa.Column('position', sa.SmallInteger(), nullable=False),
    sa.Column('upload_id', sa.Integer(), nullable=False),
    sa.Column('recorded_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('phase', sa.String(length=8), nullable=False),
    sa.Column('flight_id', sa.String(length=64), nullable=True),
    sa.Column('alt_ft', sa.Double(), nullable=False),
    sa.Column('mach', sa.Double(), nullable=False),
    sa.Column('dtamb_k', sa.Double(), nullable=False),
    sa.Column('power_pct', sa.Double(), nullable=False),
    sa.Column('wf', sa.Double(), nullable=True),
    sa.Column('vsv', sa.Double(), nullable=True),
    sa.Column('vbv', sa.Double(), nullable=True),
    sa.Column('nf', sa.Double(), nullable=True),
    sa.Column('nc', sa.Double(), nullable=True),
    sa.Column('t24', sa.Double(), nullable=True),
    sa.Column('p24', sa.Double(), nullable=True),
    sa.Column('t30', sa.Double(), nullable=True),
    sa.Column('ps30', sa.Double(), nullable=True),
    sa.Column('p30', sa.Double(), nullable=True),
    sa.Column('t48', sa.Double(), nullable=True),
    sa.Column('p50', sa.Double(), nullable=True),
    sa.Column('t50', sa.Double(), nullable=True),
    sa.Column('p15', sa.Double(), nullable=True),
    sa.CheckConstraint("phase IN ('takeoff', 'climb', 'cruise')", name=op.f('ck_snapshots_phase')),
    sa.CheckConstraint('position BETWEEN 1 AND 4', name=op.f('ck_snapshots_position')),
    sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_snapshots_engine_id_engines')),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_snapshots')),
    sa.UniqueConstraint('engine_id', 'recorded_at', name=op.f('uq_snapshots_engine_id_recorded_at'))
    )
    op.create_table('stream_chunks',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('recording_id', sa.Integer(), nullable=False),
    sa.Column('chunk_index', sa.Integer(), nullable=False),
    sa.Column('upload_id', sa.Integer(), nullable=True),
    sa.Column('checksum', sa.String(length=64), nullable=False),
    sa.Column('first_sample', sa.Integer(), nullable=False),
    sa.Column('n_samples', sa.Integer(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['recording_id'], ['stream_recordings.id'], name=op.f('fk_stream_chunks_recording_id_stream_recordings'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['upload_id'], ['uploads.id'], name=op.f('fk_stream_chunks_upload_id_uploads'), ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_stream_chunks')),
    sa.UniqueConstraint('recording_id', 'chunk_index', name=op.f('uq_stream_chunks_recording_id_chunk_index'))
    )


def downgrade() -> None:
    op.drop_table('stream_chunks')
    op.drop_table('snapshots')
    with op.batch_alter_table('uploads', schema=None) as batch_op:
        batch_op.drop_index('uq_uploads_operator_idempotency_key', sqlite_where=sa.text("status = 'stored'"), postgresql_where=sa.text("status = 'stored'"))
        batch_op.drop_index('ix_uploads_operator_created')
        batch_op.drop_index('ix_uploads_operator_checksum')

    op.drop_table('uploads')
    with op.batch_alter_table('stream_recordings', schema=None) as batch_op:
        batch_op.drop_index('ix_stream_recordings_operator_started')

    op.drop_table('stream_recordings')
