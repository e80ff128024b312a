"""Snapshots of an engine type with signals of its own: what storing them by name costs.

Two engine types with the same single-point model (the reference model of the tests), one
under the signal catalogue's names (Nf, Nc, T24, Ps30, T30, T48, Wf, VSV, VBV: the fixed
columns of the snapshot table) and one under names of its own (N1, N2, T25, PS3, T3, EGT, FF,
IGV, BLEED: the JSON object ``other_signals``). The same N rows, sensor values taken from
``fleethealth simulate``'s snapshots, are stored through the product's path
(``uploads.store.ingest_snapshots``: parse, validate per type, resolve, COPY or executemany) and
read back as the estimation reads them (``snapshots.rows.load_records`` from the database,
every engine of a batch at once), for each type. The other signals must not cost the
catalogue's path anything (it writes no JSON column at all) and should stay within the ingest
budget (50,000 snapshots/s end to end with estimation, issue 12): ingest and read of the
type's own names <= 2x the fixed columns' time.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 \\
        .venv/bin/python bench/bench_other_signals.py [--rows 100000] [--backends postgresql,sqlite]
"""

from __future__ import annotations

import argparse
import io
import subprocess
import sys
import tempfile
import time
import uuid
from datetime import UTC, datetime, timedelta
from pathlib import Path

import _common  # noqa: F401  (pins BLAS threads)
import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
from _common import ROOT, run_on_backends

from app.db import make_engine, make_sessionmaker, transaction
from app.migrate import upgrade
from app.services.designs import engine_models
from app.services.fleet import service as fleet
from app.services.snapshots import rows as snapshot_rows
from app.services.tenancy import service as tenancy
from app.services.uploads import store
from app.services.uploads.parse import split_unit
from app.signals import stored_at
from tests.app.services.uploads.test_parameter_sets import (
    CUSTOM_INPUTS,
    CUSTOM_SENSORS,
    custom_model_file,
)
from tests.estimation.models import reference_model

T0 = datetime(2026, 1, 1, tzinfo=UTC)
ENGINES = 100


def simulated_values(rows: int) -> dict[str, np.ndarray]:
    """Sensor and actuator columns of ``fleethealth simulate`` snapshots, repeated to
    ``rows`` rows (catalogue names, stored units)."""
    with tempfile.TemporaryDirectory(prefix="fh-bench-") as tmp:
        subprocess.run([sys.executable, "-c", "from app.cli import main; main()", "simulate",
                        "--aircraft", "4", "--flights", "60", "--mode", "snapshot", "--seed",
                        "12", "--format", "csv", "--out", tmp],
                       check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
        table = pacsv.read_csv(Path(tmp) / "snapshots.csv")
    columns = {split_unit(c)[0]: c for c in table.column_names}  # "Nf[rpm]": stored units
    reps = -(-rows // table.num_rows)
    return {n: np.tile(np.asarray(table[columns[n]].to_numpy(zero_copy_only=False), float),
                       reps)[:rows] for n in [*CUSTOM_SENSORS, *CUSTOM_INPUTS]}


def body(values: dict[str, np.ndarray], renamed: dict[str, str], tail_prefix: str) -> bytes:
    """CSV of the rows on ENGINES / 2 twin-engine aircraft, signals under ``renamed`` names
    without a declared unit, a renamed one scaled from its simulated mean to its trim in the
    type's model (in that model's units)."""
    trim = custom_model_file()["trim"]
    n = len(next(iter(values.values())))
    i = np.arange(n)
    columns: dict[str, pa.Array] = {
        "recorded_at": pa.array(T0 + timedelta(hours=1) * (i // ENGINES).astype(object),
                                pa.timestamp("us", tz="UTC")),
        "tail": pa.array([f"{tail_prefix}{k:03d}" for k in (i % ENGINES) // 2]),
        "position": pa.array(1 + i % 2),
    }
    for name, vals in values.items():
        target = renamed.get(name, name)
        columns[target] = pa.array(vals if target == name else vals / vals.mean() * trim[target])
    sink = io.BytesIO()
    pacsv.write_csv(pa.table(columns), sink)
    return sink.getvalue()


def run(url: str, label: str, rows: int, values: dict[str, np.ndarray]) -> bool:
    upgrade(url)
    engine = make_engine(url)
    factory = make_sessionmaker(engine)
    own = {k: v[0] for k, v in {**CUSTOM_SENSORS, **CUSTOM_INPUTS}.items()}
    plan = {"catalogue": ({}, "C", reference_model().to_dict()),
            "own names": (own, "O", custom_model_file())}
    with transaction(factory) as session:
        operator = tenancy.create_operator(session, name=f"bench {uuid.uuid4().hex[:6]}")
        engines: dict[str, list[int]] = {}
        for kind, (_renamed, prefix, model) in plan.items():
            et = fleet.create_engine_type(session, operator_id=operator.id, name=kind)
            engine_models.import_engine_model(session, operator_id=operator.id,
                                              engine_type_id=et.id, name="point", content=model)
            engines[kind] = []
            for a in range(ENGINES // 2):
                ac = fleet.create_aircraft(session, operator_id=operator.id,
                                           tail=f"{prefix}{a:03d}")
                for position in (1, 2):
                    e = fleet.create_engine(session, operator_id=operator.id,
                                            esn=f"{prefix}{a}-{position}", engine_type_id=et.id)
                    fleet.install(session, operator_id=operator.id, engine_id=e.id,
                                  aircraft_id=ac.id, position=position,
                                  installed_at=T0 - timedelta(days=1))
                    engines[kind].append(e.id)
        operator_id = operator.id
    print(f"{label}: {rows} snapshots of {ENGINES} engines per type, 9 signals each")
    times = {}
    for kind, (renamed, prefix, _model) in plan.items():
        data = body(values, renamed, prefix)
        t0 = time.perf_counter()
        with transaction(factory) as session:
            result = store.ingest_snapshots(session, operator_id=operator_id, api_key_id=None,
                                            body=data, content_format="csv")
        ingest = time.perf_counter() - t0
        assert result.upload.rows_stored == rows, result.upload.message
        names = [renamed.get(n, n) for n in values]
        places = tuple(stored_at(n) for n in names)
        t0 = time.perf_counter()
        with transaction(factory) as session:
            loaded = snapshot_rows.load_records(
                session, [(e, None) for e in engines[kind]], places, ())
        read = time.perf_counter() - t0
        got = np.concatenate([r.y for r in loaded.values()])
        assert got.shape == (rows, len(names)) and np.isfinite(got).all()
        times[kind] = (ingest, read)
        print(f"  {kind:10s} ingest {ingest:6.3f} s ({rows / ingest:9,.0f}/s)   "
              f"read {read:6.3f} s ({rows / read:9,.0f}/s)")
    engine.dispose()
    ratio = [times["own names"][k] / times["catalogue"][k] for k in (0, 1)]
    ok = all(r <= 2.0 for r in ratio)
    print(f"  own names / catalogue: ingest {ratio[0]:.2f}x, read {ratio[1]:.2f}x "
          f"(target <= 2x) -> {'PASS' if ok else 'FAIL'}")
    return ok


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--backends", default="postgresql,sqlite")
    args = ap.parse_args()
    values = simulated_values(args.rows)
    run_on_backends(args.backends, lambda url, label: run(url, label, args.rows, values))


if __name__ == "__main__":
    main()
