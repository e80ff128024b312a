"""Design evaluation on the built-in nonlinear engine (seed 002 Table 3 faults, whole envelope).

The Monte Carlo of ``estimation.evaluate`` runs on the linear model the design was made
from, where theory and experiment agree by construction. Here the truth is the nonlinear
engine (``estimation.engine.steady``): a fleet of engines with manufacturing scatter,
deterioration and actuator biases, each flying ``n_before`` snapshots (by default take-off
and cruise of random flights of ``flight.random_parameters``; climb and ground idle on
request, ``RECORD_PHASES``) before a library fault and ``n_after`` with it. The sensors
carry the engine's noise (constant in sensor units, seed 001 Table 2); the fuel-flow command
is the noisy Wf sensor, as in ``fleet.fleet_snapshots``.

Each design is scored the way the product isolates (``app.services.shift_detection``): the
baseline tuners q_0 are the R^-1-weighted least-squares fit of the records before the fault
(where the snapshot filter settles), the records after it are fitted in sensor space against
that baseline,

    r_j = dy_j - G_y,j V*^+ q_0                  (record j, percent of trim)
    a_i = sum_j g_ij^T W_j g_ij,  b_i = sum_j g_ij^T W_j r_j,  c = sum_j r_j^T W_j r_j
    f_i = clip(b_i / a_i, 0.5, 3)                 (the product's MAGNITUDE_RANGE)
    WSSR_i = c - 2 f_i b_i + f_i^2 a_i            (seed 002 eq. 21-23, f held to the range)

and the smallest WSSR names the fault (``EngineDesign.magnitudes=None``: the free fit of seed
002, f_i = b_i / a_i). ``g_ij`` is fault i's sensor change at record j:

- ``signatures="linear"``: the scheduled gains at the nominal engine, G_y,j s_i (the product
  today);
- ``signatures="secant"``: the nonlinear engine's own change at record j's condition from the
  estimated baseline health h_0 = V*^+ q_0 to h_0 + s_i (one batched steady-state solve per
  fault). This carries the engine's nonlinearity (a 4 % LPC fault, a deteriorated engine) and
  the closed loop (the controller holds corrected fan speed, so a fuel-flow bias moves only
  the fuel-flow command).

Two ways of using the fuel-flow signal (``wf="input"`` / ``"sensor"``): as a measured input
(its deviation through G_u subtracted from every sensor, the product today; a noisy input then
puts correlated error on every sensor) or as a sensor at the closed-loop gain (power setting
as the condition: the Wf row and all others from the constraint that corrected fan speed
holds its demand).

How much of each fault the data can show: ``signature_sigmas`` (a fault's sensor change at
given conditions in noise sigmas) and ``fault_sigmas`` (per simulated record). On the built-in
engine the VBV bias stays below 0.1 sigma per snapshot over the whole envelope: the bleed
flow is small wherever the valve is open (ground idle, P24 / Pamb about 1.1), so a -10 % bias
of it moves nothing, and a VSV bias is largest (0.7 sigma, on Nc) with the stators open at
high power. ``stroke_offset_sigmas`` measures the other reading of a VSV or VBV bias, an
offset of full stroke: at take-off and cruise the VSV's -2 points are the library's -2 %
(stators fully open), and the valve at its 1 % leak can close by one point only (0.43 sigma
over a 20-record event); a valve held 10 points open would show 4.2 sigma (50 engines a
fault, bench/bench_isolation.py).

Where the points go (bench/bench_isolation.py, 50 engines a fault, 30 + 20 take-off and
cruise records, the demo design on the product's path). With the free fit of seed 002 it
isolated 76.2 % of the eight: a 4 % LPC fault was taken for the VBV bias reversed and 270
times its shift (32 % of LPC faults: the VBV's linear signature, a sliver at the valve's
leak, points along the LPC's), the VSV bias for 0.01-0.4 of a fuel-flow, Fan, HPC or LPT
fault (VSV 42 %), and the VBV bias, which shows nothing, went anywhere (8 %). Held to 0.5-3
times the library's shift (``shift_detector.MAGNITUDE_RANGE``, the product's plausible range)
those hypotheses pay for the scaling: 90.5 % of the eight (Fan 92, LPC 100, HPC, HPT, LPT, Wf 100,
VSV 66, VBV 66), 94.0 % of the seven with a signature against 86.0 %.

The ceiling on the faults' evidence is ``chance_ceiling`` = (7 x 100 + 12.5) / 8 = 89.1 %:
the VBV fault shows nothing (0.04 sigma over an event; 0.22 with ground-idle records in the
mix, 0.07 sigma per idle snapshot, so some 1,800 idle snapshots would be needed for 3 sigma)
and a fit that names a fault on its signature alone isolates it at chance. Held to the
library's magnitudes, the VBV fault is named by elimination instead (when a fault is known to
have struck and nothing changed, it is the one library fault that explains no change), which
passes the ceiling in this evaluation, where the fault's onset is given. The product names a
fault only when it explains ``shift_detector.EVIDENCE_THRESHOLD`` of the change, and no alarm
is raised for a VBV fault in service: ``EngineEvaluation.percent_on_evidence`` counts that way
(76.0 % of the eight for the demo design, VBV 0 %, VSV 16 %). What the design does change
(percent of all eight, magnitudes held): the number of tuners (the baseline's fit of the
engine before the fault: SVD m = 8 87.8 %, m = 6 81.8 %, subset m = 10 90.5 %), fuel flow as
a sensor at the closed-loop gain (+3 points: 93.5 %), secant signatures beside it (94.0 %),
and the event's length (60 records instead of 20: 93.2 %, VSV 80 %; the evidence grows as
the root of the record count). Ground-idle records in place of a third of the take-off and
cruise ones lower it (86.5 %): idle shows the Fan and VSV faults less and the VBV still not.
The diagnostics-aware design (seed 002 KF design 3) buys nothing here that is larger than
the sampling noise (about 2 points): against SVD of the same m, path and records it scored
-2.5 to 0 points at m = 8 and -10 to +3 at m = 6 with the free fit, and -1.5 / +6.2 at m = 8 / 6
held (take-off and cruise, 20 records; the m = 6 SVD design fits the baseline worst), at
0.3-0.5 % worse health RMS. Its objective separates the faults in tuner space on the linear
cruise model, but the isolation here is in sensor space, where a fault's signature g_ij does
not pass through the tuners at all; V* enters only through the baseline h_0.

Pure: numpy and the engine model; randomness from the ``rng`` passed in.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from estimation import isolation
from estimation.engine.fleet import DETERIORATION_RATES, N_TURBO, engine_noise_std
from estimation.engine.flight import (
    condition_at,
    flight_profile,
    random_parameters,
    snapshot_points,
)
from estimation.engine.health import HEALTH_NAMES, N_HEALTH
from estimation.engine.schedule import EngineSchedule
from estimation.engine.sensors import SENSOR_NAMES
from estimation.engine.steady import steady_state
from estimation.shift_detector import EVIDENCE_THRESHOLD, MAGNITUDE_RANGE
from estimation.theory import information_floor

WF = SENSOR_NAMES.index("Wf")
NF = SENSOR_NAMES.index("Nf")
MODEL_ERROR = 0.2  # percent of trim added in quadrature to the noise (as the product's)
SIGNATURES = ("linear", "secant")
WF_MODES = ("input", "sensor")
# Record phases: the flight's steady snapshot points and ground idle (flight.PHASE_WINDOWS).
RECORD_PHASES = ("ground_idle", "takeoff", "climb", "cruise")
DEFAULT_PHASES = ("takeoff", "cruise")  # the product's replay
FLOOR_RECORDS = 1000  # snapshots of each phase the information floor is stated for
GROUND_IDLE_S = 60.0  # the ground-idle snapshot's time from the start of the flight
NO_SIGNATURE_SIGMAS = 1.0  # an event signature below this shows a fault no better than chance


@dataclass(frozen=True)
class FleetSpread:
    """How the simulated engines of an evaluation differ before a fault: scatter
    N(0, scatter_std) in the ten turbomachinery parameters; deterioration over U(0, cycles_max)
    cycles, shared by the modules, at the fleet simulator's mean rates times a
    lognormal(rate_spread) multiplier per parameter; actuator biases N(0, bias_std)."""

    scatter_std: float = 0.4
    cycles_max: float = 12000.0
    rate_spread: float = 0.3
    bias_std: tuple[float, float, float] = (0.5, 1.0, 2.0)

    def draw(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n engines' health [n, 13] (``HEALTH_NAMES``, percent)."""
        h = np.zeros((n, N_HEALTH))
        cycles = rng.uniform(0.0, self.cycles_max, (n, 1))
        mult = np.exp(self.rate_spread * rng.standard_normal((n, N_TURBO)))
        h[:, :N_TURBO] = (rng.normal(0.0, self.scatter_std, (n, N_TURBO))
                          + DETERIORATION_RATES * mult * cycles / 1000.0)
        h[:, N_TURBO:] = rng.normal(0.0, 1.0, (n, 3)) * np.asarray(self.bias_std)
        return h

    def covariance(self) -> np.ndarray:
        """The covariance [13, 13] of ``draw``'s engines: with c ~ U(0, C) thousand cycles and
        m_i ~ lognormal(0, s), E[c m_i] = C/2 e^(s^2/2) and E[c^2 m_i m_j] = C^2/3 e^(s^2)
        (e^(2 s^2) for i = j); the modules covary through the shared cycles."""
        C, s2 = self.cycles_max / 1000.0, self.rate_spread**2
        mean = C / 2.0 * np.exp(s2 / 2.0)
        moments = np.full((N_TURBO, N_TURBO), C**2 / 3.0 * np.exp(s2))
        np.fill_diagonal(moments, C**2 / 3.0 * np.exp(2.0 * s2))
        cov = np.zeros((N_HEALTH, N_HEALTH))
        cov[:N_TURBO, :N_TURBO] = (np.outer(DETERIORATION_RATES, DETERIORATION_RATES)
                                   * (moments - mean**2) + self.scatter_std**2 * np.eye(N_TURBO))
        cov[N_TURBO:, N_TURBO:] = np.diag(np.square(self.bias_std))
        return cov


