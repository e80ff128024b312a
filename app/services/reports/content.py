"""What a report says, read through the services the pages use (nothing recomputed).

An engine report is the engine's row of the fleet status (identity, state, severity and the
limit checks), its trend as the engine page reads it (health as the change since the baseline,
the performance group in engineering units, every record), its active events with their
isolation (``events.service``) and its maintenance actions (the trend's markers). A fleet
report is the whole fleet status ranked by severity, the fleet-average deterioration per month
and the active events (alerts).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from sqlalchemy.orm import Session

from app.errors import NotFound
from app.services.events import service as events
from app.services.fleet import status
from app.services.trends import service as trends

# The engine page's panels in engineering units: (key, title, y label, series).
PERFORMANCE_PANELS = (
    ("egt_margin", "EGT margin (take-off, ISA+15 K)", "EGT margin", ("egt_margin",)),
    ("degt", "ΔEGT against the baseline (corrected, smoothed)", "ΔEGT", ("dEGT",)),
    ("thrust_deficit", "Thrust deficit against the nominal engine", "Thrust deficit",
     ("thrust_deficit",)),
    ("stall_margins", "Stall margins", "Stall margin", ("SM_fan", "SM_LPC", "SM_HPC")),
    ("stall_margin_change", "Stall-margin change from the baseline", "Change",
     ("SM_fan_change", "SM_LPC_change", "SM_HPC_change")),
)
# The figures of the engine summary, in this order (those the design's engine has).
ENGINEERING = ("dEGT", "egt_margin", "thrust_deficit", "Fn_rated", "SM_fan", "SM_LPC",
               "SM_HPC", "SM_fan_change", "SM_LPC_change", "SM_HPC_change")
UNIT_LABELS = {"degC": "°C", "pts": "margin points"}
# Alerts listed per page read from the events service.
EVENT_PAGE = 1000


def unit_label(unit: str) -> str:
    return UNIT_LABELS.get(unit, unit)


@dataclass(frozen=True)
class Series:
    """One plotted quantity: values (None: no value) and its 1-sigma where the API gives one."""

    name: str
    unit: str
    value: list[float | None]
    sigma: list[float | None] | None


@dataclass(frozen=True)
class LimitLine:
    series: str
    level: str  # amber, red
    value: float


@dataclass(frozen=True)
class Panel:
    key: str
    title: str
    ylabel: str
    series: tuple[Series, ...]
    limits: tuple[LimitLine, ...] = ()


@dataclass(frozen=True)
class Figure:
    """A current figure: the value of the engine's latest record and its 1-sigma."""

    group: str  # "health change" or "engineering"
    name: str
    unit: str
    value: float | None
    sigma: float | None


@dataclass(frozen=True)
class CheckLine:
    limit: str
    value: float
    unit: str
    amber: float
    red: float
    level: str


@dataclass(frozen=True)
class EventLine:
    """An active event with its isolation: the fault, its fitted magnitude and the
    posterior probability of the isolated fault with its ambiguity group."""

    id: int
    esn: str
    tail: str | None
    detected_at: datetime
    kind: str
    status: str
    fault: str | None
    magnitude: float | None
    isolated: str | None
    probability: float | None
    ambiguity_group: tuple[str, ...]
    assignee: str | None


@dataclass(frozen=True)
class MaintenanceLine:
    performed_at: datetime
    kind: str
    notes: str | None


@dataclass(frozen=True)
class EngineReport:
    generated_at: datetime
    operator: str
    engine_id: int
    esn: str
    engine_type: str
    tail: str | None
    position: int | None
    design_name: str | None
    state: str
    severity: str | None
    reason: str | None
    checks: tuple[CheckLine, ...]
    n_records: int
    last_data: datetime | None
    time: list[str]
    panels: tuple[Panel, ...]
    figures: tuple[Figure, ...]
    events: tuple[EventLine, ...]
    maintenance: tuple[MaintenanceLine, ...]
    performance_note: str | None = None  # why there are no engineering figures (the trend's)


