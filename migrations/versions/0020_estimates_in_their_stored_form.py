"""estimates in their stored form: bit-packed numbers, no operator or phase column; stream
recordings say when their samples were removed

Revision ID: 0020
Revises: 0019
Create Date: 2026-11-25 01:00:00

An estimate row kept its 71 numbers (the built-in engine's) as float32, 284 bytes, beside
operator_id and phase: about 440 bytes a record on PostgreSQL with its key and index. It now
keeps them as ``EstimateLayout.encode`` packs them (59 bytes: 7-bit 1-sigmas, 12-bit values
as multiples of their 1-sigma, 8-bit residuals and WSSRs, the phase in two spare bits; the
health values and their sigmas follow from the tuners through V*^+, now named on
``filter_states.layout["health_from_tuners"]``), and the columns are ordered so that no
alignment padding is left: under 150 bytes a record. The upgrade rebuilds the table, engine by
engine and design by design, from each filter state's layout and its design's V*; rows of no
filter state (which no reader could name) are not kept. The downgrade rebuilds the float32 rows
from the decoded numbers (within the stored precision, docs/data-flow.md), the phase from the
blob and the operator from the filter state.

``stream_recordings.samples_removed_at``: when the stream sample retention
(``stream_retention_days``) deleted the recording's Parquet files; null: they are kept.
"""
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects.postgresql import JSONB

revision: str = '0020'
down_revision: str | None = '0019'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

PHASES = ("takeoff", "climb", "cruise")  # app.signals.PHASES at this revision
# The stored phase codes: the flight phases, and "" for a record of a type without phases.
STORED_PHASES = (*PHASES, "")
BATCH = 200  # (engine, design) pairs converted per round trip
JSON_DOCUMENT = sa.JSON().with_variant(JSONB(), 'postgresql')


def _json(value: Any) -> Any:
    import json

    return json.loads(value) if isinstance(value, str) else value


def _pairs(bind: sa.Connection) -> list[tuple[int, int, int, dict[str, Any], Any]]:
    """(operator, engine, design, layout document, the design's result) of each filter state."""
    rows = bind.execute(sa.text(
        "SELECT f.operator_id, f.engine_id, f.design_id, f.layout, d.result "
        "FROM filter_states f JOIN estimator_designs d ON d.id = f.design_id "
        "ORDER BY f.design_id, f.engine_id"
    )).all()
    return [(int(o), int(e), int(d), _json(layout), _json(result))
            for o, e, d, layout, result in rows]


def _health_from_tuners(layout: dict[str, Any], result: Any) -> list[list[float]] | None:
    """V*^+ = V*^T (V* V*^T)^-1 of the design, when its V* fits the layout's names."""
    vstar = None if not isinstance(result, dict) else result.get("vstar")
    if vstar is None:
        return None
    V = np.asarray(vstar, dtype=float)
    if V.ndim != 2 or V.shape != (len(layout["tuners"]), len(layout["health"])):
        return None
    vp: list[list[float]] = np.linalg.solve(V @ V.T, V).T.tolist()
    return vp


def _chunks(pairs: list[Any]) -> Iterator[list[Any]]:
    for start in range(0, len(pairs), BATCH):
        yield pairs[start:start + BATCH]


def _old_table(name: str) -> sa.Table:
    return sa.table(
        name,
        sa.column('operator_id', sa.Integer()), sa.column('engine_id', sa.Integer()),
        sa.column('design_id', sa.Integer()), sa.column('seq', sa.Integer()),
        sa.column('recorded_at', sa.DateTime(timezone=True)),
        sa.column('phase', sa.String(16)), sa.column('packed', sa.LargeBinary()),
    )


def _new_table(name: str) -> sa.Table:
    return sa.table(
        name,
        sa.column('recorded_at', sa.DateTime(timezone=True)),
        sa.column('engine_id', sa.Integer()), sa.column('design_id', sa.Integer()),
        sa.column('seq', sa.Integer()), sa.column('packed', sa.LargeBinary()),
    )


def _rows_of(bind: sa.Connection, table: sa.Table, columns: list[str],
             pairs: list[tuple[int, int]]) -> dict[tuple[int, int], list[Any]]:
    """Rows of the given (engine, design) pairs, in seq order, grouped by pair."""
    out: dict[tuple[int, int], list[Any]] = {p: [] for p in pairs}
    engines = sorted({e for e, _d in pairs})
    designs = sorted({d for _e, d in pairs})
    query = (
        sa.select(table.c.engine_id, table.c.design_id, *[table.c[c] for c in columns])
        .where(table.c.engine_id.in_(engines), table.c.design_id.in_(designs))
        .order_by(table.c.engine_id, table.c.design_id, table.c.seq)
    )
    for row in bind.execute(query):
        key = (int(row[0]), int(row[1]))
        if key in out:
            out[key].append(row[2:])
    return out