class EngineEvaluationError(ValueError):
    """Settings or a design that do not fit the engine evaluation."""


@dataclass(frozen=True)
class EngineRecords:
    """Simulated snapshot records of a faulted fleet, engine by engine.

    E engines, K = n_before + n_after records each (the fault strikes at record n_before).
    conditions [E, K, 4] (alt ft, Mach, power %, dTamb K: the schedule's axis order);
    health [E, K, 13] true health and actuator biases (percent, HEALTH_NAMES);
    y [E, K, 12] measured sensors (SENSOR_NAMES, sensor units); u [E, K, 3] actuator commands
    (Wf the measured fuel flow, VSV and VBV as commanded); y_trim [E, K, 12], u_trim [E, K, 3]
    the nominal engine at the same condition; noise_pct [E, K, 12] the sensor noise in percent
    of y_trim; fault [E] index into ``faults``.
    """

    faults: tuple[isolation.Fault, ...]
    n_before: int
    conditions: np.ndarray
    health: np.ndarray
    y: np.ndarray
    u: np.ndarray
    y_trim: np.ndarray
    u_trim: np.ndarray
    noise_pct: np.ndarray
    fault: np.ndarray

    @property
    def fault_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.faults)


def _snapshot_conditions(
    n: int, rng: np.random.Generator, phases: Sequence[str] = DEFAULT_PHASES
) -> np.ndarray:
    """n snapshot conditions of random flights [n, 4] (alt, Mach, power, dTamb), each at a
    phase drawn uniformly from ``phases`` (``RECORD_PHASES``): the steady points of
    ``flight.snapshot_points`` and ground idle (field elevation, Mach 0, power 0, a minute
    into the flight's ground-idle window)."""
    unknown = [p for p in phases if p not in RECORD_PHASES]
    if not phases or unknown:
        raise EngineEvaluationError(f"phases from {RECORD_PHASES}, got {tuple(phases)}")
    profile = flight_profile(random_parameters(n, rng))
    points = {p.phase: p.condition for p in snapshot_points(profile)}
    points["ground_idle"] = condition_at(profile, GROUND_IDLE_S)
    pick = np.minimum((rng.random(n) * len(phases)).astype(int), len(phases) - 1)
    out = np.empty((n, 4))
    for k, name in enumerate(("alt_ft", "mach", "power_pct", "dtamb_k")):
        out[:, k] = np.choose(pick, [getattr(points[p], name) for p in phases])
    return out


