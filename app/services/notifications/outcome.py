"""What one attempt at sending gave: the delivery log's row before it is stored."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass


@dataclass(frozen=True)
class Outcome:
    ok: bool
    status_code: int | None
    error: str | None
    duration_ms: float


@dataclass
class Clock:
    ms: float = 0.0


@contextmanager
def timed() -> Iterator[Clock]:
    """A clock whose ``ms`` is the block's duration once it ends (also when it raises)."""
    clock = Clock()
    start = time.perf_counter()
    try:
        yield clock
    finally:
        clock.ms = (time.perf_counter() - start) * 1000.0
