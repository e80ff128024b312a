"""Design spec dict -> design result dict (``docs/design-format.md``).

``run_design`` parses and validates a ``fleethealth.design-spec/1`` dict, runs
the tuner selection method on the linear model, and returns the
``fleethealth.design/1`` dict. ``design_from_result`` rebuilds the
``TunerDesign`` from a result dict. No file I/O: the caller resolves the
spec's model path and passes the model in.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from estimation import isolation, theory, tuners
from estimation.errors import DesignSpecError, UnknownSignalError
from estimation.model import MODEL_FORMAT, LinearModel
from estimation.reduced import covariance

SPEC_FORMAT = "fleethealth.design-spec/1"
DESIGN_FORMAT = "fleethealth.design/1"
DEFAULT_LAMBDA = 1.0


def _names(spec: Mapping[str, Any], key: str, known: Sequence[str]) -> list[str]:
    value = spec.get(key)
    if value is None:
        return list(known)
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value) or not value:
        raise DesignSpecError(f"'{key}' must be a non-empty list of names")
    unknown = [v for v in value if v not in known]
    if unknown:
        raise DesignSpecError(f"'{key}' names unknown signals {unknown}; known: {list(known)}")
    if len(set(value)) != len(value):
        raise DesignSpecError(f"'{key}' repeats a name")
    return list(value)


def _weights(value: Any, names: Sequence[str], key: str) -> np.ndarray:
    """Objective weights from true/false, a list of names (weight 1) or {name: weight}."""
    w = np.zeros(len(names))
    if value is None or value is False:
        return w
    if value is True:
        return np.ones(len(names))
    if isinstance(value, list):
        value = {n: 1.0 for n in value}
    if not isinstance(value, Mapping):
        raise DesignSpecError(
            f"'objective.{key}' must be true, a list of names or {{name: weight}}"
        )
    index = {n: i for i, n in enumerate(names)}
    for name, weight in value.items():
        if name not in index:
            raise DesignSpecError(
                f"'objective.{key}' names {name!r}, not one of the design's {list(names)}"
            )
        try:
            w[index[name]] = float(weight)
        except (TypeError, ValueError):
            raise DesignSpecError(f"'objective.{key}.{name}' must be a number") from None
    if np.any(w < 0) or not np.all(np.isfinite(w)):
        raise DesignSpecError(f"'objective.{key}' weights must be finite and non-negative")
    return w


def _cov(noise: Mapping[str, Any], key: str, n: int, default_zero: bool = False) -> np.ndarray:
    if key not in noise:
        if default_zero:
            return np.zeros((n, n))
        raise DesignSpecError(f"missing key 'noise.{key}'")
    try:
        return covariance(noise[key], n, key)
    except ValueError as exc:
        raise DesignSpecError(f"'noise.{key}': {exc}") from exc


# How stream recordings are filtered under a design (docs/design-format.md): the reduced-order
# linear filter scheduled over the envelope (default), or seed 001's constant-gain EKF on the
# built-in nonlinear engine (``estimation.cgekf``).
STREAM_FILTERS = ("scheduled_linear", "cgekf")


def parse_spec(spec: Mapping[str, Any], model: LinearModel) -> dict[str, Any]:
    """Validate a design spec against its model; return the normalised settings.

    Keys of the result: design_model (sensors and health selected), source_model
    (sensors selected, every health parameter), method, m, Q, Qh, Ph,
    health_weights, aux_weights, vstar (or None), faults (or None = default
    library), lam, svd_aux, svd_row_weights, max_iter, variance, stream_filter.
    """
    if not isinstance(spec, Mapping):
        raise DesignSpecError("a design spec must be a JSON object")
    if spec.get("format") != SPEC_FORMAT:
        raise DesignSpecError(f"format must be {SPEC_FORMAT!r}, found {spec.get('format')!r}")
    sensors = _names(spec, "sensors", model.sensor_names)
    health = _names(spec, "health", model.health_names)
    source = model.select_sensors(sensors)
    design_model = source.select_health(health)
    method = spec.get("method", "optimal")
    vstar = spec.get("vstar")
    if method not in tuners.METHODS:
        raise DesignSpecError(f"'method' must be one of {list(tuners.METHODS)}, found {method!r}")
    p = design_model.n_health
    if vstar is not None:
        try:
            V = np.array(vstar, dtype=float)
        except (TypeError, ValueError):
            raise DesignSpecError("'vstar' must be a matrix (list of rows) of numbers") from None
        if V.ndim != 2 or V.shape[1] != p or not np.all(np.isfinite(V)):
            raise DesignSpecError(
                f"Incompatible dimensions of vstar matrix; expected (m, {p}) but found {V.shape}"
            )
        vstar = V
    m = spec.get("tuners", None if vstar is None else int(vstar.shape[0]))
    if isinstance(m, bool) or not isinstance(m, int):
        raise DesignSpecError("'tuners' must be an integer number of tuners")
    if vstar is not None and vstar.shape[0] != m:
        raise DesignSpecError(f"'vstar' has {vstar.shape[0]} rows but 'tuners' is {m}")
    if not 1 <= m <= p:
        raise DesignSpecError(f"'tuners' must be between 1 and {p} (health parameters), got {m}")
    noise = spec.get("noise")
    if not isinstance(noise, Mapping):
        raise DesignSpecError("missing key 'noise' (an object with Q, Qh, Ph)")
    Q = _cov(noise, "Q", design_model.n_states, default_zero=True)
    Qh = _cov(noise, "Qh", p)
    Ph = _cov(noise, "Ph", p)
    objective = spec.get("objective", {"health": True})
    if isinstance(objective, str):
        objective = {objective: True}
    if not isinstance(objective, Mapping):
        raise DesignSpecError("'objective' must be an object {health: ..., aux: ...}")
    wh = _weights(objective.get("health", False), design_model.health_names, "health")
    wz = _weights(objective.get("aux", False), design_model.aux_names, "aux")
    if not (wh.any() or wz.any()):
        raise DesignSpecError("'objective' weights nothing: give health and/or aux weights")
    faults = None
    if spec.get("faults") is not None:
        try:
            faults = isolation.faults_from_list(spec["faults"])
        except (ValueError, KeyError, TypeError) as exc:
            raise DesignSpecError(f"'faults': {exc}") from exc
    lam = spec.get("lambda", DEFAULT_LAMBDA)
    if isinstance(lam, bool) or not isinstance(lam, int | float) or not lam >= 0:
        raise DesignSpecError("'lambda' must be a non-negative number")
    svd = spec.get("svd", {}) or {}
    if not isinstance(svd, Mapping):
        raise DesignSpecError("'svd' must be an object {aux, row_weights}")
    svd_aux = svd.get("aux")
    if svd_aux is not None:
        svd_aux = _names({"aux": svd_aux}, "aux", design_model.aux_names)
    max_iter = spec.get("max_iter", 200)
    if isinstance(max_iter, bool) or not isinstance(max_iter, int) or max_iter < 1:
        raise DesignSpecError("'max_iter' must be a positive integer")
    variance = spec.get("variance", theory.WITH_PROCESS_NOISE)
    if variance not in theory.VARIANCE_MODES:
        raise DesignSpecError(
            f"'variance' must be one of {list(theory.VARIANCE_MODES)}, found {variance!r}"
        )
    stream_filter = spec.get("stream_filter", STREAM_FILTERS[0])
    if stream_filter not in STREAM_FILTERS:
        raise DesignSpecError(
            f"'stream_filter' must be one of {list(STREAM_FILTERS)}, found {stream_filter!r}"
        )
    return {
        "design_model": design_model,
        "source_model": source,
        "method": method,
        "m": m,
        "Q": Q,
        "Qh": Qh,
        "Ph": Ph,
        "health_weights": wh,
        "aux_weights": wz,
        "vstar": vstar,
        "faults": faults,
        "lam": float(lam),
        "svd_aux": svd_aux,
        "svd_row_weights": svd.get("row_weights"),
        "max_iter": max_iter,
        "variance": variance,
        "stream_filter": stream_filter,
    }


def _design(s: dict[str, Any]) -> tuners.TunerDesign:
    model, m, Q, Qh, Ph = s["design_model"], s["m"], s["Q"], s["Qh"], s["Ph"]
    wh, wz, var = s["health_weights"], s["aux_weights"], s["variance"]
    if s["vstar"] is not None:
        return tuners.design_filter(
            model, s["vstar"], Q, Qh, Ph, "explicit", wh, wz, variance=var
        )
    method = s["method"]
    if method == "subset":
        return tuners.subset_tuners(model, m, Q, Qh, Ph, wh, wz, variance=var)
    if method == "svd":
        return tuners.svd_tuners(
            model, m, Q, Qh, Ph, s["svd_aux"], s["svd_row_weights"], wh, wz, variance=var
        )
    if method == "optimal":
        return tuners.optimal_tuners(
            model, m, Q, Qh, Ph, wh, wz, max_iter=s["max_iter"], variance=var
        )
    return tuners.diagnostic_tuners(
        model, m, Q, Qh, Ph, s["lam"], s["faults"], wh, wz, max_iter=s["max_iter"],
        variance=var,
    )


def _fault_section(
    design: tuners.TunerDesign, faults: Sequence[isolation.Fault] | None
) -> dict[str, Any] | None:
    """Fault influence in tuner space and pairwise PMC, if the library fits the model."""
    try:
        fp = tuners.fault_problem(design.model, faults)
        pmc = tuners.diagnostic_objective_terms(design, faults)
    except (isolation.IsolationError, UnknownSignalError):
        if faults is not None:
            raise
        return None  # the default library names health parameters this model lacks
    nx = design.model.n_states
    H = (design.Gamma @ design.gain @ fp.Gy_full)[nx:, :] @ fp.S
    lib = isolation.default_faults() if faults is None else tuple(faults)
    return {
        "names": list(fp.faults),
        "library": [f.to_dict() for f in lib],
        "H": H.tolist(),
        "pmc": pmc.tolist(),
        "pmc_sum": float(pmc.sum()),
    }


def design_to_dict(
    design: tuners.TunerDesign,
    source_model: LinearModel | None = None,
    faults: Sequence[isolation.Fault] | None = None,
    lam: float | None = None,
) -> dict[str, Any]:
    """The ``fleethealth.design/1`` dict of a design (JSON-ready)."""
    model = design.model
    out: dict[str, Any] = {
        "format": DESIGN_FORMAT,
        "method": design.method,
        "tuners": design.tuner_names,
        "state_names": model.state_names + design.tuner_names,
        "sensors": model.sensor_names,
        "health": model.health_names,
        "aux": model.aux_names,
        "vstar": design.vstar.tolist(),
        "vstar_pinv": design.reduced.vstar_pinv.tolist(),
        "gain": design.gain.tolist(),
        "P_prior": design.P_prior.tolist(),
        "P_hat": design.P_hat.tolist(),
        "Pq": design.P_q.tolist(),
        "Gamma": design.Gamma.tolist(),
        "noise": {"Q": design.Q.tolist(), "Qh": design.Qh.tolist(), "Ph": design.Ph.tolist()},
        "objective": design.objective,
        "variance": design.variance,
        "theory": design.theory.to_dict(),
        "model": model.to_dict(),
    }
    if lam is not None:
        out["lambda"] = lam
    if source_model is not None:
        out["source_model"] = source_model.to_dict()
    section = _fault_section(design, faults)
    if section is not None:
        out["faults"] = section
    return out


def run_design(
    spec: Mapping[str, Any],
    model: LinearModel | Mapping[str, Any],
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Design spec dict -> design result dict (``fleethealth.design/1``).

    model: the LinearModel (or its dict) named by the spec's ``model`` key,
    already loaded by the caller. Raises DesignSpecError for a bad spec and
    UnobservableDesignError when the sensors cannot estimate the tuners.
    """
    if isinstance(model, Mapping):
        model = LinearModel.from_dict(model)
    settings = parse_spec(spec, model)
    if progress is not None:
        progress(f"designing {settings['method']} tuners (m = {settings['m']})")
    design = _design(settings)
    result = design_to_dict(
        design,
        settings["source_model"],
        settings["faults"],
        settings["lam"] if design.method == "diagnostic" else None,
    )
    result["stream_filter"] = settings["stream_filter"]
    return result