def simulate_records(
    n_per_fault: int,
    *,
    rng: np.random.Generator,
    faults: Sequence[isolation.Fault] = isolation.SEED_002_FAULTS,
    n_before: int = 30,
    n_after: int = 20,
    scatter_std: float = FleetSpread.scatter_std,
    cycles_max: float = FleetSpread.cycles_max,
    rate_spread: float = FleetSpread.rate_spread,
    bias_std: tuple[float, float, float] = FleetSpread.bias_std,
    noise: bool = True,
    phases: Sequence[str] = DEFAULT_PHASES,
) -> EngineRecords:
    """A fleet of ``n_per_fault`` engines per library fault on the nonlinear engine.

    Each engine drawn as ``FleetSpread.draw`` draws it (scatter, deterioration, actuator
    biases, with these settings); then the fault's shifts from
    record ``n_before`` on. Every record at its own random flight's condition, of a phase
    drawn uniformly from ``phases`` (``RECORD_PHASES``; default take-off and cruise, half
    each).
    Solved in one batched steady-state call for the engines and one for the nominal trims.
    """
    faults = tuple(faults)
    E, K = n_per_fault * len(faults), n_before + n_after
    if n_per_fault < 1 or n_before < 2 or n_after < 1:
        raise EngineEvaluationError("need n_per_fault >= 1, n_before >= 2, n_after >= 1")
    if not phases or any(p not in RECORD_PHASES for p in phases):
        raise EngineEvaluationError(f"phases from {RECORD_PHASES}, got {tuple(phases)}")
    S = isolation.signature_matrix(faults, HEALTH_NAMES)  # [13, n_f]
    fault = np.repeat(np.arange(len(faults)), n_per_fault)
    h0 = FleetSpread(scatter_std, cycles_max, rate_spread, bias_std).draw(E, rng)
    health = np.repeat(h0[:, None, :], K, axis=1)
    health[:, n_before:, :] += S.T[fault][:, None, :]
    cond = _snapshot_conditions(E * K, rng, tuple(phases))
    env = cond[:, [0, 1, 3]]
    ss = steady_state(env, power=cond[:, 2], health=health.reshape(E * K, N_HEALTH))
    nominal = steady_state(env, power=cond[:, 2])
    std = engine_noise_std()
    y = ss.sensors + (rng.standard_normal(ss.sensors.shape) * std if noise else 0.0)
    u = ss.u.copy()
    u[:, 0] = y[:, WF]  # the fuel-flow command is measured by the Wf sensor
    noise_pct = 100.0 * std / np.abs(nominal.sensors)
    return EngineRecords(
        faults, n_before, cond.reshape(E, K, 4), health, y.reshape(E, K, 12),
        u.reshape(E, K, 3), nominal.sensors.reshape(E, K, 12), nominal.u.reshape(E, K, 3),
        noise_pct.reshape(E, K, 12), fault,
    )


