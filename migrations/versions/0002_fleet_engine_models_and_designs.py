"""fleet, engine models and designs

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-22 04:41:05.675878
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

revision: str = '0002'
down_revision: str | None = '0001'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('aircraft',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('tail', sa.String(length=32), nullable=False),
    sa.Column('aircraft_type', sa.String(length=64), nullable=True),
    sa.Column('engine_positions', sa.Integer(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.CheckConstraint('engine_positions BETWEEN 1 AND 4', name=op.f('ck_aircraft_positions')),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_aircraft_operator_id_operators'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_aircraft')),
    sa.UniqueConstraint('operator_id', 'tail', name=op.f('uq_aircraft_operator_id_tail'))
    )
    with op.batch_alter_table('aircraft', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_aircraft_operator_id'), ['operator_id'], unique=False)

    op.create_table('engine_types',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=100), nullable=False),
    sa.Column('description', sa.Text(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_engine_types_operator_id_operators'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_engine_types')),
    sa.UniqueConstraint('operator_id', 'name', name=op.f('uq_engine_types_operator_id_name'))
    )
    with op.batch_alter_table('engine_types', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_engine_types_operator_id'), ['operator_id'], unique=False)

    op.create_table('engine_models',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_type_id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=100), nullable=False),
    sa.Column('version', sa.Integer(), nullable=False),
    sa.Column('source', sa.String(length=16), nullable=False),
    sa.Column('format', sa.String(length=64), nullable=False),
    sa.Column('content', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('checksum', sa.String(length=64), nullable=False),
    sa.Column('dt', sa.Float(), nullable=False),
    sa.Column('n_states', sa.Integer(), nullable=False),
    sa.Column('sensor_names', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('health_names', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('aux_names', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('locked_at', sa.DateTime(timezone=True), nullable=True),
    sa.CheckConstraint("source IN ('imported', 'builtin')", name=op.f('ck_engine_models_source')),
    sa.CheckConstraint('version >= 1', name=op.f('ck_engine_models_version')),
    sa.ForeignKeyConstraint(['engine_type_id'], ['engine_types.id'], name=op.f('fk_engine_models_engine_type_id_engine_types'), ondelete='RESTRICT'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_engine_models_operator_id_operators'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_engine_models')),
    sa.UniqueConstraint('engine_type_id', 'name', 'version', name=op.f('uq_engine_models_engine_type_id_name_version'))
    )
    with op.batch_alter_table('engine_models', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_engine_models_engine_type_id'), ['engine_type_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_engine_models_operator_id'), ['operator_id'], unique=False)

    op.create_table('engines',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('esn', sa.String(length=64), nullable=False),
    sa.Column('engine_type_id', sa.Integer(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['engine_type_id'], ['engine_types.id'], name=op.f('fk_engines_engine_type_id_engine_types'), ondelete='RESTRICT'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_engines_operator_id_operators'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_engines')),
    sa.UniqueConstraint('operator_id', 'esn', name=op.f('uq_engines_operator_id_esn'))
    )
    with op.batch_alter_table('engines', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_engines_engine_type_id'), ['engine_type_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_engines_operator_id'), ['operator_id'], unique=False)

    op.create_table('estimator_designs',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_type_id', sa.Integer(), nullable=False),
    sa.Column('engine_model_id', sa.Integer(), nullable=False),
    sa.Column('name', sa.String(length=100), nullable=False),
    sa.Column('spec', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=False),
    sa.Column('status', sa.String(length=16), nullable=False),
    sa.Column('result', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=True),
    sa.Column('analytic_errors', sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), 'postgresql'), nullable=True),
    sa.Column('ssee_health', sa.Float(), nullable=True),
    sa.Column('ssee_aux', sa.Float(), nullable=True),
    sa.Column('failure', sa.Text(), nullable=True),
    sa.Column('active', sa.Boolean(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('completed_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('activated_at', sa.DateTime(timezone=True), nullable=True),
    sa.CheckConstraint("NOT active OR status = 'ready'", name=op.f('ck_estimator_designs_active_ready')),
    sa.CheckConstraint("status IN ('pending', 'ready', 'failed')", name=op.f('ck_estimator_designs_status')),
    sa.ForeignKeyConstraint(['engine_model_id'], ['engine_models.id'], name=op.f('fk_estimator_designs_engine_model_id_engine_models'), ondelete='RESTRICT'),
    sa.ForeignKeyConstraint(['engine_type_id'], ['engine_types.id'], name=op.f('fk_estimator_designs_engine_type_id_engine_types'), ondelete='RESTRICT'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_estimator_designs_operator_id_operators'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_estimator_designs'))
    )
    with op.batch_alter_table('estimator_designs', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_estimator_designs_engine_model_id'), ['engine_model_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_estimator_designs_engine_type_id'), ['engine_type_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_estimator_designs_operator_id'), ['operator_id'], unique=False)
        batch_op.create_index('uq_estimator_designs_active_engine_type', ['engine_type_id'], unique=True, sqlite_where=sa.text('active'), postgresql_where=sa.text('active'))

    op.create_table('installations',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_id', sa.Integer(), nullable=False),
    sa.Column('aircraft_id', sa.Integer(), nullable=False),
    sa.Column('position', sa.Integer(), nullable=False),
    sa.Column('installed_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('removed_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.CheckConstraint('position BETWEEN 1 AND 4', name=op.f('ck_installations_position')),
    sa.CheckConstraint('removed_at IS NULL OR removed_at > installed_at', name=op.f('ck_installations_period')),
    sa.ForeignKeyConstraint(['aircraft_id'], ['aircraft.id'], name=op.f('fk_installations_aircraft_id_aircraft'), ondelete='RESTRICT'),
    sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_installations_engine_id_engines'), ondelete='RESTRICT'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_installations_operator_id_operators'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_installations'))
    )
    with op.batch_alter_table('installations', schema=None) as batch_op:
        batch_op.create_index('ix_installations_aircraft_position', ['aircraft_id', 'position', 'installed_at'], unique=False)
        batch_op.create_index('ix_installations_engine_installed', ['engine_id', 'installed_at'], unique=False)
        batch_op.create_index(batch_op.f('ix_installations_operator_id'), ['operator_id'], unique=False)

    op.create_table('maintenance_actions',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=False),
    sa.Column('engine_id', sa.Integer(), nullable=False),
    sa.Column('kind', sa.String(length=32), nullable=False),
    sa.Column('performed_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('notes', sa.Text(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.CheckConstraint("kind IN ('water_wash', 'module_change', 'shop_visit')", name=op.f('ck_maintenance_actions_kind')),
    sa.ForeignKeyConstraint(['engine_id'], ['engines.id'], name=op.f('fk_maintenance_actions_engine_id_engines'), ondelete='RESTRICT'),
    sa.ForeignKeyConstraint(['operator_id'], ['operators.id'], name=op.f('fk_maintenance_actions_operator_id_operators'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_maintenance_actions'))
    )
    with op.batch_alter_table('maintenance_actions', schema=None) as batch_op:
        batch_op.create_index('ix_maintenance_actions_engine_performed', ['engine_id', 'performed_at'], unique=False)
        batch_op.create_index(batch_op.f('ix_maintenance_actions_operator_id'), ['operator_id'], unique=False)

    _add_installation_exclusions()


# Installations must not overlap for one engine nor for one tail position. The service checks
# it under a row lock; on PostgreSQL an exclusion constraint also holds it for any writer. It
# needs btree_gist (a trusted extension since PostgreSQL 13); without it the service check stays.
EXCLUSIONS = {
    'ex_installations_engine_period': 'engine_id WITH =',
    'ex_installations_position_period': 'aircraft_id WITH =, position WITH =',
}


def _add_installation_exclusions() -> None:
    bind = op.get_bind()
    if bind.dialect.name != 'postgresql':
        return
    available = bind.execute(
        sa.text("SELECT 1 FROM pg_available_extensions WHERE name = 'btree_gist'")
    ).scalar()
    if not available:
        return
    try:
        with bind.begin_nested():
            bind.execute(sa.text('CREATE EXTENSION IF NOT EXISTS btree_gist'))
    except sa.exc.DBAPIError:
        return  # no privilege to create it: the service-level check remains
    for name, keys in EXCLUSIONS.items():
        op.execute(
            f'ALTER TABLE installations ADD CONSTRAINT {name} EXCLUDE USING gist '
            f"({keys}, tstzrange(installed_at, removed_at, '[)') WITH &&)"
        )



def downgrade() -> None:
    if op.get_bind().dialect.name == 'postgresql':
        for name in EXCLUSIONS:
            op.execute(f'ALTER TABLE installations DROP CONSTRAINT IF EXISTS {name}')
    with op.batch_alter_table('maintenance_actions', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_maintenance_actions_operator_id'))
        batch_op.drop_index('ix_maintenance_actions_engine_performed')

    op.drop_table('maintenance_actions')
    with op.batch_alter_table('installations', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_installations_operator_id'))
        batch_op.drop_index('ix_installations_engine_installed')
        batch_op.drop_index('ix_installations_aircraft_position')

    op.drop_table('installations')
    with op.batch_alter_table('estimator_designs', schema=None) as batch_op:
        batch_op.drop_index('uq_estimator_designs_active_engine_type', sqlite_where=sa.text('active'), postgresql_where=sa.text('active'))
        batch_op.drop_index(batch_op.f('ix_estimator_designs_operator_id'))
        batch_op.drop_index(batch_op.f('ix_estimator_designs_engine_type_id'))
        batch_op.drop_index(batch_op.f('ix_estimator_designs_engine_model_id'))

    op.drop_table('estimator_designs')
    with op.batch_alter_table('engines', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_engines_operator_id'))
        batch_op.drop_index(batch_op.f('ix_engines_engine_type_id'))

    op.drop_table('engines')
    with op.batch_alter_table('engine_models', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_engine_models_operator_id'))
        batch_op.drop_index(batch_op.f('ix_engine_models_engine_type_id'))

    op.drop_table('engine_models')
    with op.batch_alter_table('engine_types', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_engine_types_operator_id'))

    op.drop_table('engine_types')
    with op.batch_alter_table('aircraft', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_aircraft_operator_id'))

    op.drop_table('aircraft')
