"""snapshots indexed by tail position and time

Revision ID: 0014
Revises: 0013
Create Date: 2026-11-24 20:00:00

Recording or correcting an installation moves the snapshots of its tail position over its
period to the engine it puts there. The only index was (engine_id, recorded_at), so each such
change read the whole table (0.33 s at 2.2M rows, 10.5 min to set up a 1,150-engine fleet).
"""
from collections.abc import Sequence

from alembic import op

revision: str = '0014'
down_revision: str | None = '0013'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_index(
        'ix_snapshots_aircraft_position_time', 'snapshots',
        ['aircraft_id', 'position', 'recorded_at'],
    )


def downgrade() -> None:
    op.drop_index('ix_snapshots_aircraft_position_time', table_name='snapshots')
