"""Severity on the demo fleet: the state distribution, why each red engine is red, and the
status's EGT and thrust figures against the simulator's truth.

The demo fleet is seeded as ``fleethealth serve`` seeds it on first start
(``demo.ensure_demo_fleet``: simulated, uploaded and estimated through the product, the active
design calibrated) on a throw-away database (``--backend``, dropped after; the built-in engine's
schedule read from ``--cache``), or read from a database that holds it (``--url``). The bench
regenerates the demo's fleet plan from its seed (cheap: no snapshots) and compares each engine's
status with its true health after the last round: the take-off dEGT on an ISA+15 K day
(corrected, over theta2 there, like the status's), and the thrust deficit where the status
states it, at its latest record's own condition and power setting (altitude, Mach, ambient
temperature and power of the snapshot it estimated), both from the steady-state solver; the
take-off thrust change is printed beside it for reference. Engines removed before the end
(their last data is older) are compared against a health they no longer had when last
reported. BLAS threads pinned (one).

    .venv/bin/python bench/bench_severity.py [--backend sqlite] [--url URL]
"""

from __future__ import annotations

import argparse
import collections
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import _common
import numpy as np
from sqlalchemy import select

from app.db import make_engine, make_sessionmaker, transaction
from app.migrate import upgrade
from app.models import Engine, Operator
from app.services.demo import fleet as demo
from app.services.demo.operator import DEMO_OPERATOR, ensure_demo_operator
from app.services.fleet import performance, status
from app.services.snapshots.estimator import builtin_schedule
from estimation.engine.fleet import plan_fleet
from estimation.engine.steady import steady_state


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", default="sqlite", help="the throw-away database's")
    ap.add_argument("--url", default=None, help="a database holding the demo fleet")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"),
                    help="the built-in engine's schedule cache")
    args = ap.parse_args()
    print(_common.load_line())
    with _common.schedule_cache(args.cache):
        if args.url:
            report(args.url)
            return
        with _common.throwaway_database(args.backend) as (url, label), \
                tempfile.TemporaryDirectory(prefix="fh-severity-") as keys:
            upgrade(url)
            factory = make_sessionmaker(make_engine(url))
            with transaction(factory) as session:
                ensure_demo_operator(session, Path(keys))
            t0 = time.perf_counter()
            demo.ensure_demo_fleet(factory, echo=lambda _m: None)
            print(f"demo fleet seeded on {label} in {time.perf_counter() - t0:.0f} s")
            report(url)
    print(_common.load_line())


def report(url: str) -> None:
    factory = make_sessionmaker(make_engine(url))
    with factory() as session:
        operator_id = session.scalar(select(Operator.id).where(Operator.name == DEMO_OPERATOR))
        if operator_id is None:
            raise SystemExit("no demo operator in this database")
        status.fleet_status(session, operator_id)  # schedule and caches warm
        t = time.perf_counter()
        engines = status.fleet_status(session, operator_id)["engines"]
        elapsed = time.perf_counter() - t
    print(f"fleet status: {len(engines)} engines in {elapsed:.3f} s")
    print("severity:", dict(collections.Counter(e["severity"] for e in engines)))
    why: collections.Counter[str] = collections.Counter()
    for e in engines:
        if e["severity"] == "red":
            reds = sorted(c["limit"] for c in e["checks"] if c["level"] == "red")
            why[("event + " if e["open_events"] else "") + (", ".join(reds) or "-")] += 1
    for reason, n in why.most_common():
        print(f"  red by {reason}: {n}")

    config = replace(demo.fleet_config(demo.DemoSize()), start_epoch_s=0.0)
    plan_rng, _ = np.random.default_rng(demo.SEED).spawn(2)
    plan = plan_fleet(config, plan_rng)
    health = plan.health[-1]
    n = health.shape[0]
    takeoff = np.tile([0.0, 0.0, 15.0], (n, 1))
    nominal = steady_state(takeoff[:1], power=np.array([100.0]))
    true = steady_state(takeoff, power=np.full(n, 100.0), health=health)
    ref = performance.type_reference(builtin_schedule())
    by_esn = {e["esn"]: e for e in engines}
    last = max(e["last_data"] for e in engines if e["last_data"] is not None)
    print("\nesn         true dEGT  status dEGT   true thrust  status thrust   true thrust"
          "\n            (TO, ISA+15, corrected)   (latest record's condition)   (TO, ISA+15)")
    errors, thrust_errors = [], []
    with factory() as session:
        for k, esn in enumerate(plan.esns):
            e = by_esn.get(esn)
            checks = {c["limit"]: c["value"] for c in (e or {}).get("checks", [])}
            if e is None or "egt_margin" not in checks:
                continue
            redline = 1100.0  # the built-in type's default
            # Corrected (over theta2 at the reference, ISA+15 K), as the status's dEGT is.
            d_true = (true.sensors[k, 7] - nominal.sensors[0, 7]) / 1.8 / ref.theta_reference
            d_status = (redline - checks["egt_margin"] - ref.egt_reference_c) / ref.theta_reference
            fn_takeoff = 100.0 * (1.0 - true.aux[k, 0] / nominal.aux[0, 0])
            fn_true = latest_thrust_deficit(session, operator_id, esn, e, health[k])
            fn_status = checks.get("thrust_deficit", float("nan"))
            current = (last - e["last_data"]).days < 2
            if current:
                errors.append(d_status - d_true)
                thrust_errors.append(fn_status - fn_true)
            print(f"{esn}  {d_true:9.1f}  {d_status:11.1f}   {fn_true:11.2f}  {fn_status:13.2f}"
                  f"   {fn_takeoff:11.1f}{'' if current else '   (removed: last data older)'}")
    err, fn_err = np.abs(errors), np.abs(np.asarray(thrust_errors))
    fn_err = fn_err[np.isfinite(fn_err)]
    print(f"\ndEGT, status against truth over {len(err)} engines with current data: "
          f"median |error| {np.median(err):.1f} K, largest {err.max():.1f} K")
    print(f"thrust deficit at the latest record's condition, status against truth over "
          f"{len(fn_err)} engines: median |error| {np.median(fn_err):.2f} points, largest "
          f"{fn_err.max():.2f}")


def latest_thrust_deficit(session: Any, operator_id: int, esn: str, e: dict[str, Any],
                          health: np.ndarray) -> float:
    """The true thrust deficit [%] at the condition and power setting of the snapshot whose
    estimate the status shows (``health`` the engine's true health): 100 (1 - Fn / Fn_nominal)
    from the steady-state solver, NaN without that snapshot."""
    engine_id = session.scalar(select(Engine.id).where(Engine.operator_id == operator_id,
                                                       Engine.esn == esn))
    if engine_id is None or not e.get("health"):
        return float("nan")
    epoch = np.array([e["health"]["recorded_at"].timestamp()])
    cond = performance.record_conditions(session, engine_id, epoch).conditions[0]
    if not np.all(np.isfinite(cond)):
        return float("nan")
    env, power = cond[None, :3], np.array([cond[3]])
    fn = steady_state(env, power=power, health=health[None, :]).aux[0, 0]
    fn_nominal = steady_state(env, power=power).aux[0, 0]
    return float(100.0 * (1.0 - fn / fn_nominal))


if __name__ == "__main__":
    main()