def signature_sigmas(
    conditions: np.ndarray,
    faults: Sequence[isolation.Fault] = isolation.SEED_002_FAULTS,
    health: np.ndarray | None = None,
) -> np.ndarray:
    """Each fault's sensor change in noise sigmas at each condition [N, 12, n_f].

    conditions [N, 4] (alt ft, Mach, power %, dTamb K); health [N, 13] or [13] the engine
    before the fault (default nominal). The change is the nonlinear engine's, closed loop at
    the power setting (the controller moves the fuel-flow command, which the Wf sensor
    reads), divided by the sensor noise in sensor units (``fleet.engine_noise_std``). The norm
    over sensors is what one snapshot shows of the fault; over n snapshots the evidence
    grows as the root of the sum of squares.
    """
    cond = np.atleast_2d(np.asarray(conditions, float))
    env = cond[:, [0, 1, 3]]
    h = np.broadcast_to(np.zeros(N_HEALTH) if health is None else np.asarray(health, float),
                        (cond.shape[0], N_HEALTH))
    S = isolation.signature_matrix(tuple(faults), HEALTH_NAMES)
    std = engine_noise_std()
    base = steady_state(env, power=cond[:, 2], health=h)
    out = np.empty((cond.shape[0], len(SENSOR_NAMES), S.shape[1]))
    for i in range(S.shape[1]):
        hit = steady_state(env, power=cond[:, 2], health=h + S[:, i])
        out[:, :, i] = (hit.sensors - base.sensors) / std
    return out


