"""Job kinds: a name, a plain function and the pydantic model of its parameters.

A job function is ``function(session, parameters, progress, *, operator_id) -> dict``:

- ``session`` is its own session; the runner commits it when the function returns (the result
  is recorded in that same transaction) and rolls it back when it raises. A long job may call
  ``session.commit()`` between chunks so finished chunks survive a restart; it must then be
  idempotent per chunk (re-running a chunk changes nothing), which every job must be anyway.
- ``parameters`` is the validated instance of the kind's parameter model.
- ``progress(fraction, message)`` records progress in its own short transaction, throttled;
  it raises ``JobCancelled`` once the job was cancelled, which the function lets propagate.
- ``operator_id`` is the tenant the job belongs to; every query the function makes is scoped
  to it.

Kinds register on a ``JobRegistry``; the service's registry is ``registry`` below, filled by
the modules of ``app.jobs.kinds`` (``app.jobs.kinds.load_kinds()`` imports them all).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol

from pydantic import BaseModel, ValidationError
from sqlalchemy.orm import Session

from app.errors import InvalidInput
from app.models.tenancy import ROLES


class JobCancelled(Exception):
    """The job was cancelled (or another worker took it over) while it ran."""


class Progress(Protocol):
    def __call__(self, fraction: float, message: str | None = None) -> None: ...


class JobFunction(Protocol):
    def __call__(
        self, session: Session, parameters: Any, progress: Progress, *, operator_id: int
    ) -> dict[str, Any]: ...


@dataclass(frozen=True)
class JobKind:
    """A registered kind of job.

    ``role`` is the least role whose API key may submit it through ``POST /api/v1/jobs``;
    ``submittable=False`` keeps a kind internal (submitted by services, e.g. after an upload);
    ``serial=True``: one job of the kind runs at a time per operator (a queued one waits while
    another runs; the runners' claims check it).
    """

    name: str
    function: JobFunction
    parameters: type[BaseModel]
    description: str
    role: str = "analyst"
    submittable: bool = True
    serial: bool = False

    def validate(self, parameters: dict[str, Any] | None) -> BaseModel:
        """The parameters as the kind's model, or ``InvalidInput`` (422) naming each field."""
        try:
            return self.parameters.model_validate(parameters or {})
        except ValidationError as exc:
            details = [
                {
                    "column": ".".join(str(part) for part in err["loc"]) or "parameters",
                    "reason": err["msg"],
                }
                for err in exc.errors()
            ]
            first = details[0]
            raise InvalidInput(
                f"parameters of job kind {self.name!r}: {first['column']}: {first['reason']}",
                details=details,
            ) from None


class JobRegistry:
    """Name -> ``JobKind``. Tests build their own registry with test-only kinds."""

    def __init__(self) -> None:
        self._kinds: dict[str, JobKind] = {}

    def register(self, kind: JobKind) -> JobKind:
        if kind.role not in ROLES:
            raise ValueError(f"job kind {kind.name!r}: role must be one of {ROLES}")
        existing = self._kinds.get(kind.name)
        if existing is not None and existing.function is not kind.function:
            raise ValueError(f"job kind {kind.name!r} is registered already")
        self._kinds[kind.name] = kind
        return kind

    def job(
        self,
        name: str,
        *,
        parameters: type[BaseModel],
        description: str,
        role: str = "analyst",
        submittable: bool = True,
        serial: bool = False,
    ) -> Callable[[JobFunction], JobFunction]:
        """Decorator: register the decorated function as job kind ``name``."""

        def decorate(function: JobFunction) -> JobFunction:
            self.register(
                JobKind(
                    name=name,
                    function=function,
                    parameters=parameters,
                    description=description,
                    role=role,
                    submittable=submittable,
                    serial=serial,
                )
            )
            return function

        return decorate

    def serial_kinds(self) -> tuple[str, ...]:
        """Kinds of which one job at a time runs per operator."""
        return tuple(name for name, kind in self._kinds.items() if kind.serial)

    def get(self, name: str) -> JobKind:
        """The kind called ``name``, or ``InvalidInput`` listing the known kinds."""
        kind = self._kinds.get(name)
        if kind is None:
            known = ", ".join(sorted(self._kinds)) or "none"
            raise InvalidInput(
                f"unknown job kind {name!r}; known kinds: {known}",
                details=[{"column": "kind", "reason": f"unknown job kind {name!r}"}],
            )
        return kind

    def __contains__(self, name: object) -> bool:
        return name in self._kinds

    def __iter__(self) -> Iterator[JobKind]:
        return iter(sorted(self._kinds.values(), key=lambda kind: kind.name))


def parameters_checksum(kind: str, parameters: BaseModel) -> str:
    """SHA-256 of the kind and its normalised parameters (defaults filled, keys sorted).

    Two submissions that mean the same work have the same checksum, however they were spelled.
    """
    canonical = json.dumps(
        {"kind": kind, "parameters": parameters.model_dump(mode="json")},
        sort_keys=True,
        separators=(",", ":"),
    )
    return hashlib.sha256(canonical.encode()).hexdigest()


registry = JobRegistry()

