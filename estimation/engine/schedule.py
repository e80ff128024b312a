"""Linear models and trims on a grid of operating conditions, interpolated between.

The grid spans altitude [ft], Mach, power [%] and dTamb [K] (dTamb may be a
single value). At every node the engine is trimmed and linearised
(``linearize.linear_model_at``); between nodes every matrix entry, trim value and
the derived steady-state gains (G_y, G_z of docs/math.md section 1, and those of the
inputs) are interpolated multilinearly, which is what a snapshot filter
scheduled on operating condition needs (docs/math.md section 8). Trims are
interpolated as corrected parameters (seed 004: temperatures over theta2,
pressures and thrust over delta2, speeds over sqrt(theta2), fuel flow over
delta2 sqrt(theta2)) and un-corrected at the query's own inlet conditions, so
pressures follow the atmosphere between altitude nodes instead of a straight
line. Queries outside the grid are clipped to its edges.

``EngineSchedule.to_dict`` / ``from_dict`` give the ``fleethealth.engine-schedule/1``
dict that the application caches on disk; ``design_fingerprint`` changes whenever
the engine design changes, so a cache built for another model is not reused.
"""

from __future__ import annotations

import hashlib
import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from estimation.engine.atmosphere import correction_factors
from estimation.engine.design import engine_design
from estimation.engine.linearize import DEFAULT_DT, linear_model_at
from estimation.engine.steady import SteadyState, steady_state
from estimation.errors import ModelFormatError
from estimation.grid import Grid, model_stacks
from estimation.model import MATRIX_NAMES, LinearModel

SCHEDULE_FORMAT = "fleethealth.engine-schedule/1"
AXIS_NAMES = ("alt", "mach", "power", "dtamb")
DEFAULT_AXES: dict[str, tuple[float, ...]] = {
    "alt": (0.0, 10000.0, 20000.0, 30000.0, 40000.0),
    "mach": (0.0, 0.25, 0.5, 0.7, 0.85),
    "power": (0.0, 25.0, 50.0, 75.0, 100.0),
    "dtamb": (0.0,),
}
# Trim correction: value = corrected * theta2^a * delta2^b (seed 004 corrected parameters).
_SPEED, _TEMP, _PRES, _FUEL = (0.5, 0.0), (1.0, 0.0), (0.0, 1.0), (0.5, 1.0)
CORRECTION: dict[str, tuple[float, float]] = {
    "Nf": _SPEED, "Nc": _SPEED, "TMHPC": _TEMP, "TMHPT": _TEMP, "T24": _TEMP, "T30": _TEMP,
    "T48": _TEMP, "T50": _TEMP, "T40": _TEMP, "P24": _PRES, "Ps30": _PRES, "P30": _PRES,
    "P50": _PRES, "P15": _PRES, "Fn": _PRES, "Wf": _FUEL,
}


def _correction(names: Sequence[str], cond: np.ndarray) -> np.ndarray:
    """Factors theta2^a delta2^b [K, n_trim] at conditions [K, 4]."""
    ab = np.array([CORRECTION.get(n, (0.0, 0.0)) for n in names]).reshape(-1, 2)
    return correction_factors(ab, cond[:, 0], cond[:, 1], cond[:, 3])


def design_fingerprint() -> str:
    """Hex digest identifying the engine design (maps, sizes, constants)."""
    return hashlib.sha256(repr(engine_design()).encode()).hexdigest()[:16]