def fault_sigmas(rec: EngineRecords) -> np.ndarray:
    """Per engine and post-fault record, the norm in noise sigmas of the sensor change its
    own fault makes at that record's condition (true health before and after) [E, n_after].
    The event's evidence is the root sum of squares over the records."""
    nb = rec.n_before
    cond = rec.conditions[:, nb:, :].reshape(-1, 4)
    env, power = cond[:, [0, 1, 3]], cond[:, 2]
    after = rec.health[:, nb:, :]
    before = np.repeat(rec.health[:, :1, :], after.shape[1], axis=1)
    hit = steady_state(env, power=power, health=after.reshape(-1, N_HEALTH))
    base = steady_state(env, power=power, health=before.reshape(-1, N_HEALTH))
    d = np.linalg.norm((hit.sensors - base.sensors) / engine_noise_std(), axis=1)
    return d.reshape(after.shape[:2])


def stroke_offset_sigmas(
    conditions: np.ndarray,
    actuator: str,
    offset: float,
    health: np.ndarray | None = None,
) -> np.ndarray:
    """An actuator fault taken as an offset of the actuator's full stroke (``offset``
    percentage points of its 0-100 % travel, held inside its stops) instead of the engine's
    fraction of the command: the sensor change in noise sigmas per condition [N] (norm over
    the sensors), closed loop as ``signature_sigmas``.

    ``actuator`` is "VSV" or "VBV"; conditions [N, 4] (alt ft, Mach, power %, dTamb K);
    health [N, 13] or [13] the engine before the fault (default nominal). The offset is put
    on the engine as the fraction of the command the engine's health parameter means
    (``estimation.engine.health``): position c + offset, clipped to 0-100, is c (1 + h / 100)
    with c the command before the fault. What a rigging offset would show, measured on the
    same engine: on the built-in engine the VBV sits at its 1 % leak at take-off and cruise,
    so a closing offset of 10 points shuts the valve (a 1-point change), and only an opening
    offset bleeds.
    """
    index = {"VSV": 1, "VBV": 2}
    if actuator not in index:
        raise EngineEvaluationError(f"actuator must be one of {list(index)}, not {actuator!r}")
    cond = np.atleast_2d(np.asarray(conditions, float))
    env = cond[:, [0, 1, 3]]
    h = np.broadcast_to(np.zeros(N_HEALTH) if health is None else np.asarray(health, float),
                        (cond.shape[0], N_HEALTH)).copy()
    base = steady_state(env, power=cond[:, 2], health=h)
    column = HEALTH_NAMES.index(f"{actuator.lower()}_bias")
    # The position before the fault (the bias the engine already has included), moved by
    # the offset within the stops, as a percent of the command.
    command = base.u[:, index[actuator]]
    before = command * (1.0 + h[:, column] / 100.0)
    after = np.clip(before + offset, 0.0, 100.0)
    hit_h = h.copy()
    hit_h[:, column] = 100.0 * (after / command - 1.0)
    hit = steady_state(env, power=cond[:, 2], health=hit_h)
    return np.linalg.norm((hit.sensors - base.sensors) / engine_noise_std(), axis=1)


def chance_ceiling(event_sigmas: np.ndarray, no_signature: float = NO_SIGNATURE_SIGMAS) -> float:
    """The most percent correct (mean of the confusion diagonal) the faults' evidence allows
    when each fault's event signature (noise sigmas, root sum of squares over its records) is
    ``event_sigmas`` [n_f]: a fault below ``no_signature`` shows the data nothing, so a fit
    that names faults on their signature alone draws among the n_f hypotheses (100 / n_f
    percent); every other fault is counted perfect. On the built-in engine the VBV bias (0.04
    sigma over 20 take-off and cruise records) caps the eight faults of seed 002 at
    (7 x 100 + 12.5) / 8 = 89.1 %. With the magnitudes held to the library's range a fault of
    no signature is named by elimination, which this bound does not cover (the module
    docstring); ``EngineEvaluation.percent_on_evidence`` stays under it."""
    sig = np.asarray(event_sigmas, float)
    n = sig.size
    return float(np.mean(np.where(sig >= no_signature, 100.0, 100.0 / n)))