def design_from_result(result: Mapping[str, Any]) -> tuners.TunerDesign:
    """Rebuild the TunerDesign of a ``fleethealth.design/1`` dict from its model, V* and noise.

    The gain is recomputed (deterministic) and must match the stored one.
    """
    if result.get("format") != DESIGN_FORMAT:
        raise DesignSpecError(f"format must be {DESIGN_FORMAT!r}, found {result.get('format')!r}")
    for key in ("model", "vstar", "noise", "gain"):
        if key not in result:
            raise DesignSpecError(f"missing key {key!r}")
    model_dict = result["model"]
    if not isinstance(model_dict, Mapping) or model_dict.get("format") != MODEL_FORMAT:
        raise DesignSpecError("'model' must be an embedded fleethealth.linear-model/1 object")
    model = LinearModel.from_dict(model_dict)
    noise = result["noise"]
    design = tuners.design_filter(
        model,
        np.asarray(result["vstar"], float),
        np.asarray(noise["Q"], float),
        np.asarray(noise["Qh"], float),
        np.asarray(noise["Ph"], float),
        method=str(result.get("method", "explicit")),
        objective=float(result.get("objective", np.nan)),
        # Results written before the key existed used the seeds' sensor-noise-only formula.
        variance=str(result.get("variance", theory.SENSOR_NOISE_ONLY)),
    )
    stored = np.asarray(result["gain"], float)
    if stored.shape != design.gain.shape or not np.allclose(
        stored, design.gain, rtol=1e-6, atol=1e-9 * max(1.0, np.abs(stored).max())
    ):
        raise DesignSpecError("the stored gain does not match the model, V* and noise")
    return design
