"""``fleethealth design SPEC.json --out DESIGN.json``: design a tuner Kalman filter.

Reads the design spec (``docs/design-format.md``), loads the model file it names
(a path relative to the spec), runs ``estimation.design.run_design``, prints the
analytic errors and writes the design result.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from estimation.design import run_design
from estimation.errors import (
    DesignSpecError,
    DimensionError,
    ModelFormatError,
    UnknownSignalError,
    UnobservableDesignError,
)

cli = typer.Typer(help="Estimator design.", no_args_is_help=True)


def register(app: typer.Typer) -> None:
    """Add the ``design`` command to another Typer app."""
    app.command("design")(design)


def _read_json(path: Path, what: str) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise typer.BadParameter(f"cannot read {what} {path}: {exc.strerror}") from exc
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise typer.BadParameter(
            f"{what} {path} is not JSON: line {exc.lineno} column {exc.colno}: {exc.msg}"
        ) from exc


def load_spec_and_model(spec_path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """The spec dict and the model dict it names (``model`` is relative to the spec;
    an inline model object is accepted too)."""
    spec = _read_json(spec_path, "design spec")
    if not isinstance(spec, dict):
        raise typer.BadParameter(f"design spec {spec_path} must be a JSON object")
    ref = spec.get("model")
    if isinstance(ref, dict):
        return spec, ref
    if not isinstance(ref, str) or not ref:
        raise typer.BadParameter("design spec needs 'model': the path of a model file")
    model_path = Path(ref)
    if not model_path.is_absolute():
        model_path = spec_path.parent / model_path
    model = _read_json(model_path, "model file")
    if not isinstance(model, dict):
        raise typer.BadParameter(f"model file {model_path} must be a JSON object")
    return spec, model


def error_table(result: dict[str, Any]) -> str:
    """Plain-text table of the analytic squared bias, variance and squared error."""
    theory = result["theory"]
    lines = [
        f"design: {result['method']} tuners, m = {len(result['tuners'])}, "
        f"sensors: {', '.join(result['sensors'])}",
        f"{'':2}{'signal':<16}{'bias^2':>12}{'variance':>12}{'sq. error':>12}",
    ]
    for group, total in (("health", "ssee_health"), ("aux", "ssee_aux")):
        block = theory[group]
        if not block["names"]:
            continue
        lines.append(f"{group}:")
        for name, b2, var in zip(block["names"], block["bias2"], block["variance"], strict=True):
            lines.append(f"{'':2}{name:<16}{b2:>12.4f}{var:>12.4f}{b2 + var:>12.4f}")
        lines.append(
            f"{'':2}{'SSEE':<16}{sum(block['bias2']):>12.4f}{sum(block['variance']):>12.4f}"
            f"{theory[total]:>12.4f}"
        )
    if "faults" in result:
        lines.append(f"sum of pairwise misclassification probabilities: "
                     f"{result['faults']['pmc_sum']:.4f}")
    return "\n".join(lines)


def design(
    spec: Annotated[
        Path, typer.Argument(help="Design spec file (fleethealth.design-spec/1).")
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="Design result file to write.")],
) -> None:
    """Design a tuner Kalman filter from SPEC.json and write DESIGN.json."""
    spec_dict, model_dict = load_spec_and_model(spec)
    try:
        result = run_design(
            spec_dict, model_dict, progress=lambda msg: typer.echo(msg, err=True)
        )
    except UnobservableDesignError as exc:
        typer.echo(f"error: design is not observable: {exc}", err=True)
        raise typer.Exit(code=2) from exc
    except (DesignSpecError, ModelFormatError, DimensionError, UnknownSignalError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from exc
    except ValueError as exc:  # fault library or noise values the estimator refuses
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from exc
    typer.echo(error_table(result))
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    except OSError as exc:
        typer.echo(f"error: cannot write {out}: {exc.strerror}", err=True)
        raise typer.Exit(code=1) from exc
    typer.echo(f"wrote {out}")


register(cli)