@dataclass(frozen=True)
class EngineDesign:
    """A design as evaluated here: sensors (names of SENSOR_NAMES), V* [m, 13] over the
    engine's 13 health parameters, how fuel flow is used, which fault signatures and the
    magnitudes a fault's fit is held to (times the library's nominal shift: the product's
    ``shift_detector.MAGNITUDE_RANGE``; None, the free fit of seed 002 eq. 21)."""

    name: str
    sensors: tuple[str, ...]
    vstar: np.ndarray
    wf: str = "input"
    signatures: str = "linear"
    magnitudes: tuple[float, float] | None = MAGNITUDE_RANGE

    def __post_init__(self) -> None:
        if self.wf not in WF_MODES or self.signatures not in SIGNATURES:
            raise EngineEvaluationError(f"wf in {WF_MODES}, signatures in {SIGNATURES}")
        unknown = [s for s in self.sensors if s not in SENSOR_NAMES]
        if unknown:
            raise EngineEvaluationError(f"unknown sensors {unknown}; known {SENSOR_NAMES}")
        if np.asarray(self.vstar).shape[-1] != N_HEALTH:
            raise EngineEvaluationError(f"V* must have {N_HEALTH} columns")


def subset_vstar(names: Sequence[str]) -> np.ndarray:
    """V* of the subset method: one tuner per named health parameter [m, 13]."""
    return np.eye(N_HEALTH)[[HEALTH_NAMES.index(n) for n in names]]


@dataclass(frozen=True)
class EngineEvaluation:
    """A design's figures on the nonlinear engine.

    faults       : n_f names; confusion : (n_f, n_f) percent, rows true, columns isolated
    wssr         : (E, n_f) WSSR per engine and hypothesis; dof : (E,) sensor values fitted
                   minus one (the chi-squared degrees of freedom of the right hypothesis)
    magnitude    : (E, n_f) fitted f_i; true_fault, isolated : (E,)
    health_rms   : (13,) RMS of V*^+ q_0 - h over the engines' baselines (percent)
    coverage     : (13,) fraction of |V*^+ q_0 - h| <= 1.96 sigma_i (sigma from the fit's
                   noise covariance plus the spread the tuners cannot represent)
    explained    : (E,) the part of the change the isolated fault explains, c - WSSR (the
                   product names a fault only when it reaches
                   ``shift_detector.EVIDENCE_THRESHOLD``)
    """

    design: str
    faults: tuple[str, ...]
    confusion: np.ndarray
    wssr: np.ndarray
    dof: np.ndarray
    magnitude: np.ndarray
    true_fault: np.ndarray
    isolated: np.ndarray
    health_rms: np.ndarray
    coverage: np.ndarray
    explained: np.ndarray

    @property
    def percent_on_evidence(self) -> float:
        """Percent correct counting only the isolations whose fault explains at least
        ``shift_detector.EVIDENCE_THRESHOLD`` of the change (mean over the faults): a fault
        named by elimination (no signature, no change) does not count."""
        ok = (self.isolated == self.true_fault) & (self.explained >= EVIDENCE_THRESHOLD)
        return float(np.mean([100.0 * np.mean(ok[self.true_fault == i])
                              for i in range(len(self.faults))
                              if np.any(self.true_fault == i)]))

    @property
    def percent_correct(self) -> float:
        return isolation.correct_rate(self.confusion)

    def to_dict(self) -> dict[str, object]:
        return {
            "design": self.design,
            "faults": list(self.faults),
            "confusion_percent": np.round(self.confusion, 2).tolist(),
            "percent_correct": self.percent_correct,
            "health": {"names": list(HEALTH_NAMES), "rms": self.health_rms.tolist(),
                       "coverage_95": self.coverage.tolist()},
            "n_engines": int(len(self.true_fault)),
        }


def _gains(schedule: EngineSchedule, rec: EngineRecords, wf: str) -> tuple[np.ndarray, ...]:
    """Per record: dy [E, K, 12] (percent), G [E, K, 12, 13] (health and bias columns), noise
    [E, K, 12] percent. ``wf="input"``: dy - G_u du (the product); ``"sensor"``: closed-loop
    gains at fixed power, G_cl = G_y - G_u[:, Wf] G_y[Nf] / G_u[Nf, Wf], and VSV/VBV still
    measured inputs."""
    E, K = rec.fault.shape[0], rec.conditions.shape[1]
    cond = rec.conditions.reshape(E * K, 4)
    Gy = schedule.interpolate("Gy", cond)  # [EK, 12, 13]
    Gu = schedule.interpolate("Guy", cond)  # [EK, 12, 3]
    y = rec.y.reshape(E * K, 12)
    yt = rec.y_trim.reshape(E * K, 12)
    du = 100.0 * (rec.u.reshape(E * K, 3) - rec.u_trim.reshape(E * K, 3)) / rec.u_trim.reshape(
        E * K, 3).clip(1e-9)
    du = np.where(np.abs(rec.u_trim.reshape(E * K, 3)) > 1e-9, du, 0.0)
    dy = 100.0 * (y - yt) / yt
    if wf == "input":
        dy = dy - np.einsum("kij,kj->ki", Gu, du)
        G = Gy
    else:
        dy = dy - np.einsum("kij,kj->ki", Gu[:, :, 1:], du[:, 1:])
        # the controller holds corrected fan speed: the fuel-flow command closes dNf = 0
        per_h = -Gy[:, NF, :] / Gu[:, NF, 0:1]  # [EK, 13] du_Wf per unit health
        G = Gy + Gu[:, :, 0:1] * per_h[:, None, :]
        G[:, WF, :] = per_h + Gy[:, WF, :]
    noise = np.sqrt(rec.noise_pct.reshape(E * K, 12) ** 2 + MODEL_ERROR**2)
    return dy.reshape(E, K, 12), G.reshape(E, K, 12, N_HEALTH), noise.reshape(E, K, 12)


