"""The nominal engine's trims on a dense grid of operating conditions, interpolated.

A snapshot's residuals are taken against the trims of the nominal (healthy) engine at the
snapshot's own condition. The linear-model schedule (``schedule.py``) is far too coarse for
them (off by up to ~0.5 % of some sensors between its nodes, as much as a fault's
signature); a steady-state solve per record is exact but costs a Newton solve each. This
table is solved once, in batch, on a dense grid over the whole envelope (altitude, Mach,
dTamb, power) and interpolated multilinearly, as corrected parameters (seed 004: the same
corrections as the schedule's), at any number of records in a few vectorised operations.

The default grid (9 altitudes, 69 Mach numbers, 5 dTamb, 41 power settings: 127,305 points,
a few seconds to solve) keeps every sensor's trim within 0.1 sigma of its noise over the
envelope, most within 0.05 % of trim (bench/bench_trim_table.py measures it against the exact
solve); Mach and power are the axes that need the density.

A record's trims depend only on its own condition: re-runs of any part of a history give the
same numbers.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from estimation.engine.atmosphere import flight_condition
from estimation.engine.schedule import CORRECTION
from estimation.engine.sensors import SENSOR_NAMES
from estimation.engine.steady import ENVELOPE, steady_state
from estimation.grid import corner_sums

# Condition axes, in the order of a record's condition columns.
TRIM_AXIS_NAMES = ("alt", "mach", "dtamb", "power")
DEFAULT_TRIM_AXES: dict[str, tuple[float, ...]] = {
    "alt": tuple(np.linspace(0.0, 40000.0, 9)),
    "mach": tuple(np.linspace(0.0, 0.85, 69)),
    "dtamb": tuple(np.linspace(-40.0, 40.0, 5)),
    "power": tuple(np.linspace(0.0, 100.0, 41)),
}
# Trimmed signals: the twelve sensors (fuel flow among them) and the two scheduled actuators.
TRIM_NAMES: tuple[str, ...] = (*SENSOR_NAMES, "VSV", "VBV")
SOLVE_ROWS = 4096  # grid points per batched steady-state solve


def correction_factors(names: Sequence[str], conditions: np.ndarray) -> np.ndarray:
    """theta2^a delta2^b [K, n] of each trim (``schedule.CORRECTION``) at conditions [K, 4]
    (alt, mach, dtamb, power)."""
    fc = flight_condition(conditions[:, 0], conditions[:, 1], conditions[:, 2])
    ab = np.array([CORRECTION.get(n, (0.0, 0.0)) for n in names])
    return np.asarray(fc.theta[:, None] ** ab[:, 0] * fc.delta[:, None] ** ab[:, 1])


@dataclass(frozen=True, eq=False)
class TrimTable:
    """``corrected`` [n_alt, n_mach, n_dtamb, n_power, n_trim]: the nominal engine's trims
    over corrected by ``correction_factors``, on ``axes`` (``TRIM_AXIS_NAMES``)."""

    axes: tuple[np.ndarray, ...]
    corrected: np.ndarray
    names: tuple[str, ...] = TRIM_NAMES

    def inside(self, conditions: np.ndarray) -> np.ndarray:
        """[K] bool: the condition is finite and within the table's span."""
        c = np.asarray(conditions, dtype=float)
        lo = np.array([a[0] for a in self.axes])
        hi = np.array([a[-1] for a in self.axes])
        return np.all(np.isfinite(c) & (c >= lo) & (c <= hi), axis=1)

    def trims_at(self, conditions: np.ndarray) -> np.ndarray:
        """Trims [K, n_trim] at conditions [K, 4] (alt, mach, dtamb, power), multilinear in
        the corrected parameters; conditions outside the span are clipped to its edges."""
        c = np.asarray(conditions, dtype=float)
        k = c.shape[0]
        shape = self.corrected.shape[:-1]
        flat = self.corrected.reshape(-1, self.corrected.shape[-1])
        strides = np.array([int(np.prod(shape[i + 1:])) for i in range(len(shape))])
        base = np.zeros(k, dtype=np.intp)
        frac = np.empty((len(shape), k))
        for i, ax in enumerate(self.axes):
            x = np.clip(c[:, i], ax[0], ax[-1])
            j = np.clip(np.searchsorted(ax, x, side="right") - 1, 0, len(ax) - 2)
            frac[i] = (x - ax[j]) / (ax[j + 1] - ax[j])
            base += j * strides[i]
        # Each record's sum over its corners in order, as one sparse product (``corner_sums``:
        # the same sums as corner by corner, in one pass over the table).
        index, weight = [], []
        for corner in itertools.product((0, 1), repeat=len(shape)):
            w = np.ones(k)
            for i, bit in enumerate(corner):
                w *= frac[i] if bit else 1.0 - frac[i]
            index.append(base + int(np.dot(corner, strides)))
            weight.append(w)
        out = corner_sums(np.stack(index), np.stack(weight), flat) if k else np.zeros(
            (0, flat.shape[1]))
        cc = np.column_stack([np.clip(c[:, i], ax[0], ax[-1]) for i, ax in enumerate(self.axes)])
        return out * correction_factors(self.names, cc)


def trim_axes(axes: Mapping[str, Sequence[float]] | None = None) -> tuple[np.ndarray, ...]:
    """The grid's axes (``DEFAULT_TRIM_AXES`` where not given), each sorted, within the
    envelope and at least two points long."""
    full = {**DEFAULT_TRIM_AXES, **(axes or {})}
    out = []
    for name in TRIM_AXIS_NAMES:
        a = np.unique(np.asarray(full[name], dtype=float))
        lo, hi = ENVELOPE[name]
        if len(a) < 2 or a[0] < lo or a[-1] > hi:
            raise ValueError(f"trim axis {name!r} needs two or more points in [{lo:g}, {hi:g}]")
        out.append(a)
    return tuple(out)


def build_trim_table(axes: Mapping[str, Sequence[float]] | None = None) -> TrimTable:
    """Solve the nominal engine at every grid point (batched steady-state solves); raises
    ``EngineConvergenceError`` if any point does not converge."""
    grid = trim_axes(axes)
    nodes = np.array(list(itertools.product(*grid)))
    values = np.empty((len(nodes), len(TRIM_NAMES)))
    for start in range(0, len(nodes), SOLVE_ROWS):
        part = nodes[start: start + SOLVE_ROWS]
        ss = steady_state(part[:, :3], power=part[:, 3])
        values[start: start + len(part)] = np.concatenate([ss.sensors, ss.u[:, 1:]], axis=1)
    corrected = values / correction_factors(TRIM_NAMES, nodes)
    return TrimTable(grid, corrected.reshape(tuple(len(a) for a in grid) + (len(TRIM_NAMES),)))
