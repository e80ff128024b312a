"""Cron expressions of job schedules: five fields (minute hour day-of-month month
day-of-week), read in UTC, parsed by croniter."""

from __future__ import annotations

from datetime import UTC, datetime

from croniter import CroniterBadCronError, CroniterBadDateError, croniter

from app.errors import InvalidInput

FIELDS = 5


def check_cron(expression: str, *, now: datetime) -> str:
    """The expression with its fields separated by one space, or a 422 naming ``cron`` when
    it is not five valid fields or never falls due."""
    fields = expression.split()
    reason = None
    if len(fields) != FIELDS:
        reason = (f"a cron expression has {FIELDS} fields (minute hour day-of-month month "
                  f"day-of-week), not {len(fields)}")
    elif not croniter.is_valid(" ".join(fields)):
        reason = f"{expression!r} is not a valid cron expression"
    normalised = " ".join(fields)
    if reason is None:
        try:
            next_cron_time(normalised, now)
        except (CroniterBadDateError, CroniterBadCronError):
            reason = f"{expression!r} never falls due"
    if reason is not None:
        raise InvalidInput(
            f"cron: {reason}", details=[{"column": "cron", "reason": reason}]
        )
    return normalised


def next_cron_time(expression: str, after: datetime) -> datetime:
    """The first time of the expression strictly after ``after``, in UTC."""
    found = croniter(expression, after.astimezone(UTC)).get_next(datetime)
    return found.astimezone(UTC)  # type: ignore[no-any-return]
