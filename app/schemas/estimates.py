"""Response and request models of trends, fleet status and events.

Trends are columnar (one array per signal sharing ``time`` and ``seq``), the shape plotly draws
directly: a series' ``value`` with ``value +- sigma`` as its band, and on a decimated trend its
bucket ``min``/``max`` envelope.
"""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import AwareDatetime, BaseModel, ConfigDict, Field

EventKind = Literal["shift", "isolated_fault", "wear"]
EventStatus = Literal["open", "acknowledged", "closed"]
EventActionKind = Literal["assigned", "unassigned", "acknowledged", "commented", "closed"]
# A list filter: "active" is every event not closed (open or acknowledged), the events that
# the fleet page counts.
EventStatusFilter = Literal["open", "acknowledged", "closed", "active"]


class TrendSeries(BaseModel):
    name: str
    unit: str
    value: list[float | None]
    sigma: list[float | None] | None = Field(None, description="1-sigma of the estimate")
    min: list[float | None] | None = Field(None, description="bucket minimum (decimated)")
    max: list[float | None] | None = Field(None, description="bucket maximum (decimated)")


class LimitLine(BaseModel):
    """A level of the engine type's limits drawn on a series of the performance group."""

    series: str
    level: Literal["amber", "red"]
    value: float
    unit: str


class TrendGroup(BaseModel):
    key: Literal["tuners", "health", "aux", "residuals", "wssr", "performance"]
    label: str
    series: list[TrendSeries]
    # The health group only (None elsewhere).
    view: Literal["level", "change"] | None = Field(
        None, description="health: levels, or the change since the engine's baseline"
    )
    uncertainty: Literal["calibrated", "uncalibrated", "recalibrate"] | None = Field(
        None,
        description=(
            "What the sigma is. health: calibrated: values are the calibrated level or change "
            "(the estimate corrected by the design's calibration on the simulated nonlinear "
            "engine) and sigma is the honest one (bias, filter and the design's calibrated "
            "model error); uncalibrated: the filter's estimate and its own sigma (no "
            "calibration stored with the design). tuners, aux, performance: calibrated: every "
            "sigma is the one calibrated against the simulator; uncalibrated: the filter's own "
            "(the measured figures have none); recalibrate: the design was calibrated before "
            "these were, so their sigma is the filter's own (the measured figures have none) "
            "until it is calibrated again"
        ),
    )
    unobservable: list[str] | None = Field(
        None, description=("health and tuners groups: the health parameters, or tuners, the "
                           "design cannot estimate: their values are null")
    )
    baselines: list[datetime] | None = Field(
        None, description="change view: times of the baseline records the changes start from"
    )
    limits: list[LimitLine] | None = Field(None, description="limit lines (performance group)")
    calibrated_series: list[str] | None = Field(
        None,
        description=(
            "aux and performance groups: the series whose values are calibrated (estimated "
            "from an aux output that the design's calibration on the simulated nonlinear "
            "engine corrects on the health estimates: thrust, stall margins, T40, bypass "
            "ratio); the others are as estimated or measured. tuners group: the tuners shown "
            "as V* times the calibrated level (the health group's, seen along the design's "
            "tuner directions)"
        ),
    )


class InstallationMarker(BaseModel):
    aircraft_id: int
    tail: str
    position: int
    installed_at: datetime
    removed_at: datetime | None


class MaintenanceMarker(BaseModel):
    id: int
    kind: str
    performed_at: datetime
    notes: str


class EventMarker(BaseModel):
    id: int
    detected_at: datetime
    kind: EventKind
    fault: str | None
    status: EventStatus
    seq: int


class EngineTrend(BaseModel):
    engine_id: int
    esn: str
    engine_type: str
    design_id: int | None
    design_name: str | None
    start: datetime | None
    end: datetime | None
    n_records: int = Field(description="estimates in the time range")
    n_points: int = Field(description="points returned (buckets when decimated)")
    decimated: bool
    time: list[str] = Field(description="ISO 8601 UTC; bucket mean time when decimated")
    seq: list[float] = Field(description="record number (cycles axis); bucket mean")
    phase: list[str | None]
    recording: list[int | None] = Field(
        default_factory=list,
        description="the stream recording whose steady window the record summarises "
        "(null: a snapshot, or a bucket of records of several sources)",
    )
    groups: list[TrendGroup]
    performance_note: str | None = Field(
        None, description="why the trend has no performance group (engineering units), when "
        "it has estimates but no such group: the design's engine is not the built-in one")
    installations: list[InstallationMarker]
    maintenance: list[MaintenanceMarker]
    events: list[EventMarker]


