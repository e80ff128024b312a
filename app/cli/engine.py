"""``fleethealth engine``: trim and linearise the built-in engine model."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated

import typer

cli = typer.Typer(help="The built-in two-spool turbofan: steady states and linear models.",
                  no_args_is_help=True)


def _parse_health(items: list[str]) -> dict[str, float]:
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            raise typer.BadParameter(f"{item!r}: expected NAME=PERCENT, e.g. hpc_eff=-2")
        try:
            v = float(value)
        except ValueError:
            raise typer.BadParameter(f"{item!r}: {value!r} is not a number") from None
        if not math.isfinite(v):
            raise typer.BadParameter(f"{item!r}: value must be finite")
        out[name.strip()] = v
    return out


def _health_vector(items: list[str]):
    from estimation.engine.health import health_vector

    try:
        return health_vector(_parse_health(items))
    except KeyError as exc:
        raise typer.BadParameter(str(exc.args[0])) from None


def _fail(exc: Exception) -> None:
    typer.echo(f"error: {exc}", err=True)
    raise typer.Exit(code=2)


@cli.command()
def trim(
    alt: float = typer.Option(..., "--alt", help="Altitude [ft], 0 to 40,000."),
    mach: float = typer.Option(..., "--mach", help="Flight Mach number, 0 to 0.85."),
    power: float = typer.Option(..., "--power", help="Power [%]: 0 idle, 100 take-off."),
    dtamb: float = typer.Option(0.0, "--dtamb", help="Ambient temperature offset from ISA [K]."),
    health: Annotated[list[str] | None, typer.Option(
        "--health", help="Health parameter shift NAME=PERCENT (repeatable), e.g. hpc_eff=-2."
    )] = None,
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    """Steady state: every sensor and auxiliary output with its unit."""
    health = health or []
    import numpy as np

    from estimation.engine.errors import EngineConvergenceError, EnvelopeError
    from estimation.engine.sensors import AUX_NAMES, AUX_UNITS, SENSOR_NAMES, SENSOR_UNITS
    from estimation.engine.steady import steady_state
    from estimation.engine.turbofan import INPUT_NAMES, INPUT_UNITS, STATE_NAMES, STATE_UNITS

    h = _health_vector(health)
    try:
        ss = steady_state(np.array([alt, mach, dtamb]), power=power, health=h)
    except (EnvelopeError, EngineConvergenceError) as exc:
        _fail(exc)
        return

    def group(names, units, values):
        return {n: {"value": float(v), "unit": u} for n, u, v in zip(names, units, values,
                                                                    strict=True)}

    out = {
        "operating_condition": {"alt_ft": alt, "mach": mach, "power_pct": power,
                                "dtamb_K": dtamb},
        "health": {k: v for k, v in _parse_health(health).items()},
        "sensors": group(SENSOR_NAMES, SENSOR_UNITS, ss.sensors),
        "aux": group(AUX_NAMES, AUX_UNITS, ss.aux),
        "states": group(STATE_NAMES, STATE_UNITS, ss.x),
        "inputs": group(INPUT_NAMES, INPUT_UNITS, ss.u),
    }
    if as_json:
        typer.echo(json.dumps(out, indent=2))
        return
    for section in ("sensors", "aux", "states", "inputs"):
        typer.echo(f"[{section}]")
        for name, item in out[section].items():
            typer.echo(f"  {name:8s} {item['value']:14.4f} {item['unit']}")


@cli.command()
def linearize(
    out: Annotated[Path, typer.Option("--out", help="Where to write the linear model JSON.")],
    alt: float = typer.Option(..., "--alt", help="Altitude [ft], 0 to 40,000."),
    mach: float = typer.Option(..., "--mach", help="Flight Mach number, 0 to 0.85."),
    power: float = typer.Option(..., "--power", help="Power [%]: 0 idle, 100 take-off."),
    dtamb: float = typer.Option(0.0, "--dtamb", help="Ambient temperature offset from ISA [K]."),
    health: Annotated[list[str] | None, typer.Option(
        "--health", help="Health parameter shift NAME=PERCENT (repeatable).")] = None,
    dt: float = typer.Option(0.015, "--dt", help="Sample time of the discrete model [s]."),
) -> None:
    """Write the discrete linear model (fleethealth.linear-model/1 JSON)."""
    health = health or []
    from estimation.engine.errors import EngineConvergenceError, EnvelopeError
    from estimation.engine.linearize import linearize as linearize_engine

    if not (math.isfinite(dt) and dt > 0):
        raise typer.BadParameter("--dt must be a positive number of seconds")
    h = _health_vector(health)
    try:
        model = linearize_engine(alt, mach, power, dtamb, health=h, dt=dt)
    except (EnvelopeError, EngineConvergenceError) as exc:
        _fail(exc)
        return
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(model.to_dict(), indent=1), encoding="utf-8")
    typer.echo(
        f"wrote {out}: {model.n_states} states, {model.n_inputs} inputs, "
        f"{model.n_health} health parameters, {model.n_sensors} sensors, {model.n_aux} aux"
    )
