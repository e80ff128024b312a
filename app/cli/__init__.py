"""The ``fleethealth`` command line."""

from __future__ import annotations

import typer

from app.cli import design, engine, evaluate, importers, service, simulate

app = typer.Typer(help="fleethealth: aircraft engine fleet health trending.", no_args_is_help=True)
service.register(app)
importers.register(app)
design.register(app)
evaluate.register(app)
simulate.register(app)
app.add_typer(engine.cli, name="engine")


def main() -> None:
    app()
