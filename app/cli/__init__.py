"""The ``fleethealth`` command line."""

from __future__ import annotations

import os

# The service's matrices are small and its workers many: BLAS threads only contend
# (a design gain takes ~15 ms single-threaded, 100-240 ms with default threads under load).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import typer

from app.cli import bias, design, engine, evaluate, importers, service, simulate

app = typer.Typer(help="fleethealth: aircraft engine fleet health trending.", no_args_is_help=True)
service.register(app)
importers.register(app)
design.register(app)
evaluate.register(app)
simulate.register(app)
bias.register(app)
app.add_typer(engine.cli, name="engine")


def main() -> None:
    app()
