"""Stream estimates: the reduced-order filter's decimated trend of one recording."""

from __future__ import annotations

import io
from typing import Annotated

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
from fastapi import APIRouter, Query, Response

from app.schemas.stream_estimates import StreamEstimatesOut
from app.security import CurrentPrincipal, DbSession
from app.services.streams import store as stream_store

router = APIRouter(prefix="/api/v1/streams", tags=["streams"])

# (output key, layout block, names group)
SERIES = (
    ("q_hat", "q", "tuners"),
    ("q_sigma", "q_sigma", "tuners"),
    ("h_hat", "h", "health"),
    ("h_sigma", "h_sigma", "health"),
    ("z_hat", "z", "aux"),
    ("z_sigma", "z_sigma", "aux"),
    ("residual", "residual", "sensors"),
)


def _numbers(values: np.ndarray) -> list[float | None]:
    """Floats for JSON; a window without a value (a sensor missing throughout) is null."""
    if np.all(np.isfinite(values)):
        return values.tolist()  # type: ignore[no-any-return]
    return [float(v) if np.isfinite(v) else None for v in values]


@router.get(
    "/{recording_id}/estimates",
    response_model=StreamEstimatesOut,
    responses={200: {"content": {"text/csv": {}}}},
)
def recording_estimates(
    recording_id: int,
    session: DbSession,
    principal: CurrentPrincipal,
    design_id: int | None = None,
    max_points: Annotated[int, Query(ge=1, le=100_000)] = 2000,
    fmt: Annotated[str, Query(alias="format", pattern="^(json|csv)$")] = "json",
) -> StreamEstimatesOut | Response:
    """q_hat, h_hat, z_hat with 1-sigma and sensor residuals against recording time, as
    window means (one second each, averaged further down to ``max_points``)."""
    series = stream_store.read_estimates(
        session, operator_id=principal.operator_id, recording_id=recording_id,
        design_id=design_id, max_points=max_points,
    )
    layout = series.layout
    sl = layout.slices() if layout is not None else {}
    out: dict[str, dict[str, list[float | None]]] = {}
    for key, block, group in SERIES:
        names = layout.names(group) if layout is not None else ()
        values = series.values[:, sl[block]] if layout is not None else None
        out[key] = {
            name: _numbers(values[:, k]) for k, name in enumerate(names)
        } if values is not None else {}
    if fmt == "csv":
        columns: dict[str, list[float | None]] = {"t_s": _numbers(series.t_s)}
        for key, _block, _group in SERIES:
            for name, column in out[key].items():
                columns[f"{key}.{name}"] = column
        sink = io.BytesIO()
        pacsv.write_csv(pa.table(columns), sink)
        return Response(sink.getvalue(), media_type="text/csv")
    return StreamEstimatesOut(
        recording_id=series.recording.id,
        engine_id=series.recording.engine_id,
        design_id=series.design_id,
        window_s=series.window_s,
        n_samples=series.recording.n_samples,
        n_samples_estimated=series.n_estimated,
        names={g: list(layout.names(g)) for g in ("tuners", "health", "aux", "sensors")}
        if layout is not None else {},
        t_s=series.t_s.tolist(),
        uncertainty=series.uncertainty,
        unobservable=list(series.unobservable),
        tuners_unobservable=list(series.tuners_unobservable),
        **out,
    )
