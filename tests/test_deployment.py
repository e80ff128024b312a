"""docker-compose.yml stays consistent with the code: every service command exists in the CLI."""

from __future__ import annotations

from pathlib import Path

import typer.main
import yaml

from app.cli import app as cli_app

ROOT = Path(__file__).resolve().parent.parent


def _cli_commands() -> dict[str, object]:
    group = typer.main.get_command(cli_app)
    return dict(group.commands)  # type: ignore[attr-defined]


def test_every_compose_service_runs_an_existing_cli_command() -> None:
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    services = compose["services"]
    assert {"postgres", "redis", "migrate", "api", "worker", "beat"} <= set(services)
    commands = _cli_commands()
    ours = {
        name: s
        for name, s in services.items()
        if "command" in s and s["command"][0] == "fleethealth"
    }
    assert set(ours) == {"migrate", "api", "worker", "beat"}
    for name, service in ours.items():
        words = service["command"]
        command = commands.get(words[1])
        assert command is not None, f"service {name}: 'fleethealth {words[1]}' is not a CLI command"
        options = {opt for param in command.params for opt in param.opts + param.secondary_opts}  # type: ignore[attr-defined]
        for word in words[2:]:
            if word.startswith("--"):
                assert word in options, f"service {name}: {word} is not an option of {words[1]}"


def test_dockerfile_default_command_exists() -> None:
    dockerfile = (ROOT / "Dockerfile").read_text()
    cmd_line = next(line for line in dockerfile.splitlines() if line.startswith("CMD"))
    assert '"fleethealth", "serve"' in cmd_line
    assert "serve" in _cli_commands()
