"""``fleethealth fit-bias DESIGN_ID RECORDING_ID...``: fit a design's transient bias model
(seed 004, docs/math.md section 7) on recordings of healthy engines and store it with the
design; stream estimation then applies it."""

from __future__ import annotations

import json
from typing import Annotated

import typer

from app.config import get_settings


def register(app: typer.Typer) -> None:
    """Add the ``fit-bias`` command to another Typer app."""
    app.command("fit-bias")(fit_bias)


def fit_bias(
    design_id: Annotated[int, typer.Argument(help="the design to fit")],
    recording_ids: Annotated[list[int], typer.Argument(help="recordings of healthy engines")],
    ti_star: Annotated[float, typer.Option(min=0.0, help="dead band of the index, 1/s")] = 1e-3,
    ti_tau_s: Annotated[float, typer.Option(min=0.0, help="low-pass on the index, s")] = 0.5,
) -> None:
    """Fit and store a design's transient bias model; prints its summary as JSON."""
    from app.db import make_engine, make_sessionmaker, transaction
    from app.errors import ServiceError
    from app.services.streams import bias

    settings = get_settings()
    try:
        with transaction(make_sessionmaker(make_engine(settings.resolved_database_url))) as s:
            operator_id = bias.design_operator(s, design_id)
            out = bias.fit_and_store(
                s, settings.data_dir, operator_id=operator_id, design_id=design_id,
                recording_ids=recording_ids, ti_star=ti_star, ti_tau_s=ti_tau_s,
                progress=lambda f, m: typer.echo(f"{100 * f:5.1f} % {m or ''}", err=True),
            )
    except ServiceError as exc:
        raise typer.BadParameter(str(exc)) from exc
    typer.echo(json.dumps(out))
