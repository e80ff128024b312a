"""``fleethealth simulate``: a simulated fleet in the upload formats, plus its ground truth."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from app.services.demo import simulation_files
from estimation.engine.fleet import FleetConfig, fleet_snapshots, plan_fleet, stream_flights


def register(app: typer.Typer) -> None:
    app.command("simulate")(simulate)


def simulate(
    out: Annotated[Path, typer.Option("--out", help="Output directory.")],
    aircraft: int = typer.Option(4, "--aircraft", min=1, help="Number of aircraft."),
    flights: int = typer.Option(10, "--flights", min=1, help="Flights per aircraft."),
    mode: str = typer.Option("snapshot", "--mode", help="snapshot or stream."),
    seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same fleet)."),
    rate_hz: float | None = typer.Option(
        None, "--rate-hz", min=0.001, help="Stream rate [Hz]; default every 15 ms step."
    ),
    positions: int = typer.Option(2, "--positions", min=1, max=4, help="Engines per aircraft."),
    file_format: Annotated[list[str] | None, typer.Option(
        "--format", help="csv and/or parquet (repeat the option); default both."
    )] = None,
    stream_seconds: float | None = typer.Option(
        None, "--stream-seconds", min=0.1, help="Cut stream flights short (seconds)."
    ),
) -> None:
    """Simulate a fleet and write snapshots or stream flights plus truth.json."""
    file_format = list(file_format or simulation_files.FORMATS)
    if mode not in ("snapshot", "stream"):
        raise typer.BadParameter("must be 'snapshot' or 'stream'", param_hint="--mode")
    for fmt in file_format:
        if fmt not in simulation_files.FORMATS:
            raise typer.BadParameter(f"unknown format {fmt!r}", param_hint="--format")
    config = FleetConfig(n_aircraft=aircraft, n_flights=flights, positions=positions)
    plan_rng, snap_rng, stream_rng = np.random.default_rng(seed).spawn(3)
    started = time.perf_counter()
    plan = plan_fleet(config, plan_rng)
    written = simulation_files.write_truth(plan, out)
    if mode == "snapshot":
        with typer.progressbar(length=flights, label="snapshot rounds") as bar:
            snaps = fleet_snapshots(plan, snap_rng, on_round=lambda _j: bar.update(1))
        written += simulation_files.write_snapshots(snaps, out, file_format)
        what = f"{snaps.recorded_at.size} snapshots"
    else:
        n_streams = aircraft * positions * flights
        with typer.progressbar(length=1000, label="stream flights (simulated time)") as bar:
            done = [0]

            def advance(fraction: float) -> None:
                step = int(1000 * fraction) - done[0]
                if step > 0:
                    bar.update(step)
                    done[0] += step

            manifest = simulation_files.write_streams(
                stream_flights(plan, stream_rng, rate_hz, stream_seconds, on_progress=advance),
                out, file_format,
            )
        written.append(manifest)
        what = f"{n_streams} stream flights"
    typer.echo(
        f"{what} of {aircraft} aircraft ({len(plan.esns)} engines, {len(plan.faults)} faults, "
        f"{len(plan.swaps)} swaps) written to {out} in {time.perf_counter() - started:.1f} s"
    )
    for path in written:
        typer.echo(f"  {path}")
