"""The health group of a trend: honest 1-sigma, unobservable parameters, change since baseline.

Stored estimates keep the filter's own 1-sigma (sensor noise only). At read time, with the
design's calibration (``designs.calibration``: stored in the design's result under
``"uncertainty"``), each record's health sigma becomes the honest one of
``estimation.uncertainty`` (``level_sigma``: analytic bias, filter variance and calibrated model
error), and a parameter the calibration finds unobservable comes back as nulls, listed in the
group's ``unobservable``. The aux outputs' sigma (thrust, stall margins, T40, bypass ratio) and
the tuners' take the scale and model error the calibration fitted for each on the same fleets, so
that the tuners, the aux group and the engineering units drawn from it (``trends.performance``)
carry honest bands too. Without a calibration (a design of an imported model) the filter's
sigma is shown and the group says ``"uncalibrated"``.

The change view (``health=change``) shows h_hat(t) - h_hat(0) against the engine's baseline
record 0: the first settled record (``BASELINE_SETTLE_RECORDS`` records on) after the
engine's first record, an installation, a shop visit or a module change (a water wash does not
move it: its recovery is part of the trend). Its sigma is ``uncertainty.change_sigma`` (or,
uncalibrated, the two filter sigmas in quadrature); records before a baseline settles are null.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any, Literal

import numpy as np
from sqlalchemy import select, union_all
from sqlalchemy.orm import Session

from app.models import Installation, MaintenanceAction
from app.services.designs.calibration import BASELINE_KINDS, BASELINE_SETTLE_RECORDS
from estimation import uncertainty

HealthView = Literal["level", "change"]
HEALTH_VIEWS = ("level", "change")


@dataclass(frozen=True)
class HealthMeta:
    """What the health group carries besides its series."""

    view: HealthView
    uncertainty: Literal["calibrated", "uncalibrated"]
    unobservable: tuple[str, ...]
    baselines: tuple[float, ...] = ()  # epoch seconds of the baseline records (change view)
    # The tuners the calibration finds unobservable (nulls in the tuners group) and those it
    # shows calibrated (V* times the calibrated level).
    tuners_unobservable: tuple[str, ...] = ()
    tuners_calibrated: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"view": self.view, "uncertainty": self.uncertainty,
                "unobservable": list(self.unobservable),
                "baselines": [datetime.fromtimestamp(t, UTC) for t in self.baselines]
                if self.view == "change" else None}


def baseline_resets(session: Session, engine_id: int) -> np.ndarray:
    """Epoch seconds [R], sorted, of the engine's installations, shop visits and module
    changes: each starts a new baseline."""
    query = union_all(
        select(Installation.installed_at.label("t")).where(Installation.engine_id == engine_id),
        select(MaintenanceAction.performed_at).where(
            MaintenanceAction.engine_id == engine_id, MaintenanceAction.kind.in_(BASELINE_KINDS)
        ),
    )
    times = [t.timestamp() for (t,) in session.execute(query).all() if t is not None]
    return np.array(sorted(times), dtype=float)


def baseline_index(epoch: np.ndarray, resets: np.ndarray, settle: int) -> np.ndarray:
    """Index [n] of each record's baseline record, -1 before its baseline settles.

    Records split at each reset time (a record at the reset belongs to the new piece); the
    baseline of a piece is its record number ``settle`` (0: its first record).
    """
    n = len(epoch)
    piece = np.searchsorted(resets, epoch, side="right")
    first = np.flatnonzero(np.r_[True, piece[1:] != piece[:-1]]) if n else np.empty(0, int)
    start = np.repeat(first, np.diff(np.r_[first, n]))
    base = start + settle
    # The baseline must lie inside the record's piece, and the record at or after it.
    end = np.repeat(np.r_[first[1:], n], np.diff(np.r_[first, n]))
    ok = (base < end) & (np.arange(n) >= base)
    return np.where(ok, base, -1)


def apply(
    values: np.ndarray, layout_slices: dict[str, slice], names: tuple[str, ...],
    calib: uncertainty.Calibration | None, view: HealthView,
    epoch: np.ndarray | None = None, phase: list[str] | None = None,
    resets: np.ndarray | None = None, settle: int = BASELINE_SETTLE_RECORDS,
    aux_names: tuple[str, ...] = (), tuner_names: tuple[str, ...] = (),
) -> tuple[np.ndarray, HealthMeta]:
    """The health columns of ``values`` [n, width] (a new float64 array) in ``view``, the aux
    outputs (``aux_names``) and the tuners (``tuner_names``) calibrated
    (``Calibration.aux_level``, ``Calibration.tuner_level``), their 1-sigma made honest by the
    calibration (``Calibration.aux_sigma``, ``Calibration.tuner_sigma``) and the tuners it
    finds unobservable NaN (``HealthMeta.tuners_unobservable``).

    Level: the calibrated level and its honest sigma per record (``Calibration.level``).
    Change: the calibrated h_hat - h_hat[b] and its sigma (``Calibration.change``), c the
    take-off records (cycles) since b, in thousands; uncalibrated, the raw difference and the
    two filter sigmas in quadrature. Unobservable parameters: NaN (null in JSON).
    """
    out = np.array(values, dtype=np.float64)
    h_cols, s_cols = layout_slices["h"], layout_slices["h_sigma"]
    h, f = out[:, h_cols].copy(), out[:, s_cols].copy()
    p = len(names)
    hidden = np.zeros(p, bool)
    on = calib.on(names) if calib is not None else None
    if on is not None:
        hidden = ~on.observable
    baselines: tuple[float, ...] = ()
    if view == "level":
        new_h, new_s = on.level(h, f) if on is not None else (h, f)
    else:
        epoch = np.asarray(epoch if epoch is not None else np.arange(len(out)), float)
        b = baseline_index(epoch, np.asarray(resets if resets is not None else []), settle)
        has = b >= 0
        bb = np.where(has, b, 0)
        takeoff = np.cumsum([ph == "takeoff" for ph in (phase or [])]) if phase else None
        if takeoff is None or not takeoff.size or takeoff[-1] == 0:
            takeoff = np.arange(len(out))  # no phases: one record a cycle
        kcycles = (takeoff - takeoff[bb]) / 1000.0
        if on is not None:
            delta, sigma = on.change(h, h[bb], f, f[bb], kcycles)
        else:
            delta, sigma = h - h[bb], np.sqrt(np.square(f) + np.square(f[bb]))
        new_h = np.where(has[:, None], delta, np.nan)
        new_s = np.where(has[:, None], sigma, np.nan)
        baselines = tuple(float(t) for t in epoch[np.unique(b[has])])
    new_h = np.where(hidden, np.nan, new_h)
    new_s = np.where(hidden, np.nan, new_s)
    out[:, h_cols] = new_h
    out[:, s_cols] = new_s
    if on is not None and aux_names and "z" in layout_slices:  # the calibrated aux outputs
        z_cols = layout_slices["z"]
        out[:, z_cols] = on.aux_level(aux_names, out[:, z_cols], h)
    if calib is not None and aux_names and "z_sigma" in layout_slices:
        z_cols = layout_slices["z_sigma"]
        out[:, z_cols] = calib.aux_sigma(aux_names, out[:, z_cols], uncertainty.spread(h))
    tuners_hidden: tuple[str, ...] = ()
    tuners_calibrated: tuple[str, ...] = ()
    if on is not None and tuner_names and "q" in layout_slices and "q_sigma" in layout_slices:
        # The tuners the page shows agree with its health: V* times the calibrated level.
        q_cols, qs_cols = layout_slices["q"], layout_slices["q_sigma"]
        gone = on.tuner_hidden(tuner_names)
        q = on.tuner_level(tuner_names, out[:, q_cols], h)
        q_sigma = on.tuner_sigma(tuner_names, out[:, qs_cols], uncertainty.spread(h))
        out[:, q_cols] = np.where(gone, np.nan, q)
        out[:, qs_cols] = np.where(gone, np.nan, q_sigma)
        tuners_hidden = tuple(n for n, x in zip(tuner_names, gone, strict=True) if x)
        tuners_calibrated = tuple(n for n in on.tuners_corrected if n not in tuners_hidden)
    meta = HealthMeta(view, "uncalibrated" if calib is None else "calibrated",
                      tuple(n for n, x in zip(names, hidden, strict=True) if x), baselines,
                      tuners_hidden, tuners_calibrated)
    return out, meta
