"""An engine type's linear models at several operating points, interpolated between them
(the ``fleethealth.model-schedule/1`` file of docs/model-format.md).

Each model is a ``fleethealth.linear-model/1`` model of the same signals, at the operating point
its ``operating_condition`` gives on the schedule's scheduling variables (some of the
operating-condition columns alt_ft, mach, dtamb_k, power_pct). The points fill a rectilinear
grid (every combination of each variable's values, once). Between nodes every matrix entry, the
steady-state gains, the sensor noise and the trims are interpolated multilinearly
(``estimation.grid``), as the built-in engine's schedule is (``estimation.engine.schedule``):
trims as corrected parameters (seed 004: a temperature over theta2, a pressure or thrust over
delta2, a speed over sqrt(theta2), a fuel flow over delta2 sqrt(theta2)), un-corrected at the
query's own inlet conditions. Which correction a signal takes is read from its unit unless the
file names it (``corrections``). Queries outside the grid are clipped to its edges.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from estimation.engine.atmosphere import correction_factors
from estimation.errors import ModelFormatError
from estimation.grid import Grid, model_stacks
from estimation.model import MATRIX_NAMES, SIGNAL_GROUPS, LinearModel

SCHEDULE_FORMAT = "fleethealth.model-schedule/1"
# The operating-condition columns, in the order a conditions array [K, 4] carries them (the
# order snapshots store them in).
CONDITIONS = ("alt_ft", "mach", "dtamb_k", "power_pct")
# Correction kind -> exponents (a, b) of theta2^a delta2^b.
CORRECTIONS: dict[str, tuple[float, float]] = {
    "none": (0.0, 0.0), "temperature": (1.0, 0.0), "pressure": (0.0, 1.0),
    "thrust": (0.0, 1.0), "speed": (0.5, 0.0), "fuel_flow": (0.5, 1.0),
}
# The correction a signal's unit implies when the file names none.
UNIT_CORRECTION = {
    **dict.fromkeys(("K", "degR", "R", "degC", "C", "degF", "F"), "temperature"),
    **dict.fromkeys(("Pa", "hPa", "mbar", "kPa", "MPa", "bar", "psia", "psi", "inHg"),
                    "pressure"),
    **dict.fromkeys(("rpm", "rps", "rad/s"), "speed"),
    **dict.fromkeys(("kg/s", "kg/h", "pps", "lbm/s", "lb/s", "pph", "lbm/h"), "fuel_flow"),
    **dict.fromkeys(("N", "kN", "lbf"), "thrust"),
}
# Absolute zero below a temperature unit's zero: a corrected temperature is an absolute one.
ZERO_OFFSET = {"degC": 273.15, "C": 273.15, "degF": 459.67, "F": 459.67}
_FLIGHT = ("alt_ft", "mach", "dtamb_k")  # what theta2 and delta2 are computed from


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ModelFormatError(f"{where} must be a finite number, found {value!r}")
    return float(value)


@dataclass(frozen=True, eq=False)
class ModelSchedule:
    """Linear models at the nodes of a grid over ``variables`` (C-order over ``grid``).

    ``values`` stacks every node quantity over the grid [*grid.shape, ...]: the matrices A..N,
    the gains Gy, Gz, Guy, Guz, ``noise`` (sensor noise, percent of trim) and
    ``trim_corrected`` (in the order of ``trim_names``). ``corrections`` gives each trimmed
    signal's correction kind (``CORRECTIONS``). Designs are made on ``template``, the model
    at ``design_point``."""

    variables: tuple[str, ...]
    grid: Grid
    models: tuple[LinearModel, ...]
    corrections: Mapping[str, str]
    design_point: int
    values: Mapping[str, np.ndarray]
    trim_names: tuple[str, ...]

    @property
    def template(self) -> LinearModel:
        return self.models[self.design_point]

    @property
    def corrected(self) -> bool:
        return any(self.corrections[n] != "none" for n in self.trim_names)

    @property
    def required_conditions(self) -> tuple[str, ...]:
        """Operating-condition columns a record needs: the scheduling variables, and what
        theta2 and delta2 are computed from when a trim is corrected."""
        need = set(self.variables) | (set(_FLIGHT) if self.corrected else set())
        return tuple(c for c in CONDITIONS if c in need)

    def _axes(self, conditions: np.ndarray) -> np.ndarray:
        conditions = np.atleast_2d(np.asarray(conditions, dtype=float))
        if conditions.shape[1] != len(CONDITIONS):
            raise ValueError(f"conditions must be [K, 4] {CONDITIONS}, got {conditions.shape}")
        return conditions[:, [CONDITIONS.index(v) for v in self.variables]]

    def interpolate(self, name: str, conditions: np.ndarray) -> np.ndarray:
        """``values[name]`` at conditions [K, 4] (``CONDITIONS`` order): [K, ...]."""
        return self.grid.interpolate(self.values[name], self._axes(conditions))

    def corners(self, conditions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat node indices and weights [C, K] at conditions [K, 4] (``Grid.corners``)."""
        return self.grid.corners(self._axes(conditions))

    @property
    def offsets(self) -> np.ndarray:
        """Added to each trim before it is corrected [n_trim]: absolute zero below the zero
        of a corrected temperature's unit (degC, degF), else 0."""
        units = {s.name: s.unit for g in SIGNAL_GROUPS for s in getattr(self.template, g)}
        return np.array([ZERO_OFFSET.get(units[n], 0.0) if self.corrections[n] == "temperature"
                         else 0.0 for n in self.trim_names])

    def factors(self, conditions: np.ndarray) -> np.ndarray:
        """theta2^a delta2^b [K, n_trim] of the trims at conditions [K, 4]."""
        conditions = np.atleast_2d(np.asarray(conditions, dtype=float))
        if not self.corrected:
            return np.ones((conditions.shape[0], len(self.trim_names)))
        ab = np.array([CORRECTIONS[self.corrections[n]] for n in self.trim_names])
        flight = [conditions[:, CONDITIONS.index(c)] for c in _FLIGHT]
        return correction_factors(ab, *flight)

    def trims_at(self, conditions: np.ndarray) -> dict[str, np.ndarray]:
        """Trim values at conditions [K, 4] in the models' units: name -> [K]."""
        return self._trims(self.interpolate("trim_corrected", conditions), conditions)

    def _trims(self, corrected: np.ndarray, conditions: np.ndarray) -> dict[str, np.ndarray]:
        """The corrected trims interpolated at conditions [K, n_trim], in the models' units:
        name -> [K]."""
        t = corrected * self.factors(conditions) - self.offsets
        return {n: t[:, i] for i, n in enumerate(self.trim_names)}

    def model_at(self, condition: Sequence[float]) -> LinearModel:
        """The interpolated LinearModel at one condition (alt_ft, mach, dtamb_k, power_pct)."""
        cond = np.asarray(condition, dtype=float).reshape(1, len(CONDITIONS))
        at = self.grid.interpolate_all(self.values, (*MATRIX_NAMES, "trim_corrected", "noise"),
                                       self._axes(cond))
        mats = {m: at[m][0] for m in MATRIX_NAMES}
        trim = {k: float(v[0]) for k, v in self._trims(at["trim_corrected"], cond).items()}
        oc = {**{c: float(cond[0, CONDITIONS.index(c)]) for c in self.variables},
              "interpolated": True}
        return replace(self.template, **mats, trim=trim, operating_condition=oc,
                       sensor_noise_std=at["noise"][0])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready ``fleethealth.model-schedule/1`` dict (the models in grid order)."""
        return {
            "format": SCHEDULE_FORMAT,
            "variables": list(self.variables),
            "corrections": dict(self.corrections),
            "design_point": self.design_point,
            "models": [m.to_dict() for m in self.models],
        }

    @classmethod
    def from_dict(cls, d: Any) -> ModelSchedule:
        """Read a ``fleethealth.model-schedule/1`` dict; ModelFormatError (or the linear
        model's own errors, prefixed ``models[i]:``) names the key, model or point at fault."""
        if not isinstance(d, Mapping):
            raise ModelFormatError("a model schedule must be a JSON object")
        if d.get("format") != SCHEDULE_FORMAT:
            raise ModelFormatError(f"format must be {SCHEDULE_FORMAT!r}, found {d.get('format')!r}")
        variables = d.get("variables")
        if (not isinstance(variables, list) or not variables
                or any(v not in CONDITIONS for v in variables)
                or len(set(variables)) != len(variables)):
            raise ModelFormatError(
                f"variables must be a non-empty list of distinct names from {list(CONDITIONS)}, "
                f"found {variables!r}")
        docs = d.get("models")
        if not isinstance(docs, list) or not docs:
            raise ModelFormatError("models must be a non-empty list of linear-model files")
        models: list[LinearModel] = []
        for i, doc in enumerate(docs):
            try:
                models.append(LinearModel.from_dict(doc))
            except (ValueError, KeyError, TypeError) as exc:
                raise type(exc)(f"models[{i}]: {exc}") from None
        return schedule_of(models, tuple(variables), d.get("corrections") or {},
                           d.get("design_point", 0))


def _signature(model: LinearModel) -> tuple[Any, ...]:
    return (model.dt, *(tuple((s.name, s.unit) for s in getattr(model, g))
                        for g in SIGNAL_GROUPS))


def schedule_of(
    models: Sequence[LinearModel], variables: Sequence[str],
    corrections: Mapping[str, Any] | None = None, design_point: Any = 0,
) -> ModelSchedule:
    """A schedule of ``models`` (any order) over ``variables``; ModelFormatError when the
    models' signals differ, a point is missing or given twice, or a correction is unknown."""
    variables = tuple(variables)
    if not models:
        raise ModelFormatError("models must be a non-empty list of linear-model files")
    first = models[0]
    for i, model in enumerate(models[1:], start=1):
        if _signature(model) != _signature(first):
            raise ModelFormatError(
                f"models[{i}] does not have the signals (names, units, order) and dt of "
                "models[0]; every model of a schedule must")
        if set(model.trim) != set(first.trim):
            raise ModelFormatError(f"models[{i}] trims {sorted(model.trim)}, models[0] "
                                   f"{sorted(first.trim)}; every model must trim the same signals")
    points = []
    for i, model in enumerate(models):
        oc = model.operating_condition
        missing = [v for v in variables if v not in oc]
        if missing:
            raise ModelFormatError(
                f"models[{i}]: operating_condition gives no {missing} (the scheduling variables "
                f"are {list(variables)})")
        points.append(tuple(_number(oc[v], f"models[{i}].operating_condition.{v}")
                            for v in variables))
    axes = tuple(np.array(sorted({p[k] for p in points})) for k in range(len(variables)))
    grid = Grid(axes)
    where: dict[tuple[float, ...], int] = {}
    for i, point in enumerate(points):
        if point in where:
            at = dict(zip(variables, point, strict=True))
            raise ModelFormatError(f"models[{where[point]}] and models[{i}] are both at {at}")
        where[point] = i
    nodes = list(itertools.product(*(a.tolist() for a in axes)))
    holes = [n for n in nodes if n not in where]
    if holes:
        shown = ", ".join(str(dict(zip(variables, h, strict=True))) for h in holes[:3])
        raise ModelFormatError(
            f"the operating points do not fill the grid {' x '.join(map(str, grid.shape))} over "
            f"{list(variables)}: no model at {shown}" + (
                f" and {len(holes) - 3} more" if len(holes) > 3 else ""))
    ordered = [models[where[n]] for n in nodes]
    if isinstance(design_point, bool) or not isinstance(design_point, int) or not (
            0 <= design_point < len(models)):
        raise ModelFormatError(
            f"design_point must be the index of a model (0..{len(models) - 1}), "
            f"found {design_point!r}")
    design = nodes.index(points[design_point])
    trim_names = tuple(first.trim)
    units = {s.name: s.unit for g in SIGNAL_GROUPS for s in getattr(first, g)}
    if not isinstance(corrections, Mapping):
        raise ModelFormatError("corrections must be an object: signal name -> correction")
    kinds: dict[str, str] = {}
    for name, kind in corrections.items():
        if name not in trim_names:
            raise ModelFormatError(f"corrections names {name!r}, which no model trims")
        if kind not in CORRECTIONS:
            raise ModelFormatError(
                f"corrections.{name} must be one of {list(CORRECTIONS)}, found {kind!r}")
        kinds[name] = str(kind)
    for name in trim_names:
        kinds.setdefault(name, UNIT_CORRECTION.get(units[name], "none"))
    shape = grid.shape
    values = model_stacks(ordered, shape)
    values["noise"] = np.stack([m.sensor_noise_std for m in ordered]).reshape(
        shape + first.sensor_noise_std.shape)
    trims = np.array([[m.trim[n] for n in trim_names] for m in ordered]).reshape(
        -1, len(trim_names))
    sched = ModelSchedule(variables, grid, tuple(ordered), kinds, design, values, trim_names)
    node_conditions = np.zeros((len(ordered), len(CONDITIONS)))
    if sched.corrected:
        for i, model in enumerate(models):
            for c in _FLIGHT:
                raw = model.operating_condition.get(c, 0.0 if c == "dtamb_k" else None)
                if raw is None:
                    raise ModelFormatError(
                        f"models[{i}]: operating_condition gives no {c!r}, which the corrected "
                        "trims need (name the signals' corrections \"none\" to interpolate them "
                        "as they are)")
                value = _number(raw, f"models[{i}].operating_condition.{c}")
                node_conditions[nodes.index(points[i]), CONDITIONS.index(c)] = value
    corrected = (trims + sched.offsets) / sched.factors(node_conditions)
    values["trim_corrected"] = corrected.reshape(shape + (len(trim_names),))
    return sched