class TrendSegment(BaseModel):
    position: int
    installed_at: datetime
    removed_at: datetime | None
    trend: EngineTrend


class AircraftTrend(BaseModel):
    aircraft_id: int
    tail: str
    start: datetime | None
    end: datetime | None
    segments: list[TrendSegment]


class HealthSummary(BaseModel):
    """The latest estimate of an engine in brief."""

    recorded_at: datetime
    seq: int
    worst_health: str | None = Field(
        description="health parameter with the largest level, of those the design observes")
    worst_health_value: float | None = Field(
        description="its level, percent: the calibrated level where the design has a "
                    "calibration (as the engine trend's health group shows it), else h_hat")
    worst_health_sigma: float | None
    thrust_deficit: float | None = Field(description="-z_hat of thrust, percent")
    health: dict[str, float | None] = Field(
        description="each health parameter's level (as worst_health_value); null where the "
                    "design's calibration finds it unobservable")
    aux: dict[str, float]


class OpenEventBrief(BaseModel):
    id: int
    detected_at: datetime
    kind: EventKind
    fault: str | None
    magnitude: float | None
    status: EventStatus


class LimitCheck(BaseModel):
    limit: str
    value: float
    sigma: float | None = Field(
        default=None,
        description="1-sigma of the value, in its unit, where the design's calibration gives "
        "one (the worst health parameter's, the thrust deficit's, the EGT margin's)")
    unit: str
    amber: float
    red: float
    level: Literal["normal", "amber", "red"]
    reason: str


class EngineStatus(BaseModel):
    engine_id: int
    esn: str
    engine_type: str
    aircraft_id: int | None
    tail: str | None
    position: int | None
    design_id: int | None
    last_data: datetime | None
    n_records: int
    state: Literal["no_data", "normal", "watch", "alert"] = Field(
        description="red severity is alert, amber watch"
    )
    severity: Literal["normal", "amber", "red"] | None = Field(
        None, description="worst of the type's limit checks and the active events"
    )
    severity_score: float | None = Field(
        None, description="largest (value - amber) / (red - amber): 0 at amber, 1 at red"
    )
    reason: str | None = Field(None, description="why the severity, worst first")
    checks: list[LimitCheck] = Field(default_factory=list)
    rank: int | None = Field(None, description="1 = most severe")
    health: HealthSummary | None
    open_events: int
    latest_event: OpenEventBrief | None


EngineState = Literal["alert", "watch", "normal", "no_data"]


class FleetStatus(BaseModel):
    operator: str
    n_engines: int = Field(description="every engine of the operator")
    n_open_events: int
    states: dict[EngineState, int] = Field(description="engines per state, the whole fleet")
    total: int = Field(description="engines that match the state asked for (all without one)")
    limit: int
    offset: int
    engines: list[EngineStatus] = Field(
        description="the page: ranked by severity (red, amber, normal, no data), worst first")


class DeteriorationSeries(BaseModel):
    name: str
    unit: str
    mean: list[float | None]
    sigma: list[float | None] = Field(description="spread over engines (standard deviation)")


class DeteriorationSlope(BaseModel):
    name: str
    slope: float | None = Field(description="fleet-average slope; null: unobservable")
    sigma: float | None = Field(
        description="its 1-sigma, in the same unit: the pieces' noise, the error common to a "
        "fleet and the calibrated gain's own standard error; null: uncalibrated, recalibrate "
        "or unobservable")


class DeteriorationSlopes(BaseModel):
    engine_type: str
    design_id: int
    unit: Literal["%/year"] = Field(description="unit of each slope and its sigma")
    uncertainty: Literal["calibrated", "uncalibrated", "recalibrate"] = Field(
        description="calibrated: slopes corrected by the design's calibrated gain, with their "
        "1-sigma; uncalibrated: the design has no calibration (plain mean, no sigma); "
        "recalibrate: the calibration was stored before the slope's 1-sigma held the gain's "
        "standard error: corrected slopes without a sigma until the design's calibrate_design "
        "job runs again")
    pieces: int = Field(description="engine trends (between baseline resets) the slopes use")
    engines: int
    unobservable: list[str] = Field(
        description="parameters whose slope the design cannot observe (slope null)")
    health: list[DeteriorationSlope]


