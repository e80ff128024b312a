"""snapshots keyed by engine and time: the generated id goes

Revision ID: 0010
Revises: 0009
Create Date: 2026-11-22 10:40:00

A snapshot is one engine's report at one moment, and (engine_id, recorded_at) was unique
already. The generated id, which nothing reads since estimates stopped referring to it
(migration 0008), cost a sequence call and a second index entry per COPYed row: a binary COPY
of 100,000 rows took 0.37 s with it and 0.28 s with (engine_id, recorded_at) as the primary
key alone. Downgrade numbers the rows again.
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0010'
down_revision: str | None = '0009'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('snapshots', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('uq_snapshots_engine_id_recorded_at'), type_='unique')
        batch_op.drop_constraint(batch_op.f('pk_snapshots'), type_='primary')
        batch_op.drop_column('id')
        batch_op.create_primary_key(batch_op.f('pk_snapshots'), ['engine_id', 'recorded_at'])


def downgrade() -> None:
    with op.batch_alter_table('snapshots', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('pk_snapshots'), type_='primary')
    bigid = sa.BigInteger().with_variant(sa.Integer(), 'sqlite')
    if op.get_bind().dialect.name == 'postgresql':
        op.execute("ALTER TABLE snapshots ADD COLUMN id BIGSERIAL NOT NULL")
    else:
        with op.batch_alter_table('snapshots', schema=None) as batch_op:
            batch_op.add_column(sa.Column('id', bigid, nullable=True))
        op.execute("UPDATE snapshots SET id = rowid")
    with op.batch_alter_table('snapshots', schema=None) as batch_op:
        batch_op.alter_column('id', existing_type=bigid, nullable=False)
        batch_op.create_primary_key(batch_op.f('pk_snapshots'), ['id'])
        batch_op.create_unique_constraint(
            batch_op.f('uq_snapshots_engine_id_recorded_at'), ['engine_id', 'recorded_at']
        )