@dataclass(frozen=True)
class FleetLine:
    rank: int
    engine_id: int
    esn: str
    engine_type: str
    tail: str | None
    position: int | None
    state: str
    severity: str | None
    reason: str | None
    worst_health: str | None
    worst_health_value: float | None
    worst_health_sigma: float | None
    thrust_deficit: float | None
    last_data: datetime | None
    n_records: int
    open_events: int


@dataclass(frozen=True)
class DeteriorationGroup:
    """The fleet-average deterioration of one engine type's active design, per month."""

    engine_type: str
    time: list[str]
    n_engines: list[int]
    health: tuple[Series, ...]
    aux: tuple[Series, ...]


@dataclass(frozen=True)
class FleetReport:
    generated_at: datetime
    operator: str
    n_engines: int
    n_open_events: int
    states: dict[str, int]
    engines: tuple[FleetLine, ...]
    bucket: str
    deterioration: tuple[DeteriorationGroup, ...]
    alerts: tuple[EventLine, ...]


def _time(value: Any) -> datetime | None:
    if value is None or isinstance(value, datetime):
        return value
    return datetime.fromisoformat(str(value).replace("Z", "+00:00"))


def _series(item: dict[str, Any]) -> Series:
    return Series(item["name"], item["unit"], list(item["value"]),
                  None if item.get("sigma") is None else list(item["sigma"]))


def _last(values: list[float | None] | None) -> float | None:
    return None if not values else values[-1]


def _event_line(item: dict[str, Any]) -> EventLine:
    confidence = item.get("confidence") or {}
    assignee = item.get("assignee")
    return EventLine(
        id=item["id"], esn=item["esn"], tail=item["tail"], detected_at=item["detected_at"],
        kind=item["kind"], status=item["status"], fault=item["fault"],
        magnitude=item["magnitude"], isolated=confidence.get("isolated"),
        probability=confidence.get("probability"),
        ambiguity_group=tuple(confidence.get("ambiguity_group") or ()),
        assignee=None if assignee is None else assignee["name"],
    )


def active_events(
    session: Session, operator_id: int, engine_id: int | None = None
) -> tuple[EventLine, ...]:
    """Every active (open or acknowledged) event, newest first, as the events page lists them."""
    out: list[EventLine] = []
    while True:
        page = events.list_events(session, operator_id, status=events.ACTIVE,
                                  engine_id=engine_id, limit=EVENT_PAGE, offset=len(out))
        out += [_event_line(item) for item in page["items"]]
        if not page["items"] or len(out) >= page["total"]:
            return tuple(out)


def _status_row(session: Session, operator_id: int, engine_id: int) -> tuple[str, dict[str, Any]]:
    fleet = status.fleet_status(session, operator_id)
    for row in fleet["engines"]:
        if row["engine_id"] == engine_id:
            return fleet["operator"], row
    raise NotFound(f"engine {engine_id} not found")


def engine_report(session: Session, operator_id: int, engine_id: int) -> EngineReport:
    """The engine's report (another operator's engine is not found)."""
    # The trend first: it checks the engine belongs to the operator (404 otherwise).
    trend = trends.engine_trend(session, operator_id, engine_id, health="change", max_points=0)
    operator, row = _status_row(session, operator_id, engine_id)
    groups = {g["key"]: g for g in trend["groups"]}
    panels: list[Panel] = []
    figures: list[Figure] = []
    health = groups.get("health")
    if health is not None:
        hidden = set(health.get("unobservable") or ())
        shown = tuple(_series(s) for s in health["series"] if s["name"] not in hidden)
        panels.append(Panel("health", "Health parameters: change since baseline",
                            "Health change", shown))
        figures += [Figure("health change", s.name, s.unit, _last(s.value), _last(s.sigma))
                    for s in shown]
    performance = groups.get("performance")
    if performance is not None:
        by_name = {s["name"]: _series(s) for s in performance["series"]}
        limits = performance.get("limits") or []
        for key, title, ylabel, names in PERFORMANCE_PANELS:
            chosen = tuple(by_name[n] for n in names if n in by_name)
            if chosen:
                lines = tuple(LimitLine(lim["series"], lim["level"], lim["value"])
                              for lim in limits if lim["series"] in names)
                panels.append(Panel(key, title, ylabel, chosen, lines))
        figures += [Figure("engineering", by_name[n].name, by_name[n].unit,
                           _last(by_name[n].value), _last(by_name[n].sigma))
                    for n in ENGINEERING if n in by_name]
    return EngineReport(
        generated_at=datetime.now(UTC),
        operator=operator,
        engine_id=engine_id,
        esn=trend["esn"],
        engine_type=trend["engine_type"],
        tail=row["tail"],
        position=row["position"],
        design_name=trend["design_name"],
        state=row["state"],
        severity=row["severity"],
        reason=row["reason"],
        checks=tuple(CheckLine(c["limit"], c["value"], c["unit"], c["amber"], c["red"],
                               c["level"]) for c in row["checks"]),
        n_records=trend["n_records"],
        last_data=_time(row["last_data"]),
        time=list(trend["time"]),
        panels=tuple(panels),
        figures=tuple(figures),
        events=active_events(session, operator_id, engine_id),
        maintenance=tuple(MaintenanceLine(m["performed_at"], m["kind"], m["notes"])
                          for m in trend["maintenance"]),
        performance_note=trend.get("performance_note"),
    )


