"""bulk paths keep no per-row checks: snapshots and estimates lose their foreign keys

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-22 07:35:00

A bulk upload COPYs one snapshot row per record and the estimation job one estimate row per
snapshot. PostgreSQL checks a foreign key per COPYed row with a lookup and a lock on the
referenced row: measured on 100,000 rows, the one key left on ``snapshots`` (engine_id) cost
40 % of the COPY (1.54 s -> 0.90 s without it), and each index of ``estimates`` more still.
Both tables are written only by services that resolve what they write from rows they hold:

- snapshots.engine_id comes from the installation the record resolves to, under the upload's
  transaction; an engine with data cannot be deleted (``fleet.delete_engine`` checks for its
  snapshots and answers 409, as the foreign key's refusal did).
- estimates are derived data keyed by (engine_id, design_id, seq), now their primary key:
  the surrogate id, the snapshot id (the snapshot is (engine_id, recorded_at), which the row
  carries) and their two indexes go, and so does the design's cascade. A design with estimates
  is never deleted (no route deletes designs; the demo deletes only a design whose creation
  failed, before it estimated anything).
- filter states and checkpoints drop ``last_snapshot_id`` (never read; ``last_recorded_at``
  names the same record), so the estimation job can take an upload's records from memory
  without their generated ids.

Downgrade restores the columns, keys and indexes; snapshot ids come back from
(engine_id, recorded_at).
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0008'
down_revision: str | None = '0007'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('snapshots', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('fk_snapshots_engine_id_engines'), type_='foreignkey')
    with op.batch_alter_table('estimates', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_estimates_design_id'))
        batch_op.drop_constraint(
            batch_op.f('fk_estimates_design_id_estimator_designs'), type_='foreignkey'
        )
        batch_op.drop_constraint(batch_op.f('uq_estimates_snapshot_id_design_id'), type_='unique')
        batch_op.drop_constraint(
            batch_op.f('uq_estimates_engine_id_design_id_seq'), type_='unique'
        )
        batch_op.drop_constraint(batch_op.f('pk_estimates'), type_='primary')
        batch_op.drop_column('snapshot_id')
        batch_op.drop_column('id')
        batch_op.create_primary_key(
            batch_op.f('pk_estimates'), ['engine_id', 'design_id', 'seq']
        )
    for table in ('filter_states', 'filter_checkpoints'):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.drop_column('last_snapshot_id')


def downgrade() -> None:
    bigid = sa.BigInteger().with_variant(sa.Integer(), 'sqlite')
    for table, nullable in (('filter_states', True), ('filter_checkpoints', False)):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.add_column(sa.Column('last_snapshot_id', bigid, nullable=True))
        op.execute(
            f"UPDATE {table} SET last_snapshot_id = (SELECT s.id FROM snapshots s WHERE "
            f"s.engine_id = {table}.engine_id AND s.recorded_at = {table}.last_recorded_at)"
        )
        if not nullable:
            with op.batch_alter_table(table, schema=None) as batch_op:
                batch_op.alter_column('last_snapshot_id', existing_type=bigid, nullable=False)
    with op.batch_alter_table('estimates', schema=None) as batch_op:
        batch_op.add_column(sa.Column('snapshot_id', bigid, nullable=True))
    op.execute(
        "UPDATE estimates SET snapshot_id = (SELECT s.id FROM snapshots s WHERE "
        "s.engine_id = estimates.engine_id AND s.recorded_at = estimates.recorded_at)"
    )
    with op.batch_alter_table('estimates', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('pk_estimates'), type_='primary')
        batch_op.alter_column('snapshot_id', existing_type=bigid, nullable=False)
    if op.get_bind().dialect.name == 'postgresql':
        op.execute("ALTER TABLE estimates ADD COLUMN id BIGSERIAL NOT NULL")
    else:
        with op.batch_alter_table('estimates', schema=None) as batch_op:
            batch_op.add_column(sa.Column('id', bigid, nullable=True))
        op.execute("UPDATE estimates SET id = rowid")
    with op.batch_alter_table('estimates', schema=None) as batch_op:
        batch_op.create_primary_key(batch_op.f('pk_estimates'), ['id'])
        batch_op.create_unique_constraint(
            batch_op.f('uq_estimates_engine_id_design_id_seq'), ['engine_id', 'design_id', 'seq']
        )
        batch_op.create_unique_constraint(
            batch_op.f('uq_estimates_snapshot_id_design_id'), ['snapshot_id', 'design_id']
        )
        batch_op.create_foreign_key(
            batch_op.f('fk_estimates_design_id_estimator_designs'), 'estimator_designs',
            ['design_id'], ['id'], ondelete='CASCADE',
        )
        batch_op.create_index(batch_op.f('ix_estimates_design_id'), ['design_id'], unique=False)
    with op.batch_alter_table('snapshots', schema=None) as batch_op:
        batch_op.create_foreign_key(
            batch_op.f('fk_snapshots_engine_id_engines'), 'engines', ['engine_id'], ['id']
        )
