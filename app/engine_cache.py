"""Disk cache of the built-in engine's linear-model schedule.

The schedule (``estimation.engine.schedule``) takes a few seconds to build; it
is written once as JSON under the data directory, named by the engine design
fingerprint and the grid, and read back afterwards. A file for another design
or grid is never used; a damaged file is rebuilt. Writes go to a temporary file
and are renamed into place, so a crash never leaves half a cache.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path

from estimation.engine.linearize import DEFAULT_DT
from estimation.engine.schedule import (
    AXIS_NAMES,
    DEFAULT_AXES,
    EngineSchedule,
    build_schedule,
    design_fingerprint,
)
from estimation.errors import ModelFormatError

log = logging.getLogger(__name__)


def _full_axes(axes: Mapping[str, Sequence[float]] | None) -> dict[str, list[float]]:
    ax = {k: list(v) for k, v in DEFAULT_AXES.items()}
    for k, v in (axes or {}).items():
        if k not in AXIS_NAMES:
            raise ValueError(f"unknown schedule axis {k!r}; expected {AXIS_NAMES}")
        ax[k] = sorted(float(x) for x in v)
    return ax


def cache_path(
    cache_dir: Path, axes: Mapping[str, Sequence[float]] | None = None, dt: float = DEFAULT_DT
) -> Path:
    """File that holds the schedule for this design, grid and dt."""
    key = json.dumps({"axes": _full_axes(axes), "dt": dt}, sort_keys=True)
    digest = hashlib.sha256(key.encode()).hexdigest()[:12]
    return Path(cache_dir) / f"engine-schedule-{design_fingerprint()}-{digest}.json"


def load_schedule(path: Path) -> EngineSchedule | None:
    """The cached schedule at ``path``, or None if absent, damaged or for another design."""
    if not path.exists():
        return None
    try:
        with path.open(encoding="utf-8") as f:
            sched = EngineSchedule.from_dict(json.load(f))
    except (OSError, ValueError, KeyError, TypeError, ModelFormatError) as exc:
        log.warning("engine schedule cache %s unreadable (%s); rebuilding", path, exc)
        return None
    if sched.fingerprint != design_fingerprint():
        return None
    return sched


def save_schedule(sched: EngineSchedule, path: Path) -> None:
    """Write atomically: temporary file in the same directory, then rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(sched.to_dict(), f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def engine_schedule(
    cache_dir: Path, axes: Mapping[str, Sequence[float]] | None = None, dt: float = DEFAULT_DT
) -> EngineSchedule:
    """The schedule for ``axes`` (default ``DEFAULT_AXES``): cached, or built and cached."""
    path = cache_path(cache_dir, axes, dt)
    sched = load_schedule(path)
    if sched is None:
        sched = build_schedule(_full_axes(axes), dt=dt)
        save_schedule(sched, path)
    return sched
