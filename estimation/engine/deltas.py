"""The classic performance deltas: each measured gas-path parameter against the nominal engine at
the record's own condition, in corrected parameters, smoothed over flights.

dEGT = (T48 - T48_base) / theta2 [K] (T48 in degR: / 1.8); dWf, dN2 (Nc), dN1 (Nf) in percent
of the baseline (a ratio at one condition, so corrected and physical ratios are equal). One
record's scatter (0.75 % of T48, about 6 K) would hide a trend of a few degrees, so the deltas
are smoothed by a first-order recursive filter over records (``smooth``, weight ``SMOOTHING``:
about ten flights). The EGT at a reference condition follows from the smoothed dEGT as
EGT_ref = T48_base(ref) + dEGT theta2(ref) (``reference_egt``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import signal

from estimation.engine.atmosphere import RANKINE, flight_condition
from estimation.engine.schedule import EngineSchedule

# (figure, measured sensor, unit) of each delta.
DELTA_SENSORS = (("dEGT", "T48", "degC"), ("dWf", "Wf", "%"), ("dN2", "Nc", "%"),
                 ("dN1", "Nf", "%"))
EGT_SENSOR = "T48"
SMOOTHING = 0.1  # weight of each new record in the exponential filter (~10 flights)
# The fleet status's EGT margin: from the median dEGT of an engine's last EGT_WINDOW records
# (raw, not smoothed), the figure its severity checks and the fleet page draws.
STATUS_EGT_MARGIN = "status_egt_margin"
EGT_WINDOW = 20


def window_medians(values: np.ndarray, window: int = EGT_WINDOW) -> np.ndarray:
    """[n] the median of each record's last ``window`` values (itself included; fewer at the
    start), as the fleet status takes the EGT margin's dEGT."""
    values = np.asarray(values, float)
    n = len(values)
    out = np.empty(n)
    head = min(n, window - 1)
    for i in range(head):
        out[i] = np.median(values[: i + 1])
    if n >= window:
        out[window - 1:] = np.median(
            np.lib.stride_tricks.sliding_window_view(values, window), axis=1)
    return out


def egt_delta(t48: np.ndarray, baseline: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """dEGT [K, corrected] of measured T48 against the nominal engine's, both in degR."""
    return (np.asarray(t48, float) - baseline) / theta / RANKINE


def smooth(values: np.ndarray, weight: float = SMOOTHING) -> np.ndarray:
    """Exponential smoothing over records along axis 0 [n, k]; a missing value (NaN) keeps the
    previous smoothed value, and the filter starts at the first value present.

    Per column, over its present values x_0, x_1, ...: s_0 = x_0, s_i = s_(i-1) + w (x_i -
    s_(i-1)), a first-order recursive filter (``scipy.signal.lfilter``); a missing record
    carries the last s forward.
    """
    values = np.asarray(values, float)
    out = np.full(values.shape, np.nan)
    flat = values.reshape(values.shape[0], -1)
    res = out.reshape(values.shape[0], -1)
    for j in range(flat.shape[1]):
        present = np.flatnonzero(~np.isnan(flat[:, j]))
        if present.size == 0:
            continue
        x = flat[present, j]
        s = np.empty_like(x)
        s[0] = x[0]
        if x.size > 1:
            s[1:], _ = signal.lfilter([weight], [1.0, weight - 1.0], x[1:],
                                      zi=[(1.0 - weight) * x[0]])
        # Each record takes the smoothed value of the last present record at or before it.
        last = np.searchsorted(present, np.arange(flat.shape[0]), side="right") - 1
        known = last >= 0
        res[known, j] = s[last[known]]
    return out


def smoothed_deltas(
    measured: Mapping[str, np.ndarray], baseline: Mapping[str, np.ndarray], theta: np.ndarray,
) -> list[tuple[str, str, np.ndarray]]:
    """(figure, unit, [n] smoothed values) of each delta whose sensor is measured and has a
    baseline: ``measured`` and ``baseline`` name -> [n] in engine units (degR, pps, rpm),
    theta [n] the records' theta2."""
    raw: list[tuple[str, str, np.ndarray]] = []
    for name, sensor, unit in DELTA_SENSORS:
        value = measured.get(sensor)
        if value is None or sensor not in baseline:
            continue
        value = np.asarray(value, float)
        if sensor == EGT_SENSOR:
            delta = egt_delta(value, baseline[sensor], theta)
        else:
            delta = 100.0 * (value / baseline[sensor] - 1.0)
        raw.append((name, unit, delta))
    if not raw:
        return []
    smoothed = smooth(np.stack([d for _n, _u, d in raw], axis=1))
    return [(name, unit, smoothed[:, j]) for j, (name, unit, _d) in enumerate(raw)]


def reference_egt(
    d_egt: np.ndarray | float, egt_reference: float, theta_reference: float,
) -> np.ndarray:
    """EGT at the reference condition of engines with the smoothed dEGT [K]: the nominal
    engine's there (``egt_reference``, any temperature unit of kelvin steps) plus dEGT
    uncorrected to the reference's theta2."""
    return egt_reference + np.asarray(d_egt, float) * theta_reference


# The EGT margin's reference condition, in the schedule's axes order: alt [ft], mach, power [%],
# dtamb [K]: take-off at sea level on an ISA+15 K day (the flat-rate corner where the margin
# is smallest).
EGT_REFERENCE_CONDITION = (0.0, 0.0, 100.0, 15.0)


@dataclass(frozen=True)
class EgtReference:
    """The nominal engine at the EGT margin's reference condition: its T48 [K] and theta2."""

    t48_k: float
    theta: float

    @property
    def environment(self) -> np.ndarray:
        """[1, 3] alt, mach, dtamb of the reference (the steady-state solver's order)."""
        alt, mach, _power, dtamb = EGT_REFERENCE_CONDITION
        return np.array([[alt, mach, dtamb]])

    @property
    def power(self) -> float:
        return EGT_REFERENCE_CONDITION[2]


def egt_reference(schedule: EngineSchedule) -> EgtReference:
    """The schedule's nominal T48 at ``EGT_REFERENCE_CONDITION`` and the theta2 there."""
    alt, mach, _power, dtamb = EGT_REFERENCE_CONDITION
    t48 = float(schedule.trims_at(np.array([EGT_REFERENCE_CONDITION]))[EGT_SENSOR][0])
    return EgtReference(t48 / RANKINE, float(flight_condition(alt, mach, dtamb).theta))


def smoothing_growth(n: int, weight: float = SMOOTHING) -> np.ndarray:
    """[n] factor on a settled smoothed record's 1-sigma at record i of a trend: the smoothed
    noise's variance at record i over its settled value, sqrt(1 + (1 - w)^(2 i) (2 - 2 w) / w)
    (s_0 is one raw record; the variance settles to w / (2 - w) of a record's)."""
    decay = (1.0 - weight) ** (2.0 * np.arange(n))
    return np.sqrt(1.0 + decay * (2.0 - 2.0 * weight) / weight)
