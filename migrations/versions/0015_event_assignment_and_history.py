"""event assignment and history; borescope findings

Revision ID: 0015
Revises: 0014
Create Date: 2026-11-24 20:15:00

An alert can be assigned to a person (an analyst or admin API key of the operator:
``events.assignee_key_id``), and every step of its handling is kept in ``event_history``: who
assigned, acknowledged, commented on or closed it, when, and the reason given. A maintenance
action may be a borescope finding (kind ``borescope_finding``). Downgrade drops the history,
the assignments and the borescope findings.
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0015'
down_revision: str | None = '0014'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


OLD_KINDS = "kind IN ('water_wash', 'module_change', 'shop_visit')"
NEW_KINDS = "kind IN ('water_wash', 'module_change', 'shop_visit', 'borescope_finding')"


def upgrade() -> None:
    with op.batch_alter_table('maintenance_actions', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_maintenance_actions_kind'), type_='check')
        batch_op.create_check_constraint(batch_op.f('ck_maintenance_actions_kind'), NEW_KINDS)

    with op.batch_alter_table('events', schema=None) as batch_op:
        batch_op.add_column(sa.Column('assignee_key_id', sa.Integer(), nullable=True))
        batch_op.create_foreign_key(
            batch_op.f('fk_events_assignee_key_id_api_keys'), 'api_keys',
            ['assignee_key_id'], ['id'], ondelete='SET NULL',
        )

    op.create_table('event_history',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('event_id', sa.Integer(), nullable=False),
    sa.Column('action', sa.String(length=16), nullable=False),
    sa.Column('actor_key_id', sa.Integer(), nullable=True),
    sa.Column('actor', sa.String(length=200), nullable=False),
    sa.Column('assignee_key_id', sa.Integer(), nullable=True),
    sa.Column('assignee', sa.String(length=200), nullable=True),
    sa.Column('reason', sa.Text(), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.CheckConstraint(
        "action IN ('assigned', 'unassigned', 'acknowledged', 'commented', 'closed')",
        name=op.f('ck_event_history_action'),
    ),
    sa.ForeignKeyConstraint(['actor_key_id'], ['api_keys.id'], name=op.f('fk_event_history_actor_key_id_api_keys'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['assignee_key_id'], ['api_keys.id'], name=op.f('fk_event_history_assignee_key_id_api_keys'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['event_id'], ['events.id'], name=op.f('fk_event_history_event_id_events'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_event_history'))
    )
    with op.batch_alter_table('event_history', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_event_history_event_id'), ['event_id'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('event_history', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_event_history_event_id'))

    op.drop_table('event_history')
    with op.batch_alter_table('events', schema=None) as batch_op:
        batch_op.drop_constraint(
            batch_op.f('fk_events_assignee_key_id_api_keys'), type_='foreignkey'
        )
        batch_op.drop_column('assignee_key_id')

    op.execute("DELETE FROM maintenance_actions WHERE kind = 'borescope_finding'")
    with op.batch_alter_table('maintenance_actions', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_maintenance_actions_kind'), type_='check')
        batch_op.create_check_constraint(batch_op.f('ck_maintenance_actions_kind'), OLD_KINDS)