def fleet_report(session: Session, operator_id: int, bucket: str = "month") -> FleetReport:
    """The operator's fleet report."""
    fleet = status.fleet_status(session, operator_id)
    deterioration = status.fleet_deterioration(session, operator_id, bucket)
    lines = []
    for e in fleet["engines"]:
        h = e["health"] or {}
        lines.append(FleetLine(
            rank=e["rank"], engine_id=e["engine_id"], esn=e["esn"], engine_type=e["engine_type"],
            tail=e["tail"], position=e["position"], state=e["state"], severity=e["severity"],
            reason=e["reason"], worst_health=h.get("worst_health"),
            worst_health_value=h.get("worst_health_value"),
            worst_health_sigma=h.get("worst_health_sigma"),
            thrust_deficit=h.get("thrust_deficit"), last_data=_time(e["last_data"]),
            n_records=e["n_records"], open_events=e["open_events"],
        ))
    groups = tuple(
        DeteriorationGroup(
            g["engine_type"], list(g["time"]), list(g["n_engines"]),
            tuple(Series(s["name"], s["unit"], s["mean"], s["sigma"]) for s in g["health"]
                  if s["name"] not in g["unobservable"]),
            tuple(Series(s["name"], s["unit"], s["mean"], s["sigma"]) for s in g["aux"]),
        )
        for g in deterioration["groups"]
    )
    return FleetReport(
        generated_at=datetime.now(UTC),
        operator=fleet["operator"],
        n_engines=fleet["n_engines"],
        n_open_events=fleet["n_open_events"],
        states=dict(fleet["states"]),
        engines=tuple(lines),
        bucket=bucket,
        deterioration=groups,
        alerts=active_events(session, operator_id),
    )


# How figures read in a report: the API's names in engineers' words.
LABELS = {
    "dEGT": "dEGT (corrected, smoothed)",
    "egt_margin": "EGT margin (take-off, ISA+15 K)",
    "thrust_deficit": "Thrust deficit",
    "Fn_rated": "Net thrust, % of rated",
    "SM_fan": "Fan stall margin",
    "SM_LPC": "LPC stall margin",
    "SM_HPC": "HPC stall margin",
    "SM_fan_change": "Fan stall-margin change",
    "SM_LPC_change": "LPC stall-margin change",
    "SM_HPC_change": "HPC stall-margin change",
}
DIGITS = 2


def label(name: str) -> str:
    return LABELS.get(name, name)


def number(value: float | None, digits: int = DIGITS) -> str:
    """A figure as the PDF prints it: ``digits`` decimals, a dash for no value."""
    return "–" if value is None else f"{value:.{digits}f}"


def stamp(value: datetime | str | None) -> str:
    """A time as the PDF prints it: UTC to the minute."""
    when = _time(value)
    return "–" if when is None else when.astimezone(UTC).strftime("%Y-%m-%d %H:%M UTC")