def _secant_signatures(
    rec: EngineRecords, schedule: EngineSchedule, h0: np.ndarray, S: np.ndarray, wf: str
) -> np.ndarray:
    """Nonlinear fault signatures at each post-fault record [E, n_after, 12, n_f], in the
    deviation form of ``_gains``: the engine's change from h0 to h0 + s_i at the record's
    condition and power setting (closed loop: the fuel-flow command moves, corrected fan
    speed holds), percent of the nominal trim, less the measured inputs' change through G_u
    (VSV and VBV commands; the fuel-flow command too when ``wf="input"``)."""
    E, K = rec.fault.shape[0], rec.conditions.shape[1]
    nb = rec.n_before
    cond = rec.conditions[:, nb:, :].reshape(-1, 4)
    env = cond[:, [0, 1, 3]]
    Gu = schedule.interpolate("Guy", cond)  # [EKa, 12, 3]
    inputs = slice(0, 3) if wf == "input" else slice(1, 3)
    base_h = np.repeat(h0[:, None, :], K - nb, axis=1).reshape(-1, N_HEALTH)
    base = steady_state(env, power=cond[:, 2], health=base_h)
    yt = rec.y_trim[:, nb:, :].reshape(-1, 12)
    ut = rec.u_trim[:, nb:, :].reshape(-1, 3)
    out = np.empty((E, K - nb, 12, S.shape[1]))
    for i in range(S.shape[1]):
        hit = steady_state(env, power=cond[:, 2], health=base_h + S[:, i])
        d = 100.0 * (hit.sensors - base.sensors) / yt
        du = np.where(np.abs(ut) > 1e-9, 100.0 * (hit.u - base.u) / np.where(
            np.abs(ut) > 1e-9, ut, 1.0), 0.0)
        du[:, 0] = d[:, WF]  # the fuel-flow command as its sensor measures it
        d = d - np.einsum("kij,kj->ki", Gu[:, :, inputs], du[:, inputs])
        out[:, :, :, i] = d.reshape(E, K - nb, 12)
    return out


