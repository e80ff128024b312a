"""An engine's severity: the worst of its limit checks and its active events.

Each limit of the engine type (``EngineType.effective_limits``) is checked against the engine's
latest values: normal, amber past the amber level, red past the red level, in the limit's worse
direction. An active event (open or acknowledged) counts too: an isolated fault red, an
unexplained shift amber. The engine's level is the worst of all; its score, which ranks
engines of one level, is the largest exceedance ``(value - amber) / (red - amber)`` in the
worse direction (0 at amber, 1 at red, negative while short of amber), so a 17.6 % thrust
deficit ranks above a 3 % one.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from app.models.estimates import EVENT_LEVEL

LEVELS = ("normal", "amber", "red")
LEVEL_INDEX = {level: k for k, level in enumerate(LEVELS)}
LABELS = {
    "health_change": "health change",
    "egt_margin": "EGT margin",
    "thrust_deficit": "thrust deficit",
    "rate_of_change": "rate of change",
}
UNIT_TEXT = {"degC": " °C", "%": " %", "%/100 records": " %/100 records"}


@dataclass(frozen=True)
class LimitValue:
    """An engine's value for one limit; ``detail`` names what it is (a health parameter);
    ``sigma`` its 1-sigma where the design's calibration gives one (None: not known)."""

    value: float
    detail: str | None = None
    sigma: float | None = None


@dataclass(frozen=True)
class Check:
    limit: str
    value: float
    unit: str
    amber: float
    red: float
    level: str
    exceedance: float
    reason: str
    sigma: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"limit": self.limit, "value": round(self.value, 3),
                "sigma": None if self.sigma is None else round(self.sigma, 3), "unit": self.unit,
                "amber": self.amber, "red": self.red, "level": self.level,
                "reason": self.reason}


def grade(levels: Mapping[str, Any], value: float) -> tuple[str, float, float]:
    """One value against one limit's levels: (level, the level's bound, exceedance)."""
    amber, red = float(levels["amber"]), float(levels["red"])
    sign = 1.0 if levels["worse"] == "above" else -1.0
    exceedance = sign * (value - amber) / (sign * (red - amber))
    if sign * (value - red) >= 0:
        return "red", red, exceedance
    if sign * (value - amber) >= 0:
        return "amber", amber, exceedance
    return "normal", amber, exceedance


def check(limit: str, levels: Mapping[str, Any], value: LimitValue) -> Check:
    """One limit against one value."""
    unit, worse = levels["unit"], levels["worse"]
    amber, red = float(levels["amber"]), float(levels["red"])
    level, bound, exceedance = grade(levels, value.value)
    u = UNIT_TEXT.get(unit, f" {unit}")
    name = LABELS.get(limit, limit) + (f" ({value.detail})" if value.detail else "")
    if level == "normal":
        relation = "<" if worse == "above" else ">"
        reason = f"{name} {value.value:.1f}{u} {relation} amber {amber:g}{u}"
    else:
        relation = ">" if worse == "above" else "<"
        reason = f"{name} {value.value:.1f}{u} {relation} {level} {bound:g}{u}"
    return Check(limit, value.value, unit, amber, red, level, exceedance, reason, value.sigma)


@dataclass(frozen=True)
class Severity:
    level: str  # normal, amber, red
    score: float  # largest exceedance over the checks (-inf without any)
    reason: str | None  # why the level, worst first
    checks: tuple[Check, ...]


def severity(
    limits: Mapping[str, Any], values: Mapping[str, LimitValue],
    events: Iterable[tuple[int, str, str, str | None]] = (),
) -> Severity:
    """Level, score and reason from the limits and values present, and the active events
    (id, kind, status, fault)."""
    checks = tuple(check(name, limits[name], v) for name, v in values.items() if name in limits)
    level = max((c.level for c in checks), key=LEVELS.index, default="normal")
    reasons = [c for c in sorted(checks, key=lambda c: (-LEVELS.index(c.level), -c.exceedance))
               if c.level != "normal"]
    texts = [c.reason for c in reasons]
    for event_id, kind, status, fault in events:
        event_level = EVENT_LEVEL.get(kind, "amber")
        level = max(level, event_level, key=LEVELS.index)
        what = f"isolated fault {fault}" if kind == "isolated_fault" else "unexplained shift"
        text = f"{status} event #{event_id}: {what}"
        if event_level == "red":
            texts.insert(0, text)
        else:
            texts.append(text)
    score = max((c.exceedance for c in checks), default=float("-inf"))
    return Severity(level, score, "; ".join(texts) if texts else None, checks)


def rank(
    limits: Mapping[str, Any], values: Mapping[str, LimitValue],
    events: Iterable[tuple[int, str, str, str | None]] = (),
) -> tuple[str, float]:
    """The level and score of ``severity`` without its checks' and events' texts (what ranks
    a fleet's engines; the page shows ``severity`` of those it lists)."""
    worst, score = 0, float("-inf")
    for name, v in values.items():
        levels = limits.get(name)
        if levels is not None:
            graded, _bound, exceedance = grade(levels, v.value)
            worst = max(worst, LEVEL_INDEX[graded])
            if exceedance > score:
                score = exceedance
    for _event_id, kind, _status, _fault in events:
        worst = max(worst, LEVEL_INDEX[EVENT_LEVEL.get(kind, "amber")])
    return LEVELS[worst], score