class DeteriorationGroup(BaseModel):
    engine_type: str
    design_id: int
    time: list[str] = Field(description="bucket start, ISO 8601 UTC")
    n_engines: list[int]
    health: list[DeteriorationSeries]
    aux: list[DeteriorationSeries]
    unobservable: list[str] = Field(
        default_factory=list,
        description="health parameters the design's calibration finds unobservable (their "
        "means and spreads null)",
    )
    level: Literal["calibrated", "estimated"] = Field(
        default="estimated",
        description="calibrated: the health means are the calibrated level the engine pages "
        "show (the design's calibration applied to each engine's period mean); estimated: the "
        "design has no calibration, the estimates as stored")


class FleetDeterioration(BaseModel):
    bucket: Literal["week", "month"]
    groups: list[DeteriorationGroup]


class FleetDeteriorationSlopes(BaseModel):
    groups: list[DeteriorationSlopes] = Field(
        description="per active design: the fleet-average deterioration slope of each health "
        "parameter (weekly means of each engine between baseline resets, inverse-variance "
        "mean, the design's calibrated gain) with its 1-sigma")


class CommentOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    author: str
    author_key_id: int | None
    body: str
    created_at: datetime


class HistoryEntryOut(BaseModel):
    """One step of an alert's handling."""

    model_config = ConfigDict(from_attributes=True)

    id: int
    action: EventActionKind
    actor: str = Field(description="name of the API key that acted")
    actor_key_id: int | None
    assignee: str | None = Field(description="name of the key assigned (assigned only)")
    assignee_key_id: int | None
    reason: str | None = Field(description="reason to acknowledge or close, or the comment")
    created_at: datetime


class Assignee(BaseModel):
    """A person an alert can be assigned to: an active analyst or admin key of the operator."""

    key_id: int
    name: str
    role: str


class ConfusionRow(BaseModel):
    true_fault: str
    faults: list[str]
    percent: list[float] = Field(description="how often the design isolates each fault, %")


class EventTempering(BaseModel):
    """How the design's nonlinear-engine run tempered its events' confidence."""

    wssr_scale: float = Field(description="s of p_i ∝ exp(-WSSR_i / 2 s) C_ij^beta")
    confusion_power: float = Field(description="beta: the weight of the confusion column")
    log_score: float = Field(description="mean log posterior of the true fault on the events "
                             "it was fitted on (0 is perfect)")
    default_score: float = Field(description="the same untempered (the isolation's margin, "
                                 "beta = 1)")
    events: int = Field(description="events of known fault it was fitted on")


class EventConfidence(BaseModel):
    """Posterior over the fault hypotheses (seed 002 eq. 21-23 likelihoods times the design's
    measured confusion; estimation/posterior.py)."""

    source: Literal["nonlinear_engine", "linear_monte_carlo", "wssr_only"] = Field(
        description="which confusion the posterior uses"
    )
    source_note: str
    evaluation_job_id: int | None = Field(description="the evaluation the confusion is from")
    faults: list[str]
    posterior: list[float] = Field(description="probability of each fault hypothesis, sums to 1")
    wssr_posterior: list[float] = Field(description="the same from the WSSR alone")
    isolated: str = Field(description="the hypothesis with the smallest WSSR")
    probability: float = Field(description="posterior of the isolated fault")
    label: str = Field(description='fewest faults holding credible_mass, e.g. "HPT or Wf"')
    credible_mass: float
    fit_probability: float = Field(
        description="chi-squared tail probability of the smallest WSSR: small when no library "
        "fault explains the event"
    )
    fit_level: float = Field(
        default=0.001,
        description="the tail probability below which no library fault explains the event (the "
        "level the isolation accepts a fault at)",
    )
    ambiguity_group: list[str] = Field(
        description="faults the design confuses with the isolated one (its confusion)"
    )
    confusion_row: ConfusionRow | None = Field(
        description="the design's confusion row of the isolated fault"
    )
    not_visible: list[str] = Field(
        description="library faults with no visible signature on the built-in engine"
    )
    fits_better: list[str] = Field(
        default_factory=list,
        description="of left_out, the faults whose WSSR is under half the isolated fault's: "
        "they fit the change clearly better than any hypothesis of this kind of event",
    )
    explained: float | None = Field(
        default=None,
        description="for a wear event, the share of the accumulated change (weighed as its "
        "health change) the isolated fault explains; null for other events",
    )
    left_out: list[str] = Field(
        default_factory=list,
        description="faults of the event's WSSR that are not hypotheses of this kind of event: "
        "for a wear event, actuator biases and faults fitted with a negative magnitude (wear "
        "is attributed among module deteriorations)",
    )
    tempering: EventTempering | None = Field(
        default=None,
        description="the posterior's tempering fitted on the design's nonlinear-engine run "
        "(a sensor-space isolation with that run's confusion); null: untempered",
    )


