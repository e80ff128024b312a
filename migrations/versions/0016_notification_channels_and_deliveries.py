"""notification channels, deliveries, their attempts and engine alert levels

Revision ID: 0016
Revises: 0015
Create Date: 2026-11-24 20:15:00

An operator's webhooks and e-mail (SMTP) channels; the deliveries the estimation pipeline queues
for the events it raises, and every attempt to send one (the delivery log); each engine's
severity when notifications last looked (an engine turning red is notified once).
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0016'
down_revision: str | None = '0015'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        'notification_channels',
        sa.Column('id', sa.Integer(), nullable=False),
        sa.Column('operator_id', sa.Integer(), nullable=False),
        sa.Column('kind', sa.String(length=16), nullable=False),
        sa.Column('name', sa.String(length=200), nullable=False),
        sa.Column('enabled', sa.Boolean(), nullable=False),
        sa.Column('url', sa.String(length=2000), nullable=True),
        sa.Column('secret', sa.String(length=200), nullable=True),
        sa.Column('smtp_host', sa.String(length=255), nullable=True),
        sa.Column('smtp_port', sa.Integer(), nullable=True),
        sa.Column('smtp_starttls', sa.Boolean(), nullable=False),
        sa.Column('smtp_username', sa.String(length=255), nullable=True),
        sa.Column('smtp_password', sa.String(length=255), nullable=True),
        sa.Column('mail_from', sa.String(length=320), nullable=True),
        sa.Column('mail_to', sa.Text(), nullable=True),
        sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
        sa.CheckConstraint("kind IN ('webhook', 'email')", name=op.f('ck_notification_channels_kind')),
        sa.ForeignKeyConstraint(
            ['operator_id'], ['operators.id'],
            name=op.f('fk_notification_channels_operator_id_operators'), ondelete='CASCADE',
        ),
        sa.PrimaryKeyConstraint('id', name=op.f('pk_notification_channels')),
    )
    op.create_index(
        op.f('ix_notification_channels_operator_id'), 'notification_channels', ['operator_id']
    )
    op.create_table(
        'notification_deliveries',
        sa.Column('id', sa.Integer(), nullable=False),
        sa.Column('operator_id', sa.Integer(), nullable=False),
        sa.Column('channel_id', sa.Integer(), nullable=False),
        sa.Column('event_id', sa.Integer(), nullable=True),
        sa.Column('subject', sa.String(length=300), nullable=False),
        sa.Column('payload', sa.JSON(), nullable=False),
        sa.Column('status', sa.String(length=16), nullable=False),
        sa.Column('attempts', sa.Integer(), nullable=False),
        sa.Column('next_attempt_at', sa.DateTime(timezone=True), nullable=False),
        sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
        sa.Column('sent_at', sa.DateTime(timezone=True), nullable=True),
        sa.CheckConstraint(
            "status IN ('pending', 'sent', 'failed')",
            name=op.f('ck_notification_deliveries_status'),
        ),
        sa.ForeignKeyConstraint(
            ['channel_id'], ['notification_channels.id'],
            name=op.f('fk_notification_deliveries_channel_id_notification_channels'),
            ondelete='CASCADE',
        ),
        sa.ForeignKeyConstraint(
            ['event_id'], ['events.id'],
            name=op.f('fk_notification_deliveries_event_id_events'), ondelete='SET NULL',
        ),
        sa.ForeignKeyConstraint(
            ['operator_id'], ['operators.id'],
            name=op.f('fk_notification_deliveries_operator_id_operators'), ondelete='CASCADE',
        ),
        sa.PrimaryKeyConstraint('id', name=op.f('pk_notification_deliveries')),
    )
    op.create_index(
        op.f('ix_notification_deliveries_channel_id'), 'notification_deliveries', ['channel_id']
    )
    op.create_index(
        op.f('ix_notification_deliveries_event_id'), 'notification_deliveries', ['event_id']
    )
    op.create_index(
        'ix_notification_deliveries_operator_status', 'notification_deliveries',
        ['operator_id', 'status'],
    )
    op.create_table(
        'delivery_attempts',
        sa.Column('id', sa.Integer(), nullable=False),
        sa.Column('delivery_id', sa.Integer(), nullable=False),
        sa.Column('attempted_at', sa.DateTime(timezone=True), nullable=False),
        sa.Column('ok', sa.Boolean(), nullable=False),
        sa.Column('status_code', sa.Integer(), nullable=True),
        sa.Column('error', sa.Text(), nullable=True),
        sa.Column('duration_ms', sa.Float(), nullable=False),
        sa.ForeignKeyConstraint(
            ['delivery_id'], ['notification_deliveries.id'],
            name=op.f('fk_delivery_attempts_delivery_id_notification_deliveries'),
            ondelete='CASCADE',
        ),
        sa.PrimaryKeyConstraint('id', name=op.f('pk_delivery_attempts')),
    )
    op.create_index(
        op.f('ix_delivery_attempts_delivery_id'), 'delivery_attempts', ['delivery_id']
    )
    op.create_table(
        'engine_alert_levels',
        sa.Column('engine_id', sa.Integer(), nullable=False),
        sa.Column('operator_id', sa.Integer(), nullable=False),
        sa.Column('level', sa.String(length=8), nullable=False),
        sa.Column('changed_at', sa.DateTime(timezone=True), nullable=False),
        sa.CheckConstraint(
            "level IN ('normal', 'amber', 'red')", name=op.f('ck_engine_alert_levels_level')
        ),
        sa.ForeignKeyConstraint(
            ['engine_id'], ['engines.id'],
            name=op.f('fk_engine_alert_levels_engine_id_engines'), ondelete='CASCADE',
        ),
        sa.ForeignKeyConstraint(
            ['operator_id'], ['operators.id'],
            name=op.f('fk_engine_alert_levels_operator_id_operators'), ondelete='CASCADE',
        ),
        sa.PrimaryKeyConstraint('engine_id', name=op.f('pk_engine_alert_levels')),
    )
    op.create_index(
        op.f('ix_engine_alert_levels_operator_id'), 'engine_alert_levels', ['operator_id']
    )


def downgrade() -> None:
    op.drop_table('engine_alert_levels')
    op.drop_table('delivery_attempts')
    op.drop_table('notification_deliveries')
    op.drop_table('notification_channels')