@dataclass(frozen=True, eq=False)
class EngineSchedule:
    """Stacks over the grid: ``values[name]`` is [n_alt, n_mach, n_power, n_dtamb, ...]
    for each matrix A..N, the gains Gy [ny, np], Gz, Guy [ny, nu], Guz, and
    ``trim_corrected`` [.., n_trim] in the order of ``trim_names`` (see CORRECTION).
    ``template`` carries the signals, noise and dt of every model."""

    axes: tuple[np.ndarray, ...]
    values: Mapping[str, np.ndarray]
    trim_names: tuple[str, ...]
    template: LinearModel
    fingerprint: str

    @property
    def grid(self) -> Grid:
        return Grid(self.axes)

    def interpolate(self, name: str, cond: np.ndarray) -> np.ndarray:
        """``values[name]`` at conditions cond [K, 4] (alt, mach, power, dtamb): [K, ...]."""
        cond = np.atleast_2d(np.asarray(cond, dtype=float))
        if cond.shape[1] != len(AXIS_NAMES):
            raise ValueError(
                f"conditions must be [K, 4] (alt, mach, power, dtamb), got {cond.shape}"
            )
        return self.grid.interpolate(self.values[name], cond)

    def corners(self, cond: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat node indices and weights [C, K] at conditions cond [K, 4] (alt, mach, power,
        dtamb): ``estimation.grid.Grid.corners``."""
        return self.grid.corners(np.atleast_2d(np.asarray(cond, dtype=float)))

    def model_at(
        self, alt: float, mach: float, power: float, dtamb: float = 0.0
    ) -> LinearModel:
        """Interpolated LinearModel at one operating condition."""
        cond = np.array([[alt, mach, power, dtamb]], dtype=float)
        at = self.grid.interpolate_all(self.values, (*MATRIX_NAMES, "trim_corrected"), cond)
        mats = {m: at[m][0] for m in MATRIX_NAMES}
        trim = {k: float(v[0]) for k, v in self._trims(at["trim_corrected"], cond).items()}
        oc = {"alt_ft": float(alt), "mach": float(mach), "dtamb_K": float(dtamb),
              "power_pct": float(power), "interpolated": True}
        return replace(self.template, **mats, trim=trim, operating_condition=oc)

    def trims_at(self, cond: np.ndarray) -> dict[str, np.ndarray]:
        """Trim values at conditions [K, 4] (alt, mach, power, dtamb): name -> [K]."""
        cond = np.atleast_2d(np.asarray(cond, dtype=float))
        return self._trims(self.interpolate("trim_corrected", cond), cond)

    def _trims(self, corrected: np.ndarray, cond: np.ndarray) -> dict[str, np.ndarray]:
        """The corrected trims interpolated at cond [K, n_trim], uncorrected: name -> [K]."""
        t = corrected * _correction(self.trim_names, cond)
        return {n: t[:, i] for i, n in enumerate(self.trim_names)}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready ``fleethealth.engine-schedule/1`` dict."""
        return {
            "format": SCHEDULE_FORMAT,
            "fingerprint": self.fingerprint,
            "axes": {n: a.tolist() for n, a in zip(AXIS_NAMES, self.axes, strict=True)},
            "trim_names": list(self.trim_names),
            "template": self.template.to_dict(),
            "values": {k: v.tolist() for k, v in self.values.items()},
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> EngineSchedule:
        """Rebuild from ``to_dict`` output; ModelFormatError names a missing key."""
        if d.get("format") != SCHEDULE_FORMAT:
            raise ModelFormatError(f"format must be {SCHEDULE_FORMAT!r}, found {d.get('format')!r}")
        for key in ("fingerprint", "axes", "trim_names", "template", "values"):
            if key not in d:
                raise ModelFormatError(f"missing key {key!r}")
        axes = tuple(np.asarray(d["axes"][n], dtype=float) for n in AXIS_NAMES)
        values = {k: np.asarray(v, dtype=float) for k, v in d["values"].items()}
        shape = tuple(len(a) for a in axes)
        for k, v in values.items():
            if v.shape[: len(shape)] != shape:
                raise ModelFormatError(f"values.{k} does not span the grid {shape}")
        return cls(axes, values, tuple(d["trim_names"]), LinearModel.from_dict(d["template"]),
                   str(d["fingerprint"]))


def build_schedule(
    axes: Mapping[str, Sequence[float]] | None = None,
    dt: float = DEFAULT_DT,
    health: np.ndarray | None = None,
) -> EngineSchedule:
    """Trim and linearise at every grid node (axes default to ``DEFAULT_AXES``).

    All nodes are trimmed in one batched steady-state solve; each is then
    linearised (about 10 ms a node).
    """
    ax: dict[str, Sequence[float]] = dict(DEFAULT_AXES)
    ax.update(axes or {})
    grid = tuple(np.asarray(sorted(ax[n]), dtype=float) for n in AXIS_NAMES)
    for n, a in zip(AXIS_NAMES, grid, strict=True):
        if len(a) == 0 or len(np.unique(a)) != len(a):
            raise ValueError(f"axis {n!r} must hold distinct values, got {a.tolist()}")
    nodes = np.array(list(itertools.product(*grid)))
    env = nodes[:, [0, 1, 3]]
    trims = steady_state(env, power=nodes[:, 2], health=health)
    models = []
    for i in range(len(nodes)):
        one = SteadyState(
            trims.x[i], trims.u[i], trims.env[i], trims.health[i], trims.inner[i],
            trims.sensors[i], trims.aux[i], {k: v[i] for k, v in trims.stations.items()},
            trims.power[i],
        )
        models.append(linear_model_at(one, dt))
    shape = tuple(len(a) for a in grid)
    values = model_stacks(models, shape)
    trim_names = tuple(models[0].trim)
    trim = np.array([[mod.trim[n] for n in trim_names] for mod in models])
    values["trim_corrected"] = (trim / _correction(trim_names, nodes)).reshape(
        shape + (len(trim_names),))
    return EngineSchedule(grid, values, trim_names, models[0], design_fingerprint())