class EventOut(BaseModel):
    id: int
    engine_id: int
    esn: str
    tail: str | None = Field(description="tail the engine sat on when the event was detected")
    position: int | None
    design_id: int
    seq: int
    detected_at: datetime
    kind: EventKind
    fault: str | None
    magnitude: float | None = Field(description="fitted f, 1.0 = the library's nominal shift")
    statistic: float = Field(description="detector statistic at the alarm")
    wssr: dict[str, float] = Field(description="WSSR of every fault hypothesis")
    wssr_threshold: float | None = Field(description="WSSR below which a fault is accepted")
    tuner_shift: dict[str, float] = Field(description="tuner change against the baseline")
    health_shift: dict[str, float] = Field(description="h_hat change against the baseline, %")
    fault_shift: dict[str, float] = Field(
        description="the isolated fault's health shifts scaled by magnitude, %"
    )
    status: EventStatus
    acknowledged_at: datetime | None
    acknowledged_by: int | None
    closed_at: datetime | None
    closed_by: int | None
    acknowledged_reason: str | None = Field(None, description="why it was acknowledged")
    closed_reason: str | None = Field(None, description="why it was closed")
    assignee: Assignee | None = Field(None, description="the person the alert is assigned to")
    comments: list[CommentOut]
    history: list[HistoryEntryOut] = Field(
        default_factory=list, description="assigned, acknowledged, commented, closed: oldest first"
    )
    confidence: EventConfidence | None = Field(
        None, description="posterior over the fault hypotheses; null without stored WSSR"
    )


class EventPage(BaseModel):
    items: list[EventOut]
    total: int
    limit: int
    offset: int


class CommentIn(BaseModel):
    model_config = ConfigDict(extra="forbid", str_strip_whitespace=True)

    body: str = Field(min_length=1, max_length=10_000)


class EventAction(BaseModel):
    """The reason, required, to acknowledge or close an event."""

    model_config = ConfigDict(extra="forbid", str_strip_whitespace=True)

    reason: str = Field(min_length=1, max_length=10_000)


class AssignIn(BaseModel):
    """Assign an event to an analyst or admin key of the operator; null takes the assignment
    away."""

    model_config = ConfigDict(extra="forbid")

    assignee_key_id: int | None


class EngineCoverageOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    engine_id: int
    esn: str
    aircraft_id: int | None
    tail: str | None = Field(description="the tail it is installed on now; null if none")
    position: int | None
    installed_at: AwareDatetime | None
    last_data: AwareDatetime | None = Field(description="its newest record (recorded_at)")
    overdue: bool = Field(
        description="installed, and its last record (or installation) older than overdue_days"
    )


class TailCoverageOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    aircraft_id: int
    tail: str
    last_data: AwareDatetime | None = Field(description="its newest record, any position")
    engines_installed: int
    engines_overdue: int


class DataCoverage(BaseModel):
    now: AwareDatetime = Field(description="the service's time the ages are counted to")
    overdue_days: float = Field(description="an installed engine without data longer is overdue")
    n_overdue: int
    tails: list[TailCoverageOut] = Field(description="by tail number")
    engines: list[EngineCoverageOut] = Field(
        description="overdue first, then by last data, oldest first")
