"""wear events: the kind ``wear`` and one event per record and kind

Revision ID: 0012
Revises: 0011
Create Date: 2026-11-24 16:10:00

The wear detector (estimation.wear, run in the pipeline next to the shift detector) raises
events of kind ``wear``. A wear alert and a shift may fall on the same record, so an event is
unique per (engine, design, record, kind) rather than per record. Downgrade deletes the wear
events.
"""
from collections.abc import Sequence

from alembic import op

revision: str = '0012'
down_revision: str | None = '0011'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('events', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_events_kind'), type_='check')
        batch_op.create_check_constraint(
            batch_op.f('ck_events_kind'), "kind IN ('shift', 'isolated_fault', 'wear')"
        )
        batch_op.drop_constraint(batch_op.f('uq_events_engine_id_design_id_seq'), type_='unique')
        batch_op.create_unique_constraint(
            batch_op.f('uq_events_engine_id_design_id_seq_kind'),
            ['engine_id', 'design_id', 'seq', 'kind'],
        )


def downgrade() -> None:
    op.execute("DELETE FROM events WHERE kind = 'wear'")
    with op.batch_alter_table('events', schema=None) as batch_op:
        batch_op.drop_constraint(
            batch_op.f('uq_events_engine_id_design_id_seq_kind'), type_='unique'
        )
        batch_op.create_unique_constraint(
            batch_op.f('uq_events_engine_id_design_id_seq'), ['engine_id', 'design_id', 'seq']
        )
        batch_op.drop_constraint(batch_op.f('ck_events_kind'), type_='check')
        batch_op.create_check_constraint(
            batch_op.f('ck_events_kind'), "kind IN ('shift', 'isolated_fault')"
        )
