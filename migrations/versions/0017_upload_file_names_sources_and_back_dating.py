"""upload file names, sources and back-dating

Revision ID: 0017
Revises: 0016
Create Date: 2026-11-24 20:40:00

Each upload keeps the name of the file it came from (a multipart part's file name or the
``filename`` query parameter of a raw body), its source (the uploads page, the C-MAPSS
importer or another API client) and the name of the API key that sent it at the time, and
whether it was back-dated: records older than an affected engine's last estimated record.
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0017'
down_revision: str | None = '0016'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('uploads', schema=None) as batch_op:
        batch_op.add_column(sa.Column('filename', sa.String(length=255), nullable=True))
        batch_op.add_column(
            sa.Column('source', sa.String(length=16), nullable=False, server_default='api')
        )
        batch_op.add_column(sa.Column('api_key_name', sa.String(length=200), nullable=True))
        batch_op.add_column(
            sa.Column('back_dated', sa.Boolean(), nullable=False, server_default=sa.false())
        )
        batch_op.create_check_constraint(
            batch_op.f('ck_uploads_source'), "source IN ('browser', 'cli', 'api')"
        )


def downgrade() -> None:
    with op.batch_alter_table('uploads', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_uploads_source'), type_='check')
        batch_op.drop_column('back_dated')
        batch_op.drop_column('api_key_name')
        batch_op.drop_column('source')
        batch_op.drop_column('filename')
