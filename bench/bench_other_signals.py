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
type's own names <= 2x the fixed columns' time. Each of ``--rounds`` rounds stores the rows
of both types for a new operator, the types in turn, and the best time of each is compared
(the least disturbed run, as ``_common.best_time`` takes it).

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
from typing import Any

import _common  # noqa: F401  (pins BLAS threads)
import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
from _common import ROOT, cpu_seconds, load_line, run_on_backends
from sqlalchemy.orm import Session, sessionmaker

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


Plan = dict[str, tuple[dict[str, str], str, dict[str, Any]]]


class Clock:
    """One transaction timed: wall seconds, and CPU seconds of this process (its COPY writer
    thread included) and of the PostgreSQL backend serving it (when the server runs on this
    machine: ``/proc``), which a loaded machine does not inflate as it does the wall time."""

    def __init__(self, factory: sessionmaker[Session]) -> None:
        self._transaction = transaction(factory)
        self.wall = self.cpu = 0.0
        self.shown = ""

    def __enter__(self) -> Clock:
        self.session = self._transaction.__enter__()
        driver = self.session.connection().connection.driver_connection
        info = getattr(driver, "info", None)
        self._backend = getattr(info, "backend_pid", None)
        self._server0 = cpu_seconds(self._backend) if self._backend else 0.0
        self._cpu0, self._t0 = time.process_time(), time.perf_counter()
        return self

    def __exit__(self, *exc: Any) -> None:
        client = time.process_time() - self._cpu0
        server = cpu_seconds(self._backend) - self._server0 if self._backend else 0.0
        self._transaction.__exit__(*exc)
        self.wall = time.perf_counter() - self._t0
        self.cpu = client + server
        self.shown = (f"CPU {client:.2f} + server {server:.2f} s" if self._backend
                      else f"CPU {client:.2f} s")


def fleet_of(factory: sessionmaker[Session], plan: Plan) -> tuple[int, dict[str, list[int]]]:
    """A new operator with both types, their model and ENGINES engines each on aircraft;
    (operator id, engine ids by type)."""
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
        return operator.id, engines


def run(url: str, label: str, rows: int, values: dict[str, np.ndarray], rounds: int) -> bool:
    upgrade(url)
    engine = make_engine(url)
    factory = make_sessionmaker(engine)
    own = {k: v[0] for k, v in {**CUSTOM_SENSORS, **CUSTOM_INPUTS}.items()}
    plan: Plan = {"catalogue": ({}, "C", reference_model().to_dict()),
                  "own names": (own, "O", custom_model_file())}
    print(f"{label}: {rows} snapshots of {ENGINES} engines per type, 9 signals each, "
          f"{rounds} rounds (each a new operator; the types in turn), the best of each")
    times: dict[str, list[tuple[float, float]]] = {kind: [] for kind in plan}
    cpu: dict[str, list[tuple[float, float]]] = {kind: [] for kind in plan}
    for k in range(rounds):
        operator_id, engines = fleet_of(factory, plan)
        for kind, (renamed, prefix, _model) in plan.items():
            data = body(values, renamed, prefix)
            with Clock(factory) as ingest:
                result = store.ingest_snapshots(ingest.session, operator_id=operator_id,
                                                api_key_id=None, body=data, content_format="csv")
            assert result.upload.rows_stored == rows, result.upload.message
            names = [renamed.get(n, n) for n in values]
            places = tuple(stored_at(n) for n in names)
            with Clock(factory) as read:
                loaded = snapshot_rows.load_records(
                    read.session, [(e, None) for e in engines[kind]], places, ())
            got = np.concatenate([r.y for r in loaded.values()])
            assert got.shape == (rows, len(names)) and np.isfinite(got).all()
            times[kind].append((ingest.wall, read.wall))
            cpu[kind].append((ingest.cpu, read.cpu))
            print(f"  round {k + 1} {kind:10s} ingest {ingest.wall:6.3f} s "
                  f"({rows / ingest.wall:9,.0f}/s, {ingest.shown})   read {read.wall:6.3f} s "
                  f"({rows / read.wall:9,.0f}/s, {read.shown})   "
                  f"{load_line().split(';')[0]}")
    engine.dispose()
    best = {kind: (min(t[0] for t in ts), min(t[1] for t in ts)) for kind, ts in times.items()}
    for kind, (w_ingest, w_read) in best.items():
        print(f"  best {kind:10s} ingest {w_ingest:6.3f} s ({rows / w_ingest:9,.0f}/s)   "
              f"read {w_read:6.3f} s ({rows / w_read:9,.0f}/s)")
    ratio = [best["own names"][k] / best["catalogue"][k] for k in (0, 1)]
    ok = all(r <= 2.0 for r in ratio)
    least = {kind: (min(c[0] for c in cs), min(c[1] for c in cs)) for kind, cs in cpu.items()}
    cpu_ratio = [least["own names"][k] / least["catalogue"][k] for k in (0, 1)]
    print(f"  own names / catalogue: ingest {ratio[0]:.2f}x, read {ratio[1]:.2f}x "
          f"(target <= 2x) -> {'PASS' if ok else 'FAIL'}; CPU (least of the rounds): ingest "
          f"{cpu_ratio[0]:.2f}x, read {cpu_ratio[1]:.2f}x")
    return ok


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--backends", default="postgresql,sqlite")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    values = simulated_values(args.rows)
    run_on_backends(args.backends,
                    lambda url, label: run(url, label, args.rows, values, args.rounds))


if __name__ == "__main__":
    main()
