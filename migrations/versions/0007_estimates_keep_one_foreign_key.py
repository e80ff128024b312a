"""estimates keep one foreign key (design_id)

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-22 06:43:12.955137

The estimation job COPYs one estimate row per snapshot; PostgreSQL checks every foreign key of
every row with a lock on the referenced row, and with four of them finishing the COPY ran at
about 28,000 rows/s. As on ``snapshots`` (migration 0003 keeps only engine_id), only the key
that does work stays:

- design_id -> estimator_designs ON DELETE CASCADE: deleting a design (the demo fleet replaces
  its designs) must delete the estimates computed under it.
- snapshot_id, engine_id, operator_id are written by the pipeline from the snapshot row it has
  just read in the same transaction (``pipeline._load_records``). Their cascades never fired:
  snapshots are never deleted, and an engine or operator with snapshots cannot be deleted
  (snapshots.engine_id has no ON DELETE), so no estimate can outlive them.

Indexes stay as they are, each serving a query: the primary key; (engine_id, design_id, seq) for
trends, re-runs (``seq >= seq0``) and the one-record-per-seq rule; (snapshot_id, design_id) for
the pending-work anti-join and one estimate per snapshot and design; design_id for the fleet
status query and the cascade from a design.
"""
from collections.abc import Sequence

from alembic import op

revision: str = '0007'
down_revision: str | None = '0006'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

# (constraint, referenced table, column) of the keys this revision drops.
DROPPED = (
    ("fk_estimates_snapshot_id_snapshots", "snapshots", "snapshot_id"),
    ("fk_estimates_operator_id_operators", "operators", "operator_id"),
    ("fk_estimates_engine_id_engines", "engines", "engine_id"),
)


def upgrade() -> None:
    with op.batch_alter_table('estimates', schema=None) as batch_op:
        for name, _table, _column in DROPPED:
            batch_op.drop_constraint(batch_op.f(name), type_='foreignkey')


def downgrade() -> None:
    with op.batch_alter_table('estimates', schema=None) as batch_op:
        for name, table, column in DROPPED:
            batch_op.create_foreign_key(
                batch_op.f(name), table, [column], ['id'], ondelete='CASCADE'
            )
