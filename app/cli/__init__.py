"""The ``fleethealth`` command line."""

from __future__ import annotations

import typer

from app.cli import importers, service

app = typer.Typer(help="fleethealth: aircraft engine fleet health trending.", no_args_is_help=True)
service.register(app)
importers.register(app)


def main() -> None:
    app()
