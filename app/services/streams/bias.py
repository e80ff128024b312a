"""Transient bias compensation of a design (seed 004, docs/math.md section 7): fit the bias
model on a design's healthy recordings and store it with the design's result under
``transient_bias``; the stream estimator applies it when present (estimator.py, run.py)."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy.orm import Session

from app.errors import Conflict, InvalidInput, NotFound
from app.models import EstimatorDesign, StreamRecording
from app.services import common
from app.services.designs import service as designs
from app.services.streams import samples
from app.services.streams.estimator import BIAS_KEY, StreamEstimationError, estimator_for
from app.services.streams.run import deviations, learning_residuals
from estimation.bias import TI_STAR, BiasFitWarning, BiasModel, fit_bias

JOB_KIND = "fit_transient_bias"
__all__ = ["BIAS_KEY", "JOB_KIND", "MAX_RECORDINGS", "check_request", "design_operator",
           "fit_and_store", "fit_design_bias", "store_bias", "stored_bias", "summary"]
MAX_RECORDINGS = 200

Progress = Callable[[float, str | None], None]


def check_request(session: Session, *, operator_id: int, design_id: int,
                  recording_ids: Sequence[int]) -> tuple[EstimatorDesign, list[StreamRecording]]:
    """The operator's ready design and recordings (NotFound for another operator's or a
    missing design; InvalidInput naming a missing recording)."""
    design = designs.get_design(session, operator_id=operator_id, design_id=design_id)
    if design.status != "ready" or design.result is None:
        raise Conflict(f"design {design_id} is {design.status}: it has no filter to fit")
    if not recording_ids:
        raise InvalidInput("recording_ids: give at least one recording")
    rows = []
    for k, rid in enumerate(recording_ids):
        rows.append(common.referenced(session, StreamRecording, operator_id, rid,
                                      f"recording_ids[{k}]", "recording"))
    return design, rows


def fit_design_bias(
    session: Session, data_dir: Path, *, operator_id: int, design_id: int,
    recording_ids: Sequence[int], ti_star: float = TI_STAR, ti_tau_s: float = 0.5,
    progress: Progress | None = None,
) -> BiasModel:
    """The bias model of a design from recordings of healthy engines (seed 004 Algorithm 1),
    over the design's sensors that every recording carries."""
    design, rows = check_request(session, operator_id=operator_id, design_id=design_id,
                                 recording_ids=recording_ids)
    ti_all: list[np.ndarray] = []
    r_all: list[np.ndarray] = []
    sensors: list[str] | None = None
    R: np.ndarray | None = None
    x_ref: np.ndarray | None = None
    all_names: list[str] = []
    for k, rec in enumerate(rows):
        try:
            est = estimator_for(session, design, rec.signals)
        except StreamEstimationError as e:
            raise InvalidInput(f"recording_ids[{k}]: {e}") from e
        names = list(est.model.sensor_names)
        sensors = names if sensors is None else [n for n in sensors if n in names]
        if x_ref is None:
            x_ref = est.x_ref()
            R = est.model.R
            all_names = names
        if rec.samples_removed_at is not None:
            raise InvalidInput(f"recording_ids[{k}]: the samples of recording {rec.id} were "
                               "removed by the stream sample retention")
        table = samples.read_all(data_dir, rec)
        cond, dy, du = deviations(est, table)
        ti, innov = learning_residuals(est, float(rec.dt_s), cond, dy, du, x_ref, ti_tau_s)
        ti_all.append(ti)
        r_all.append(np.column_stack([innov[:, names.index(n)] if n in names
                                      else np.full(len(ti), np.nan) for n in all_names]))
        if progress is not None:
            progress((k + 1) / len(rows), f"recording {rec.id}: {len(ti)} samples")
    assert sensors is not None and R is not None and x_ref is not None
    if not sensors:
        raise InvalidInput("recording_ids: the recordings share none of the design's sensors")
    cols = [all_names.index(n) for n in sensors]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BiasFitWarning)
        model = fit_bias(np.concatenate(ti_all), np.concatenate(r_all)[:, cols],
                         R[np.ix_(cols, cols)], sensors, ti_star=ti_star,
                         x_ref=[float(v) for v in x_ref], ti_tau_s=ti_tau_s)
    if model.accelerating is None and model.decelerating is None:
        raise InvalidInput(f"recording_ids: no transients in the recordings (|TI| > {ti_star:g}/s "
                           "too rarely); record accelerations and decelerations")
    return model


def store_bias(session: Session, design: EstimatorDesign, model: BiasModel) -> dict[str, Any]:
    """Put the bias model into the design's result document (a new dict: the JSON column sees
    the change); flushed."""
    if design.result is None:
        raise Conflict(f"design {design.id} is {design.status}: nothing to store")
    document = model.to_dict()
    design.result = {**design.result, BIAS_KEY: document}
    session.flush()
    return document


def stored_bias(session: Session, *, operator_id: int, design_id: int) -> dict[str, Any] | None:
    """The design's stored bias model document; None while none is fitted (the design itself
    must exist and be the operator's: NotFound otherwise)."""
    design = designs.get_design(session, operator_id=operator_id, design_id=design_id)
    document = (design.result or {}).get(BIAS_KEY)
    return document if isinstance(document, dict) else None


def design_operator(session: Session, design_id: int) -> int:
    """The operator owning a design (the command line acts for it)."""
    design = session.get(EstimatorDesign, design_id)
    if design is None:
        raise NotFound(f"design {design_id} not found")
    return int(design.operator_id)


def fit_and_store(
    session: Session, data_dir: Path, *, operator_id: int, design_id: int,
    recording_ids: Sequence[int], ti_star: float = TI_STAR, ti_tau_s: float = 0.5,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Fit the design's bias model and store it with the design; the summary."""
    model = fit_design_bias(session, data_dir, operator_id=operator_id, design_id=design_id,
                            recording_ids=recording_ids, ti_star=ti_star, ti_tau_s=ti_tau_s,
                            progress=progress)
    design = designs.get_design(session, operator_id=operator_id, design_id=design_id)
    store_bias(session, design, model)
    return summary(design_id, model)


def summary(design_id: int, model: BiasModel) -> dict[str, Any]:
    return {"design_id": design_id, "sensors": list(model.sensors), "ti_star": model.ti_star,
            "accelerating_samples": model.accelerating.n_samples if model.accelerating else 0,
            "decelerating_samples": model.decelerating.n_samples if model.decelerating else 0}
