"""``fleethealth evaluate``: Monte Carlo check of a design result file.

Reads a ``fleethealth.design/1`` file (written by ``fleethealth design``; it
embeds the design model, and the source model with every health parameter),
runs the seed 002 Table 5 experiment (SSEE, theory next to Monte Carlo) and,
with ``--faults``, the Tables 6-9 isolation experiment; prints both and writes
RESULT.json.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

RESULT_FORMAT = "fleethealth.evaluation/1"

cli = typer.Typer(help="Monte Carlo evaluation of estimator designs.")


def register(app: typer.Typer) -> None:
    """Mount ``evaluate`` on the ``fleethealth`` app (same as ``app.add_typer(cli)``)."""
    app.add_typer(cli)


def _load_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise typer.BadParameter(f"{what} file {path} does not exist") from None
    except json.JSONDecodeError as exc:
        raise typer.BadParameter(f"{what} file {path} is not JSON: {exc}") from None


def _load_design(path: Path):
    """TunerDesign, truth model (all health parameters) and fault library of a result file."""
    from estimation.design import design_from_result
    from estimation.isolation import faults_from_list
    from estimation.model import LinearModel

    result = _load_json(path, "design")
    if not isinstance(result, dict):
        raise typer.BadParameter(f"design file {path} must hold a JSON object")
    try:
        design = design_from_result(result)
        truth = (
            LinearModel.from_dict(result["source_model"]) if "source_model" in result else None
        )
        library = (result.get("faults") or {}).get("library")
        faults = faults_from_list(library) if library else None
    except (ValueError, KeyError) as exc:
        raise typer.BadParameter(f"design file {path}: {exc}") from None
    return design, truth, faults


@contextmanager
def _progress(enabled: bool) -> Iterator[Callable[[str], Callable[[float], None]]]:
    """Yields ``task(label) -> update(fraction)``; a rich progress bar on a terminal."""
    if not enabled:
        yield lambda label: (lambda fraction: None)
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(
        TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>5.1f}%"),
        TimeElapsedColumn(), transient=True,
    ) as bar:

        def task(label: str) -> Callable[[float], None]:
            tid = bar.add_task(label, total=1.0)
            return lambda fraction: bar.update(tid, completed=fraction)

        yield task


def _ssee_table(exp) -> str:
    names = exp.health_names
    w = max(9, *(len(n) for n in names))
    lines = [
        f"{'parameter':<{w}} {'bias^2':>9} {'variance':>9} {'theory':>9} {'monte carlo':>12} "
        f"{'+-se':>7}"
    ]
    for i, n in enumerate(names):
        lines.append(
            f"{n:<{w}} {exp.theory_bias2[i]:9.4f} {exp.theory_variance[i]:9.4f} "
            f"{exp.theory_squared_error[i]:9.4f} {exp.squared_error[i]:12.4f} "
            f"{exp.standard_error[i]:7.4f}"
        )
    total_se = float(np.sqrt(np.sum(exp.standard_error**2)))
    lines.append(
        f"{'SSEE':<{w}} {np.sum(exp.theory_bias2):9.4f} {np.sum(exp.theory_variance):9.4f} "
        f"{exp.ssee_theory:9.4f} {exp.ssee:12.4f} {total_se:7.4f}"
    )
    return "\n".join(lines)


def _confusion_table(name: str, conf) -> str:
    w = max(5, *(len(f) for f in conf.faults))
    head = " " * (w + 1) + " ".join(f"{f:>{w}}" for f in conf.faults)
    lines = [f"{name}: rows true fault, columns isolated fault (%)", head]
    for f, row in zip(conf.faults, conf.percent, strict=True):
        lines.append(f"{f:<{w}} " + " ".join(f"{v:>{w}.1f}" for v in row))
    lines.append(f"overall correct isolation rate: {conf.correct_rate:.1f} %")
    return "\n".join(lines)


@cli.command("evaluate")
def evaluate(
    design_file: Annotated[
        Path, typer.Argument(metavar="DESIGN.json", help="Design result file.")
    ],
    monte_carlo: int = typer.Option(200, "--monte-carlo", min=2, help="Monte Carlo cases."),
    seed: int = typer.Option(0, "--seed", help="Random seed."),
    faults: bool = typer.Option(False, "--faults", help="Also run the isolation experiment."),
    out: Annotated[
        Path | None, typer.Option("--out", metavar="RESULT.json", help="Result file.")
    ] = None,
    duration: float = typer.Option(30.0, help="Seconds per SSEE case."),
    window: float = typer.Option(10.0, help="Error window at the end of each case (s)."),
    fault_duration: float = typer.Option(300.0, help="Seconds per fault case."),
    fault_runs: int = typer.Option(1, min=1, help="Runs per fault."),
    diagnostic: Annotated[
        Path | None,
        typer.Option(metavar="DESIGN2.json", help="A diagnostics-aware design to compare."),
    ] = None,
    progress: bool | None = typer.Option(
        None, "--progress/--no-progress", help="Progress bar (default: on a terminal)."
    ),
) -> None:
    """Monte Carlo SSEE of a design next to its theory, and with --faults the confusion
    matrices of WSSR isolation on q_hat and y_hat and of the max-|h_hat| rule."""
    from estimation import evaluate as ev

    design, truth, library = _load_design(design_file)
    diag = _load_design(diagnostic)[0] if diagnostic is not None else None
    rng = np.random.default_rng(seed)
    show = sys.stderr.isatty() if progress is None else progress
    result: dict[str, Any] = {
        "format": RESULT_FORMAT,
        "design": str(design_file),
        "seed": seed,
        "method": design.method,
    }
    with _progress(show) as task:
        mc = ev.ssee_monte_carlo(
            design, monte_carlo, rng=rng, duration=duration, window=window,
            progress=task(f"SSEE Monte Carlo ({monte_carlo} cases)"),
        )
        result["monte_carlo"] = mc.to_dict()
        typer.echo(
            f"Health parameter squared estimation error (percent^2), {mc.n_cases} cases, "
            f"{mc.duration:g} s each, last {mc.window:.2f} s"
        )
        typer.echo(_ssee_table(mc))
        if faults:
            companion_note = "max_h from a companion design with actuator-bias health parameters"
            try:
                companion = ev.max_h_companion(design, library, truth)
            except ValueError as exc:
                companion, companion_note = None, f"max_h from the design itself ({exc})"
            try:
                iso = ev.isolation_experiment(
                    design, library, rng=rng, truth=truth, duration=fault_duration,
                    runs_per_fault=fault_runs, max_h_design=companion, diagnostic=diag,
                    progress=task(f"isolation ({fault_duration:g} s per fault)"),
                )
            except ValueError as exc:
                typer.echo(f"isolation experiment not possible: {exc}", err=True)
                raise typer.Exit(1) from None
            result["confusion"] = {k: c.to_dict() for k, c in iso.confusion.items()}
            result["isolation_settings"] = {
                "duration_s": iso.duration,
                "runs_per_fault": iso.runs_per_fault,
                "max_h": companion_note,
            }
            for name, conf in iso.confusion.items():
                typer.echo("")
                typer.echo(_confusion_table(name, conf))
    if out is not None:
        out.write_text(json.dumps(result, indent=2) + "\n")
        typer.echo(f"\nwrote {out}")
