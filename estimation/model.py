"""Linear engine model at one operating point (docs/math.md section 1).

    x[k+1] = A x[k] + B u[k] + L h[k] + w[k]
    y[k]   = C x[k] + D u[k] + M h[k] + v[k]
    z[k]   = F x[k] + G u[k] + N h[k]

Every signal is a deviation from the operating point's trim, in percent of trim
(health parameters in percent deviation). The dict form is the JSON file format
``fleethealth.linear-model/1`` described in ``docs/model-format.md``; this module
converts dicts and objects and reads no files.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from estimation.errors import (
    DimensionError,
    ModelFormatError,
    SingularModelError,
    UnknownSignalError,
)

MODEL_FORMAT = "fleethealth.linear-model/1"

SIGNAL_GROUPS = ("states", "inputs", "health", "sensors", "aux")
MATRIX_NAMES = ("A", "B", "C", "D", "L", "M", "F", "G", "N")
# Matrices a file may leave out; they default to zeros of the right shape.
OPTIONAL_MATRICES = ("D", "F", "G", "M", "N")

# (rows, columns) of each matrix as signal groups.
_MATRIX_SHAPE_GROUPS = {
    "A": ("states", "states"),
    "B": ("states", "inputs"),
    "C": ("sensors", "states"),
    "D": ("sensors", "inputs"),
    "L": ("states", "health"),
    "M": ("sensors", "health"),
    "F": ("aux", "states"),
    "G": ("aux", "inputs"),
    "N": ("aux", "health"),
}

# Singular words for messages.
_GROUP_WORD = {
    "states": "state",
    "inputs": "input",
    "health": "health parameter",
    "sensors": "sensor",
    "aux": "auxiliary output",
}


@dataclass(frozen=True)
class Signal:
    """A named signal with its engineering unit (the unit of its trim value)."""

    name: str
    unit: str

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"signal name must be a non-empty string, got {self.name!r}")
        if not isinstance(self.unit, str):
            raise ValueError(f"unit of signal {self.name!r} must be a string, got {self.unit!r}")


def check_shape(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """Return ``value`` as a float array of ``shape`` or raise DimensionError naming ``name``.

    Empty arrays are reshaped (JSON cannot say ``(0, 3)`` from ``[]``). NaN and
    infinity are refused.
    """
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DimensionError(f"{name} matrix is not numeric: {exc}") from exc
    if arr.size == 0 and math.prod(shape) == 0:
        arr = arr.reshape(shape)
    if arr.shape != shape:
        raise DimensionError(
            f"Incompatible dimensions of {name} matrix; expected {shape} but found {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise DimensionError(f"{name} matrix contains NaN or infinity")
    arr.setflags(write=False)
    return arr


def _signals(group: str, value: Iterable[Any]) -> tuple[Signal, ...]:
    out = []
    for item in value:
        if isinstance(item, Signal):
            out.append(item)
        elif isinstance(item, Mapping):
            out.append(Signal(str(item.get("name", "")), str(item.get("unit", ""))))
        else:
            raise ValueError(f"{group} entries must be Signal or {{name, unit}}, got {item!r}")
    names = [s.name for s in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"duplicate {_GROUP_WORD[group]} names: {dup}")
    return tuple(out)


@dataclass(frozen=True, eq=False)
class LinearModel:
    """Discrete-time linear engine model at one operating point.

    Shapes (nx states, nu inputs, np health parameters, ny sensors, nz aux):
    A [nx, nx], B [nx, nu], C [ny, nx], D [ny, nu], L [nx, np], M [ny, np],
    F [nz, nx], G [nz, nu], N [nz, np]; sensor_noise_std [ny] in percent of
    trim (R = diag(sensor_noise_std**2)). ``trim`` maps state, input, sensor and
    aux names to their trim value in the signal's unit (entries may be missing).
    Arrays are stored read-only; derive new models with the ``select_*`` methods.
    """

    dt: float
    states: tuple[Signal, ...]
    inputs: tuple[Signal, ...]
    health: tuple[Signal, ...]
    sensors: tuple[Signal, ...]
    aux: tuple[Signal, ...]
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    L: np.ndarray
    M: np.ndarray
    F: np.ndarray
    G: np.ndarray
    N: np.ndarray
    trim: Mapping[str, float] = field(default_factory=dict)
    sensor_noise_std: np.ndarray = field(default_factory=lambda: np.zeros(0))
    operating_condition: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        dt = float(self.dt)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {self.dt!r}")
        object.__setattr__(self, "dt", dt)
        for group in SIGNAL_GROUPS:
            object.__setattr__(self, group, _signals(group, getattr(self, group)))
        sizes = {g: len(getattr(self, g)) for g in SIGNAL_GROUPS}
        if sizes["states"] == 0:
            raise ValueError("a model needs at least one state")
        if sizes["health"] == 0:
            raise ValueError("a model needs at least one health parameter")
        if sizes["sensors"] == 0:
            raise ValueError("a model needs at least one sensor")
        for name in MATRIX_NAMES:
            rows, cols = _MATRIX_SHAPE_GROUPS[name]
            arr = check_shape(name, getattr(self, name), (sizes[rows], sizes[cols]))
            object.__setattr__(self, name, arr)
        std = np.array(self.sensor_noise_std, dtype=float)
        if std.shape != (sizes["sensors"],):
            raise DimensionError(
                "Incompatible dimensions of sensor_noise_std; "
                f"expected ({sizes['sensors']},) but found {std.shape}"
            )
        if not np.all(np.isfinite(std)) or np.any(std <= 0):
            raise ValueError("sensor_noise_std must be finite and positive for every sensor")
        std.setflags(write=False)
        object.__setattr__(self, "sensor_noise_std", std)
        known = {s.name for g in ("states", "inputs", "sensors", "aux") for s in getattr(self, g)}
        trim = {}
        for key, value in dict(self.trim).items():
            if key not in known:
                raise UnknownSignalError(
                    f"trim names {key!r}, which is not a state, input, sensor or aux signal"
                )
            v = float(value)
            if not math.isfinite(v):
                raise ValueError(f"trim value of {key!r} is not finite")
            trim[key] = v
        object.__setattr__(self, "trim", trim)
        cond = {}
        for key, value in dict(self.operating_condition).items():
            cond[str(key)] = value
        object.__setattr__(self, "operating_condition", cond)

    # ----------------------------------------------------------------- sizes, names

    @property
    def n_states(self) -> int:
        return len(self.states)

    @property
    def n_inputs(self) -> int:
        return len(self.inputs)

    @property
    def n_health(self) -> int:
        return len(self.health)

    @property
    def n_sensors(self) -> int:
        return len(self.sensors)

    @property
    def n_aux(self) -> int:
        return len(self.aux)

    def names(self, group: str) -> list[str]:
        """Names of one signal group (``states``, ``inputs``, ``health``, ``sensors``, ``aux``)."""
        if group not in SIGNAL_GROUPS:
            raise ValueError(f"unknown signal group {group!r}; expected one of {SIGNAL_GROUPS}")
        return [s.name for s in getattr(self, group)]

    @property
    def state_names(self) -> list[str]:
        return self.names("states")

    @property
    def input_names(self) -> list[str]:
        return self.names("inputs")

    @property
    def health_names(self) -> list[str]:
        return self.names("health")

    @property
    def sensor_names(self) -> list[str]:
        return self.names("sensors")

    @property
    def aux_names(self) -> list[str]:
        return self.names("aux")

    def index(self, group: str, names: str | Sequence[str]) -> int | list[int]:
        """Position(s) of signal name(s) in a group; UnknownSignalError names a missing one."""
        lookup = {n: i for i, n in enumerate(self.names(group))}

        def one(n: str) -> int:
            try:
                return lookup[n]
            except KeyError:
                raise UnknownSignalError(
                    f"{n!r} is not a {_GROUP_WORD[group]} of this model; "
                    f"known: {list(lookup)}"
                ) from None

        if isinstance(names, str):
            return one(names)
        return [one(n) for n in names]

    def state_index(self, names: str | Sequence[str]) -> int | list[int]:
        return self.index("states", names)

    def input_index(self, names: str | Sequence[str]) -> int | list[int]:
        return self.index("inputs", names)

    def health_index(self, names: str | Sequence[str]) -> int | list[int]:
        return self.index("health", names)

    def sensor_index(self, names: str | Sequence[str]) -> int | list[int]:
        return self.index("sensors", names)

    def aux_index(self, names: str | Sequence[str]) -> int | list[int]:
        return self.index("aux", names)

    # ---------------------------------------------------------------- derived

    @property
    def R(self) -> np.ndarray:
        """Sensor noise covariance [ny, ny] = diag(sensor_noise_std**2)."""
        return np.diag(self.sensor_noise_std**2)

    def steady_state_gains(self) -> tuple[np.ndarray, np.ndarray]:
        """Open-loop steady-state gains of h (docs/math.md section 1), u = 0.

        G_y = C (I - A)^-1 L + M   [ny, np]
        G_z = F (I - A)^-1 L + N   [nz, np]
        """
        X = self._solve_i_minus_a(self.L)
        return self.C @ X + self.M, self.F @ X + self.N

    def steady_state_input_gains(self) -> tuple[np.ndarray, np.ndarray]:
        """Open-loop steady-state gains of u: G_u,y = C (I-A)^-1 B + D [ny, nu], and for z."""
        X = self._solve_i_minus_a(self.B)
        return self.C @ X + self.D, self.F @ X + self.G

    def _solve_i_minus_a(self, rhs: np.ndarray) -> np.ndarray:
        I_A = np.eye(self.n_states) - self.A
        # A reciprocal condition number near machine precision means no steady state.
        if np.linalg.cond(I_A) > 1e12:
            raise SingularModelError("I - A is singular: the model has no open-loop steady state")
        return np.linalg.solve(I_A, rhs)

    # ------------------------------------------------------------------- subsets

    def select_sensors(self, names: Sequence[str]) -> LinearModel:
        """Model with only the named sensors, in the given order (rows of C, D, M)."""
        idx = self._unique_index("sensors", names)
        kept = {self.sensors[i].name for i in idx}
        dropped = set(self.sensor_names) - kept
        # A dropped sensor's trim may still be a state's or aux's trim under the same name.
        other = {s.name for g in ("states", "inputs", "aux") for s in getattr(self, g)}
        trim = {k: v for k, v in self.trim.items() if k not in dropped or k in other}
        return replace(
            self,
            sensors=tuple(self.sensors[i] for i in idx),
            C=self.C[idx],
            D=self.D[idx],
            M=self.M[idx],
            sensor_noise_std=self.sensor_noise_std[idx],
            trim=trim,
        )

    def select_health(self, names: Sequence[str]) -> LinearModel:
        """Model with only the named health parameters, in the given order (columns of L, M, N)."""
        idx = self._unique_index("health", names)
        return replace(
            self,
            health=tuple(self.health[i] for i in idx),
            L=self.L[:, idx],
            M=self.M[:, idx],
            N=self.N[:, idx],
        )

    def select_aux(self, names: Sequence[str]) -> LinearModel:
        """Model with only the named auxiliary outputs, in the given order (rows of F, G, N)."""
        idx = self._unique_index("aux", names)
        dropped = set(self.aux_names) - {self.aux[i].name for i in idx}
        other = {s.name for g in ("states", "inputs", "sensors") for s in getattr(self, g)}
        trim = {k: v for k, v in self.trim.items() if k not in dropped or k in other}
        return replace(
            self,
            aux=tuple(self.aux[i] for i in idx),
            F=self.F[idx],
            G=self.G[idx],
            N=self.N[idx],
            trim=trim,
        )

    def _unique_index(self, group: str, names: Sequence[str]) -> list[int]:
        if isinstance(names, str):
            names = [names]
        names = list(names)
        if len(set(names)) != len(names):
            raise ValueError(f"{_GROUP_WORD[group]} names repeat: {names}")
        idx = self.index(group, names)
        assert isinstance(idx, list)
        return idx

    # --------------------------------------------------------------- dict format

    def to_dict(self) -> dict[str, Any]:
        """The ``fleethealth.linear-model/1`` dict (JSON-ready: lists and floats only)."""
        return {
            "format": MODEL_FORMAT,
            "dt": self.dt,
            "signals": {
                g: [{"name": s.name, "unit": s.unit} for s in getattr(self, g)]
                for g in SIGNAL_GROUPS
            },
            "matrices": {m: getattr(self, m).tolist() for m in MATRIX_NAMES},
            "trim": dict(self.trim),
            "sensor_noise_std": self.sensor_noise_std.tolist(),
            "operating_condition": dict(self.operating_condition),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> LinearModel:
        """Build a model from a ``fleethealth.linear-model/1`` dict; extra keys are ignored.

        Raises ModelFormatError naming a missing or malformed key, DimensionError
        naming a matrix of the wrong shape.
        """
        if not isinstance(d, Mapping):
            raise ModelFormatError("a linear model must be a JSON object")
        fmt = d.get("format")
        if fmt != MODEL_FORMAT:
            raise ModelFormatError(f"format must be {MODEL_FORMAT!r}, found {fmt!r}")
        for key in ("dt", "signals", "matrices", "trim", "sensor_noise_std"):
            if key not in d:
                raise ModelFormatError(f"missing key {key!r}")
        signals = d["signals"]
        if not isinstance(signals, Mapping):
            raise ModelFormatError("'signals' must be an object of signal lists")
        groups: dict[str, tuple[Signal, ...]] = {}
        for g in SIGNAL_GROUPS:
            if g not in signals:
                raise ModelFormatError(f"missing key 'signals.{g}'")
            items = signals[g]
            if not isinstance(items, list):
                raise ModelFormatError(f"'signals.{g}' must be a list of {{name, unit}}")
            out = []
            for i, item in enumerate(items):
                if not (isinstance(item, Mapping) and isinstance(item.get("name"), str)):
                    raise ModelFormatError(f"'signals.{g}[{i}]' must have a string 'name'")
                unit = item.get("unit", "")
                if not isinstance(unit, str):
                    raise ModelFormatError(f"'signals.{g}[{i}].unit' must be a string")
                out.append(Signal(item["name"], unit))
            groups[g] = tuple(out)
        matrices = d["matrices"]
        if not isinstance(matrices, Mapping):
            raise ModelFormatError("'matrices' must be an object of nested lists")
        sizes = {g: len(groups[g]) for g in SIGNAL_GROUPS}
        mats: dict[str, Any] = {}
        for m in MATRIX_NAMES:
            if m in matrices:
                mats[m] = matrices[m]
            elif m in OPTIONAL_MATRICES:
                rows, cols = _MATRIX_SHAPE_GROUPS[m]
                mats[m] = np.zeros((sizes[rows], sizes[cols]))
            else:
                raise ModelFormatError(f"missing key 'matrices.{m}'")
        if not isinstance(d["trim"], Mapping):
            raise ModelFormatError("'trim' must be an object of name: value")
        cond = d.get("operating_condition", {}) or {}
        if not isinstance(cond, Mapping):
            raise ModelFormatError("'operating_condition' must be an object")
        try:
            dt = float(d["dt"])
        except (TypeError, ValueError):
            raise ModelFormatError(f"'dt' must be a number, found {d['dt']!r}") from None
        kwargs: dict[str, Any] = {**groups, **mats}
        return cls(
            dt=dt,
            **kwargs,
            trim=d["trim"],
            sensor_noise_std=d["sensor_noise_std"],
            operating_condition=cond,
        )
