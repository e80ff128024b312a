"""Flight profiles and the snapshot points of a flight.

Seed 001 runs its engine through "ground-idle, takeoff, climb and then cruise
phases of a typical flight (Altitude: 0.0 ~ 35,000 ft, Mach: 0.0 ~ 0.84). The
flight duration is 2500 seconds" and takes 100 s windows of ground idle, climb
and cruise. The seed gives no breakpoints (its figure is lost), so the
profile below is ours: piecewise linear in altitude, Mach number and power
setting between breakpoint times shared by every flight, so that a batch of
flights with different airports, weather and cruise levels interpolates with
one weight per time step.

Power setting p [%] is the controller's demand: 0 ground idle, 100 take-off
(``actuators.demanded_corrected_fan_speed``). The ambient temperature offset
dTamb [K] is held over the whole flight.

Snapshot points are the steady-state conditions a ground station receives per
flight: take-off, climb and cruise, each with its operating condition and its
time from the start of the flight.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

PHASES = ("ground_idle", "takeoff", "climb", "cruise")
SNAPSHOT_PHASES = ("takeoff", "climb", "cruise")
DURATION_S = 2500.0

# Breakpoint times [s] shared by every flight; the value at each breakpoint
# comes from the flight's parameters (``_breakpoint_values``).
BREAKPOINTS_S = np.array(
    [0.0, 120.0, 126.0, 160.0, 240.0, 250.0, 600.0, 1300.0, 1330.0, DURATION_S]
)
# Phase windows [start, end) in seconds.
PHASE_WINDOWS: dict[str, tuple[float, float]] = {
    "ground_idle": (0.0, 120.0),
    "takeoff": (120.0, 250.0),
    "climb": (250.0, 1300.0),
    "cruise": (1300.0, DURATION_S),
}
# When, from the start of the flight, each snapshot is taken.
SNAPSHOT_TIMES_S: dict[str, float] = {"takeoff": 200.0, "climb": 700.0, "cruise": 2000.0}


class FlightParameters(NamedTuple):
    """What varies from flight to flight; arrays over a batch of flights [B] (or scalars).

    field_alt_ft: airport elevation; dtamb_k: ambient temperature offset from ISA;
    takeoff_power_pct, climb_power_pct, cruise_power_pct: power settings;
    cruise_alt_ft, cruise_mach: cruise level and speed.
    """

    field_alt_ft: np.ndarray
    dtamb_k: np.ndarray
    takeoff_power_pct: np.ndarray
    climb_power_pct: np.ndarray
    cruise_power_pct: np.ndarray
    cruise_alt_ft: np.ndarray
    cruise_mach: np.ndarray


class OperatingPoint(NamedTuple):
    """Operating condition, arrays of one shape: altitude [ft], Mach, dTamb [K], power [%]."""

    alt_ft: np.ndarray
    mach: np.ndarray
    dtamb_k: np.ndarray
    power_pct: np.ndarray


class FlightProfile(NamedTuple):
    """Piecewise-linear profiles of a batch of B flights on shared breakpoint times.

    time_s [K]; alt_ft, mach, power_pct [B, K]; dtamb_k [B]. Between breakpoints
    the condition is linear in time; after the last it is held.
    """

    time_s: np.ndarray
    alt_ft: np.ndarray
    mach: np.ndarray
    power_pct: np.ndarray
    dtamb_k: np.ndarray

    @property
    def n_flights(self) -> int:
        return int(self.alt_ft.shape[0])

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1])


class SnapshotPoint(NamedTuple):
    """One snapshot of a batch of flights: phase name, time from start [s], condition [B]."""

    phase: str
    time_s: float
    condition: OperatingPoint


def seed001_parameters(n: int = 1) -> FlightParameters:
    """The nominal flight of seed 001: sea level, ISA, cruise at 35,000 ft and Mach 0.84."""
    full = np.full
    return FlightParameters(
        field_alt_ft=full(n, 0.0), dtamb_k=full(n, 0.0),
        takeoff_power_pct=full(n, 100.0), climb_power_pct=full(n, 92.0),
        cruise_power_pct=full(n, 80.0), cruise_alt_ft=full(n, 35000.0),
        cruise_mach=full(n, 0.84),
    )


def random_parameters(n: int, rng: np.random.Generator) -> FlightParameters:
    """Per-flight variation around the seed 001 flight, for a fleet.

    Airports up to 5,000 ft (most near sea level), dTamb ~ N(0, 8 K) clipped to
    +-25 K, derated take-off 90-100 %, climb 88-95 %, cruise 75-85 %, cruise at
    flight levels 310-390 (the model's envelope ends at 40,000 ft), Mach 0.78-0.84.
    """
    return FlightParameters(
        field_alt_ft=np.minimum(rng.exponential(800.0, n), 5000.0),
        dtamb_k=np.clip(rng.normal(0.0, 8.0, n), -25.0, 25.0),
        takeoff_power_pct=rng.uniform(90.0, 100.0, n),
        climb_power_pct=rng.uniform(88.0, 95.0, n),
        cruise_power_pct=rng.uniform(75.0, 85.0, n),
        cruise_alt_ft=rng.choice(np.arange(31000.0, 39001.0, 2000.0), n),
        cruise_mach=rng.uniform(0.78, 0.84, n),
    )


def _as_batch(params: FlightParameters) -> FlightParameters:
    arrays = [np.atleast_1d(np.asarray(v, dtype=float)) for v in params]
    n = max(a.shape[0] for a in arrays)
    return FlightParameters(*(np.broadcast_to(a, (n,)).copy() for a in arrays))


def flight_profile(params: FlightParameters | None = None) -> FlightProfile:
    """The 2500 s profile (ground idle, take-off, climb, cruise) of a batch of flights.

    Breakpoints (s): 0-120 ground idle; 120-126 throttle to take-off power;
    126-160 take-off roll to Mach 0.25; 160-240 initial climb to field + 2,000 ft;
    240-250 back to climb power; 250-1300 climb (Mach 0.3 -> 0.6 at 15,000 ft ->
    0.80 at cruise level); 1300-1330 level off to cruise power and Mach; cruise
    to 2500 s.
    """
    p = _as_batch(params if params is not None else seed001_parameters())
    f = p.field_alt_ft
    zero = np.zeros_like(f)
    c_alt = np.maximum(p.cruise_alt_ft, f + 20000.0)
    mid_alt = np.maximum(15000.0, f + 5000.0)
    alt = np.stack([f, f, f, f, f + 2000.0, f + 2000.0, mid_alt, c_alt, c_alt, c_alt], axis=1)
    mach = np.stack(
        [zero, zero, zero, zero + 0.25, zero + 0.30, zero + 0.30, zero + 0.60,
         np.minimum(p.cruise_mach, 0.80), p.cruise_mach, p.cruise_mach], axis=1,
    )
    power = np.stack(
        [zero, zero, p.takeoff_power_pct, p.takeoff_power_pct, p.takeoff_power_pct,
         p.climb_power_pct, p.climb_power_pct, p.climb_power_pct, p.cruise_power_pct,
         p.cruise_power_pct], axis=1,
    )
    return FlightProfile(BREAKPOINTS_S.copy(), alt, mach, power, p.dtamb_k.copy())


def condition_at(profile: FlightProfile, t: float | np.ndarray) -> OperatingPoint:
    """Operating condition of every flight at time(s) t [s]: arrays [B] (or [B, T] for t [T]).

    Linear interpolation between the shared breakpoints, held beyond the ends.
    """
    ts = profile.time_s
    tt = np.clip(np.asarray(t, dtype=float), ts[0], ts[-1])
    i = np.clip(np.searchsorted(ts, tt, side="right") - 1, 0, ts.size - 2)
    w = (tt - ts[i]) / (ts[i + 1] - ts[i])

    def lerp(v: np.ndarray) -> np.ndarray:
        return v[:, i] + w * (v[:, i + 1] - v[:, i])

    alt, mach, power = lerp(profile.alt_ft), lerp(profile.mach), lerp(profile.power_pct)
    dtamb = np.broadcast_to(
        profile.dtamb_k.reshape((-1,) + (1,) * np.ndim(tt)), alt.shape
    ).copy()
    return OperatingPoint(alt, mach, dtamb, power)


def phase_at(t: float | np.ndarray) -> np.ndarray:
    """Phase name at time(s) t [s] from the start of the flight (``PHASES``)."""
    tt = np.asarray(t, dtype=float)
    starts = np.array([PHASE_WINDOWS[name][0] for name in PHASES])
    idx = np.clip(np.searchsorted(starts, tt, side="right") - 1, 0, len(PHASES) - 1)
    return np.asarray(PHASES, dtype=object)[idx]


def snapshot_points(profile: FlightProfile) -> tuple[SnapshotPoint, ...]:
    """Take-off, climb and cruise snapshot conditions of every flight in the batch."""
    times = SNAPSHOT_TIMES_S
    return tuple(
        SnapshotPoint(phase, times[phase], condition_at(profile, times[phase]))
        for phase in SNAPSHOT_PHASES
    )