def evaluate_design(
    design: EngineDesign, rec: EngineRecords, schedule: EngineSchedule,
    Ph: np.ndarray | None = None,
) -> EngineEvaluation:
    """Score one design on simulated records (see the module docstring).

    Ph : (13, 13) fleet health covariance the coverage's tuner-approximation term uses
    (default: the records' own baseline spread).
    """
    sensors = np.array([SENSOR_NAMES.index(s) for s in design.sensors])
    vstar = np.asarray(design.vstar, float)
    Vp = np.linalg.solve(vstar @ vstar.T, vstar).T  # V*^+ (seed 002 eq. 5), [13, m]
    dy, G, noise = _gains(schedule, rec, design.wf)
    dy, G, noise = dy[:, :, sensors], G[:, :, sensors, :], noise[:, :, sensors]
    nb = rec.n_before
    w = 1.0 / noise**2  # [E, K, ny]
    # baseline tuners: weighted least squares over the records before the fault
    Hd = G[:, :nb] @ Vp  # [E, nb, ny, m]
    A = np.einsum("ekim,eki,ekin->emn", Hd, w[:, :nb], Hd)
    b = np.einsum("ekim,eki,eki->em", Hd, w[:, :nb], dy[:, :nb])
    q0 = np.linalg.solve(A, b[..., None])[..., 0]  # [E, m]
    h0 = q0 @ Vp.T  # [E, 13]
    S = isolation.signature_matrix(rec.faults, HEALTH_NAMES)
    if design.signatures == "secant":
        g = _secant_signatures(rec, schedule, h0, S, design.wf)[:, :, sensors, :]
    else:
        g = G[:, nb:] @ S  # [E, Ka, ny, n_f]
    r = dy[:, nb:] - np.einsum("ekih,eh->eki", G[:, nb:], h0)
    wa = w[:, nb:]
    a = np.einsum("eki,ekif,ekif->ef", wa, g, g)
    bb = np.einsum("eki,ekif,eki->ef", wa, g, r)
    c = np.einsum("eki,eki,eki->e", wa, r, r)
    if design.magnitudes is None:
        f = bb / a
        wssr = np.maximum(c[:, None] - bb * f, 0.0)
    else:
        wssr, f = isolation.bounded_fit(a, bb, c, design.magnitudes)
    isolated = np.argmin(wssr, axis=1)
    conf = isolation.confusion_percent(rec.fault, isolated, len(rec.faults))
    # health figures at the baseline
    h_true = rec.health[:, 0, :]
    err = h0 - h_true
    rms = np.sqrt(np.mean(err**2, axis=0))
    Pq = np.linalg.inv(A)  # [E, m, m]
    P_noise = np.einsum("hm,emn,gn->ehg", Vp, Pq, Vp)
    Ph_ = np.cov(h_true.T) if Ph is None else np.asarray(Ph, float)
    # the part of h the tuners cannot represent: h_hat = Vp (Hd' W Hd)^-1 Hd' W G h
    Tm = np.einsum("emn,ekin,eki,ekih->emh", Pq, Hd, w[:, :nb], G[:, :nb])  # q per unit h
    Bm = np.einsum("hm,emg->ehg", Vp, Tm) - np.eye(N_HEALTH)
    P_bias = np.einsum("ehg,gk,elk->ehl", Bm, Ph_, Bm)
    sigma = np.sqrt(np.diagonal(P_noise + P_bias, axis1=1, axis2=2))
    coverage = np.mean(np.abs(err) <= 1.96 * sigma, axis=0)
    dof = np.full(len(rec.fault), (rec.conditions.shape[1] - nb) * len(sensors) - 1)
    explained = c - wssr[np.arange(len(isolated)), isolated]
    return EngineEvaluation(design.name, rec.fault_names, conf, wssr, dof, f, rec.fault,
                            isolated, rms, coverage, explained)


def information_floors(
    schedule: EngineSchedule,
    sensors: Sequence[str],
    records: int = FLOOR_RECORDS,
    phases: Sequence[str] = DEFAULT_PHASES,
    spread: FleetSpread = FleetSpread(),
) -> np.ndarray:
    """The least 1-sigma [13] (``HEALTH_NAMES``, percent) with which ``sensors`` can know each
    health parameter and actuator bias of an engine from ``records`` snapshots of each of
    ``phases`` of the seed 001 flight (``theory.information_floor``): the schedule's linear
    model at each phase's condition, the engine's sensor noise in percent of the sensor's trim
    there, fuel flow held as an input as the pipeline holds it, and the fleet's ``spread`` as
    the prior (``FleetSpread.covariance``, ``simulate_records``' engines by default). What no
    design on these sensors can beat on those engines' linear models, however it is tuned; a
    parameter whose floor stays near its prior is one whose level the sensors do not see."""
    points = {p.phase: p.condition for p in snapshot_points(flight_profile())}
    unknown = [p for p in phases if p not in points]
    if unknown:
        raise EngineEvaluationError(f"phases {unknown} have no snapshot of the seed 001 flight")
    rows = [SENSOR_NAMES.index(s) for s in sensors if s != "Wf"]
    absolute = engine_noise_std()[rows]
    gains, noise = [], []
    for phase in phases:
        c = points[phase]
        model = schedule.model_at(float(c.alt_ft[0]), float(c.mach[0]), float(c.power_pct[0]),
                                  float(c.dtamb_k[0]))
        trims = np.array([model.trim[SENSOR_NAMES[r]] for r in rows])
        gains.append(model.steady_state_gains()[0][rows])
        noise.append(100.0 * absolute / np.abs(trims))
    return information_floor(gains, noise, spread.covariance(), records)
