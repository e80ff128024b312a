"""cron job schedules and late uploads

Revision ID: 0018
Revises: 0017
Create Date: 2026-11-24 21:50:00

A job schedule runs at the times of a five-field cron expression (UTC) or every
``interval_seconds``, exactly one of the two: ``cron`` is added and ``interval_seconds`` may be
null; existing schedules keep their interval. Each upload counts the records it carried that
were recorded longer before it arrived than the lateness (``rows_late``); existing uploads
count none.
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0018'
down_revision: str | None = '0017'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

CRON_OR_INTERVAL = (
    "(cron IS NULL AND interval_seconds IS NOT NULL) "
    "OR (cron IS NOT NULL AND interval_seconds IS NULL)"
)


def upgrade() -> None:
    with op.batch_alter_table('job_schedules', schema=None) as batch_op:
        batch_op.add_column(sa.Column('cron', sa.String(length=100), nullable=True))
        batch_op.alter_column('interval_seconds', existing_type=sa.Integer(), nullable=True)
        batch_op.create_check_constraint(
            batch_op.f('ck_job_schedules_cron_or_interval'), CRON_OR_INTERVAL
        )
    with op.batch_alter_table('uploads', schema=None) as batch_op:
        batch_op.add_column(
            sa.Column('rows_late', sa.Integer(), nullable=False, server_default='0')
        )


def downgrade() -> None:
    with op.batch_alter_table('uploads', schema=None) as batch_op:
        batch_op.drop_column('rows_late')
    # Cron schedules have no interval to fall back to: they go with the column.
    op.execute("DELETE FROM job_schedules WHERE cron IS NOT NULL")
    with op.batch_alter_table('job_schedules', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_job_schedules_cron_or_interval'), type_='check')
        batch_op.alter_column('interval_seconds', existing_type=sa.Integer(), nullable=False)
        batch_op.drop_column('cron')
