"""Stream estimates: what the reduced-order steady-state filter derives from a recording.

A recording at tens of Hz gives hundreds of thousands of samples a flight. Trends need far
fewer, so the filter's output is stored decimated: one row per window of ``window`` samples
(one second of the recording, aligned on the recording's first sample) holding the window's
means, packed like snapshot estimates (``app.models.estimates.EstimateLayout``: q_hat, its
1-sigma, h_hat, 1-sigma, z_hat, 1-sigma, sensor residuals; no fault block). The filter itself
runs at full rate; its full-rate state is kept in ``stream_filter_states`` at the last window
boundary (where the next chunk restarts, so a window split by a chunk boundary is recomputed
whole) and at the end of the last chunk.

Rows are derived data: a re-run deletes rows from the first affected window and inserts them
again, and ``(recording_id, design_id, window)`` is unique, so nothing is ever duplicated.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import Double, ForeignKey, Index, Integer, LargeBinary, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column

from app.models.base import Base, UTCDateTime, utcnow
from app.models.designs import JSONDocument
from app.models.ingest import BigId


class StreamEstimate(Base):
    """The filter's output over one window of a recording under one design (window means).

    ``window`` numbers the recording's windows from 0; ``t_s`` is the recording time of the
    window's first sample and ``n`` its number of samples (the last window may be short).
    """

    __tablename__ = "stream_estimates"
    __table_args__ = (UniqueConstraint("recording_id", "design_id", "window"),)

    id: Mapped[int] = mapped_column(BigId, primary_key=True)
    operator_id: Mapped[int] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    engine_id: Mapped[int] = mapped_column(ForeignKey("engines.id", ondelete="CASCADE"))
    design_id: Mapped[int] = mapped_column(
        ForeignKey("estimator_designs.id", ondelete="CASCADE"), index=True
    )
    recording_id: Mapped[int] = mapped_column(
        ForeignKey("stream_recordings.id", ondelete="CASCADE")
    )
    window: Mapped[int] = mapped_column(Integer)
    t_s: Mapped[float] = mapped_column(Double)
    n: Mapped[int] = mapped_column(Integer)
    packed: Mapped[bytes] = mapped_column(LargeBinary)


class StreamFilterState(Base):
    """The stream filter's state for one recording and design after its last estimated sample.

    ``state`` holds, as exact JSON floats: ``x`` = x_hat at sample ``restart_sample - 1``,
    ``u_prev`` the input deviation there and ``anchor`` the operating condition the gain was
    scheduled at (where the next run restarts), ``x_end`` = x_hat at sample ``n_samples - 1``
    (the end of the last chunk) and ``x_initial`` (x_hat before sample 0, carried over from
    the engine's previous recording). The engine's latest recording's row is the engine's
    filter state under that design; ``layout`` names the numbers packed in each estimate.
    """

    __tablename__ = "stream_filter_states"
    __table_args__ = (
        UniqueConstraint("recording_id", "design_id"),
        Index("ix_stream_filter_states_engine_design_started", "engine_id", "design_id",
              "started_at"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    engine_id: Mapped[int] = mapped_column(ForeignKey("engines.id", ondelete="CASCADE"))
    design_id: Mapped[int] = mapped_column(
        ForeignKey("estimator_designs.id", ondelete="CASCADE")
    )
    recording_id: Mapped[int] = mapped_column(
        ForeignKey("stream_recordings.id", ondelete="CASCADE")
    )
    started_at: Mapped[datetime] = mapped_column(UTCDateTime())
    window: Mapped[int] = mapped_column(Integer)  # samples per stored window
    n_samples: Mapped[int] = mapped_column(Integer, default=0)
    restart_sample: Mapped[int] = mapped_column(Integer, default=0)
    n_segments: Mapped[int] = mapped_column(Integer, default=0)
    layout: Mapped[dict[str, Any]] = mapped_column(JSONDocument)
    state: Mapped[dict[str, Any]] = mapped_column(JSONDocument)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
