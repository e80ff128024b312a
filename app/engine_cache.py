"""Disk cache of the built-in engine's linear-model schedule and its nominal trim table, and of
the detectors' tables that every process would otherwise compute again.

The schedule (``estimation.engine.schedule``) takes a few seconds to build; it
is written once as JSON under the data directory, named by the engine design
fingerprint and the grid, and read back afterwards. A file for another design
or grid is never used; a damaged file is rebuilt. The nominal trim table
(``estimation.engine.trim_table``) is kept the same way, as an ``.npz`` file.
The detectors' tables (``arrays``: a CUSUM's threshold, the wear bank's Monte Carlo
calibration) are pure functions of a few numbers; each is kept as an ``.npz`` file named by
those numbers, so the job process and each engine-group worker read it instead of spending
a fraction of a second to seconds on it at their first job. Writes go to a temporary file and
are renamed into place, so a crash never leaves half a cache.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from estimation.engine.linearize import DEFAULT_DT
from estimation.engine.schedule import (
    AXIS_NAMES,
    DEFAULT_AXES,
    EngineSchedule,
    build_schedule,
    design_fingerprint,
)
from estimation.engine.trim_table import TRIM_NAMES, TrimTable, build_trim_table, trim_axes
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


def trim_table_path(cache_dir: Path, axes: Mapping[str, Sequence[float]] | None = None) -> Path:
    """File that holds the nominal trim table for this design and grid."""
    grid = trim_axes(axes)
    key = json.dumps([a.tolist() for a in grid])
    digest = hashlib.sha256(key.encode()).hexdigest()[:12]
    return Path(cache_dir) / f"engine-trims-{design_fingerprint()}-{digest}.npz"


def load_trim_table(
    path: Path, axes: Mapping[str, Sequence[float]] | None = None
) -> TrimTable | None:
    """The cached table at ``path``, or None if absent, damaged or of another grid."""
    if not path.exists():
        return None
    grid = trim_axes(axes)
    try:
        with np.load(path, allow_pickle=False) as f:
            names = tuple(str(n) for n in f["names"])
            corrected = np.array(f["corrected"], dtype=float)
            stored = [np.array(f[f"axis_{k}"], dtype=float) for k in range(len(grid))]
    except (OSError, ValueError, KeyError, EOFError) as exc:
        log.warning("engine trim table cache %s unreadable (%s); rebuilding", path, exc)
        return None
    shape = tuple(len(a) for a in grid) + (len(TRIM_NAMES),)
    if (names != TRIM_NAMES or corrected.shape != shape
            or any(not np.array_equal(a, b) for a, b in zip(stored, grid, strict=True))
            or not np.all(np.isfinite(corrected))):
        log.warning("engine trim table cache %s does not match its grid; rebuilding", path)
        return None
    return TrimTable(grid, corrected)


def save_trim_table(table: TrimTable, path: Path) -> None:
    """Write atomically: temporary file in the same directory, then rename."""
    arrays: dict[str, Any] = {f"axis_{k}": a for k, a in enumerate(table.axes)}
    _save_npz(path, names=np.array(table.names), corrected=table.corrected, **arrays)


def _save_npz(path: Path, **arrays: Any) -> None:
    """``np.savez`` atomically: a temporary file in the same directory, then renamed."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def arrays(
    cache_dir: Path, name: str, key: Mapping[str, Any], build: Callable[[], Mapping[str, Any]]
) -> dict[str, np.ndarray]:
    """The arrays ``build`` returns for ``key`` (JSON numbers and strings), read from the
    cache file of ``name`` and that key, or built and written there (a damaged file is
    rebuilt)."""
    digest = hashlib.sha256(json.dumps(dict(key), sort_keys=True).encode()).hexdigest()[:16]
    path = Path(cache_dir) / f"{name}-{digest}.npz"
    if path.exists():
        try:
            with np.load(path, allow_pickle=False) as f:
                return {k: np.array(f[k]) for k in f.files}
        except (OSError, ValueError, KeyError, EOFError) as exc:
            log.warning("cache %s unreadable (%s); rebuilding", path, exc)
    built = {k: np.asarray(v) for k, v in build().items()}
    _save_npz(path, **built)
    return built


def engine_trim_table(
    cache_dir: Path, axes: Mapping[str, Sequence[float]] | None = None
) -> TrimTable:
    """The nominal engine's trim table on ``axes`` (default ``DEFAULT_TRIM_AXES``): cached,
    or solved (a few seconds) and cached."""
    path = trim_table_path(cache_dir, axes)
    table = load_trim_table(path, axes)
    if table is None:
        table = build_trim_table(axes)
        save_trim_table(table, path)
    return table