def _create(name: str, new: bool) -> None:
    # PostgreSQL's constraint names are index names, one per schema: renamed after the swap.
    # SQLite's live in the table's text only: the final name from the start.
    pk = 'pk_estimates_next' if op.get_bind().dialect.name == 'postgresql' else 'pk_estimates'
    if new:
        op.create_table(
            name,
            sa.Column('recorded_at', sa.DateTime(timezone=True), nullable=False),
            sa.Column('engine_id', sa.Integer(), nullable=False),
            sa.Column('design_id', sa.Integer(), nullable=False),
            sa.Column('seq', sa.Integer(), nullable=False),
            sa.Column('packed', sa.LargeBinary(), nullable=False),
            sa.PrimaryKeyConstraint('engine_id', 'design_id', 'seq', name=pk),
        )
        if op.get_bind().dialect.name == 'postgresql':
            # A blob of tens of bytes, kept in line (MAIN: never moved to TOAST; rows of ~100
            # bytes are far below the size at which PostgreSQL would compress one). Not PLAIN:
            # a PLAIN bytea keeps a 4-byte length word where MAIN's short one takes 1 byte,
            # which with its alignment costs 8 bytes a row.
            op.execute(f"ALTER TABLE {name} ALTER COLUMN packed SET STORAGE MAIN")
    else:
        op.create_table(
            name,
            sa.Column('engine_id', sa.Integer(), nullable=False),
            sa.Column('design_id', sa.Integer(), nullable=False),
            sa.Column('seq', sa.Integer(), nullable=False),
            sa.Column('operator_id', sa.Integer(), nullable=False),
            sa.Column('recorded_at', sa.DateTime(timezone=True), nullable=False),
            sa.Column('phase', sa.String(length=16), nullable=False),
            sa.Column('packed', sa.LargeBinary(), nullable=False),
            sa.PrimaryKeyConstraint('engine_id', 'design_id', 'seq', name=pk),
        )


def _swap(old: str) -> None:
    """Drop ``estimates``'s previous form (renamed ``old``), give the new one its name."""
    op.drop_table(old)
    op.rename_table('estimates_next', 'estimates')
    if op.get_bind().dialect.name == 'postgresql':
        op.execute("ALTER INDEX pk_estimates_next RENAME TO pk_estimates")


def upgrade() -> None:
    from app.models.estimates import EstimateLayout

    with op.batch_alter_table('stream_recordings', schema=None) as batch_op:
        batch_op.add_column(
            sa.Column('samples_removed_at', sa.DateTime(timezone=True), nullable=True)
        )
    bind = op.get_bind()
    _create('estimates_next', new=True)
    old, new = _old_table('estimates'), _new_table('estimates_next')
    phase_index = {name: i for i, name in enumerate(STORED_PHASES)}
    pairs = _pairs(bind)
    for chunk in _chunks(pairs):
        rows = _rows_of(bind, old, ['seq', 'recorded_at', 'phase', 'packed'],
                        [(e, d) for _o, e, d, _l, _r in chunk])
        for _operator, engine_id, design_id, layout_doc, result in chunk:
            doc = dict(layout_doc)
            vp = _health_from_tuners(doc, result)
            if vp is not None:
                doc['health_from_tuners'] = vp
            bind.execute(sa.text(
                "UPDATE filter_states SET layout = :layout WHERE engine_id = :e AND design_id = :d"
            ).bindparams(sa.bindparam('layout', type_=JSON_DOCUMENT)),
                {"layout": doc, "e": engine_id, "d": design_id})
            got = rows[(engine_id, design_id)]
            if not got:
                continue
            layout = EstimateLayout.from_dict(doc)
            floats = np.frombuffer(b"".join(bytes(r[3]) for r in got), dtype="<f4")
            values = floats.reshape(len(got), layout.width).astype(np.float64)
            stored = layout.encode(values, np.array([phase_index[r[2]] for r in got]))
            bind.execute(sa.insert(new), [
                {"recorded_at": r[1], "engine_id": engine_id, "design_id": design_id,
                 "seq": r[0], "packed": blob.tobytes()}
                for r, blob in zip(got, stored, strict=True)
            ])
    op.rename_table('estimates', 'estimates_float32')
    if bind.dialect.name == 'postgresql':
        op.execute("ALTER INDEX pk_estimates RENAME TO pk_estimates_float32")
    _swap('estimates_float32')


def downgrade() -> None:
    from app.models.estimates import EstimateLayout

    with op.batch_alter_table('stream_recordings', schema=None) as batch_op:
        batch_op.drop_column('samples_removed_at')
    bind = op.get_bind()
    _create('estimates_next', new=False)
    old, new = _new_table('estimates'), _old_table('estimates_next')
    pairs = _pairs(bind)
    for chunk in _chunks(pairs):
        rows = _rows_of(bind, old, ['seq', 'recorded_at', 'packed'],
                        [(e, d) for _o, e, d, _l, _r in chunk])
        for operator_id, engine_id, design_id, layout_doc, _result in chunk:
            doc = dict(layout_doc)
            layout = EstimateLayout.from_dict(doc)
            doc.pop('health_from_tuners', None)
            bind.execute(sa.text(
                "UPDATE filter_states SET layout = :layout WHERE engine_id = :e AND design_id = :d"
            ).bindparams(sa.bindparam('layout', type_=JSON_DOCUMENT)),
                {"layout": doc, "e": engine_id, "d": design_id})
            got = rows[(engine_id, design_id)]
            if not got:
                continue
            decoded = layout.decode(b"".join(bytes(r[2]) for r in got), len(got))
            floats = decoded.values.astype("<f4")
            bind.execute(sa.insert(new), [
                {"operator_id": operator_id, "engine_id": engine_id, "design_id": design_id,
                 "seq": r[0], "recorded_at": r[1], "phase": STORED_PHASES[int(code)],
                 "packed": row.tobytes()}
                for r, code, row in zip(got, decoded.phase, floats, strict=True)
            ])
    op.rename_table('estimates', 'estimates_packed')
    if bind.dialect.name == 'postgresql':
        op.execute("ALTER INDEX pk_estimates RENAME TO pk_estimates_packed")
    _swap('estimates_packed')
