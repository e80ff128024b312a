"""A design result read once into typed values, and the snapshot estimator's numerics from it.

``DesignResult.from_document`` reads what the estimators use of a ``fleethealth.design/1``
result (``estimation.design.design_to_dict``): V*, the sensor suite, the noise (Q, Qh, Ph)
and the fault library. ``snapshot_design`` derives the snapshot filter's covariances and the
fault library in tuner space: the snapshot filter settles on the R^-1-weighted least-squares
tuner fit of a constant health shift (docs/math.md section 4 with the filter's steady state
replaced by that fit; equal to V* S when m = p).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimation import isolation
from estimation.model import LinearModel


@dataclass(frozen=True, eq=False)
class DesignResult:
    """What the estimators read of a design result (None: absent from the document).

    vstar [m, p]; sensors: the design's sensor suite; Q, Qh, Ph: process noise, health walk
    and fleet health covariance (``noise``; Ph also at the top level); faults: the fault
    library as listed (``faults.library``, or a list under ``faults``)."""

    vstar: np.ndarray | None
    sensors: tuple[str, ...] | None
    Q: np.ndarray | None
    Qh: np.ndarray | None
    Ph: Any
    faults: list[Any] | None

    @classmethod
    def from_document(cls, result: Mapping[str, Any]) -> DesignResult:
        vstar = result.get("vstar")
        sensors = result.get("sensors")
        noise = result.get("noise")
        noise = noise if isinstance(noise, Mapping) else {}
        Ph = result.get("Ph")
        if Ph is None:
            Ph = noise.get("Ph")
        faults = result.get("faults")
        if isinstance(faults, Mapping):
            faults = faults.get("library")
        return cls(
            None if vstar is None else np.asarray(vstar, float),
            tuple(sensors) if isinstance(sensors, list) and sensors
            and all(isinstance(s, str) for s in sensors) else None,
            np.asarray(noise["Q"], float) if "Q" in noise else None,
            np.asarray(noise["Qh"], float) if "Qh" in noise else None,
            Ph,
            faults if isinstance(faults, list) else None,
        )


@dataclass(frozen=True, eq=False)
class SnapshotDesign:
    """The snapshot filter's numbers of a design.

    Vp: V*^+ [p, m]; Qq, P0: tuner random walk per flight and start covariance [m, m];
    noise_std [ny] (sensor noise with the model error); H [m, n_faults]: tuner change per
    library fault; S_full [p + len(bias_inputs), n_faults]: the faults in health space and in
    the biases of the inputs ``bias_inputs`` (those whose bias is not a health parameter);
    library: the faults kept (those with a tuner-space signature).
    """

    Vp: np.ndarray
    Qq: np.ndarray
    P0: np.ndarray
    noise_std: np.ndarray
    H: np.ndarray
    S_full: np.ndarray
    bias_inputs: tuple[int, ...]
    library: tuple[isolation.Fault, ...]


def _covariance(value: Any, n: int, default_std: float) -> np.ndarray:
    if value is None:
        return np.eye(n) * default_std**2
    arr = np.asarray(value, float)
    return np.diag(arr) if arr.ndim == 1 else arr


def snapshot_design(
    model: LinearModel, vstar: np.ndarray, Ph: Any, faults: Sequence[Any] | None,
    walk_std: float, fleet_std: float, start_std: float, model_error: float,
) -> SnapshotDesign:
    """The snapshot filter's covariances and tuner-space fault library of V* on ``model``.

    Ph: the fleet health covariance (matrix, diagonal or None: ``fleet_std`` per parameter),
    raised to at least ``start_std`` per parameter (engines join the service deteriorated);
    walk_std: the health random walk per flight; model_error: added to the sensor noise.
    """
    p = vstar.shape[1]
    Vp = np.linalg.solve(vstar @ vstar.T, vstar).T  # V*^+ (seed 002 eq. 5)
    walk = np.eye(p) * walk_std**2
    P_h = _covariance(Ph, p, fleet_std)
    P_h = P_h + np.diag(np.maximum(start_std**2 - np.diag(P_h), 0.0))
    Qq = vstar @ walk @ vstar.T
    P0 = vstar @ P_h @ vstar.T

    G_y, _G_z = model.steady_state_gains()
    G_u, _ = model.steady_state_input_gains()
    # An actuator bias is a fault through its input column, unless the design's health
    # vector already carries it (then its health column is the one, counted once).
    health_lower = {n.lower() for n in model.health_names}
    bias_inputs = tuple(
        j for j, s in enumerate(model.inputs) if f"{s.name.lower()}_bias" not in health_lower
    )
    names = list(model.health_names) + [
        f"{model.inputs[j].name.lower()}_bias" for j in bias_inputs
    ]
    G_full = np.concatenate([G_y, G_u[:, list(bias_inputs)]], axis=1)
    library = isolation.faults_from_list(list(faults) if faults is not None else None)
    known = {n.lower() for n in names}
    library = tuple(f for f in library if all(k.lower() in known for k in f.shifts))
    S = isolation.signature_matrix(library, names)
    Hd = G_y @ Vp
    Rinv = 1.0 / (model.sensor_noise_std**2 + model_error**2)
    normal = Hd.T @ (Rinv[:, None] * Hd)
    H = np.linalg.solve(normal, Hd.T @ (Rinv[:, None] * (G_full @ S)))
    usable = np.sum(H**2, axis=0) > 1e-12
    library = tuple(f for f, ok in zip(library, usable, strict=True) if ok)
    return SnapshotDesign(
        Vp=Vp,
        Qq=0.5 * (Qq + Qq.T),
        P0=0.5 * (P0 + P0.T),
        noise_std=np.sqrt(np.asarray(model.sensor_noise_std, float) ** 2 + model_error**2),
        H=H[:, usable],
        S_full=S[:, usable],
        bias_inputs=bias_inputs,
        library=library,
    )
