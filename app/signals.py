"""The signal catalogue: every signal an upload may carry, its quantity, stored unit and bounds.

The names, units and bounds that uploads are validated against and that the snapshot table's
columns are made from (``app.models.ingest``), kept apart from the tables so that parsing,
estimation and the schemas read it without SQLAlchemy.
"""

from __future__ import annotations

from dataclasses import dataclass

PHASES = ("takeoff", "climb", "cruise")
# A stream's sample interval: at most 1 kHz (finer is noise, not engine data, and would
# make a short file millions of samples long), at least one sample a minute.
STREAM_DT_MIN_S = 1e-3
STREAM_DT_MAX_S = 60.0
# Chunks of a live recording: chunk-NNNNNN.parquet files, indexed from 0.
MAX_CHUNK_INDEX = 999_999


@dataclass(frozen=True)
class SignalSpec:
    """A stored signal: upload name, table column, quantity and the unit it is stored in.

    ``percent_reference`` is 100 % in the stored unit (design spool speeds), for ``%`` uploads.
    """

    name: str
    quantity: str
    unit: str
    low: float | None = None
    high: float | None = None
    percent_reference: float | None = None

    @property
    def column(self) -> str:
        return self.name.lower()


# Operating condition: every snapshot and stream sample carries all four.
OPERATING_CONDITION = (
    SignalSpec("alt_ft", "length", "ft", -2000.0, 60000.0),
    SignalSpec("mach", "dimensionless", "1", 0.0, 1.0),
    SignalSpec("dtamb_k", "temperature_difference", "K", -100.0, 100.0),
    SignalSpec("power_pct", "percent", "%", 0.0, 110.0),
)
# Actuators and sensors in the built-in engine's units (C-MAPSS units, estimation/engine
# turbofan.outputs_from_stations); 100 % spool speed is the design point (engine/design.py).
ACTUATORS = (
    SignalSpec("Wf", "mass_flow", "pps", 0.0),
    SignalSpec("VSV", "percent", "%", 0.0, 100.0),
    SignalSpec("VBV", "percent", "%", 0.0, 100.0),
)
SENSORS = (
    SignalSpec("Nf", "rotational_speed", "rpm", 0.0, percent_reference=2388.06),
    SignalSpec("Nc", "rotational_speed", "rpm", 0.0, percent_reference=9055.99),
    SignalSpec("T24", "temperature", "degR", 0.0),
    SignalSpec("P24", "pressure", "psia", 0.0),
    SignalSpec("T30", "temperature", "degR", 0.0),
    SignalSpec("Ps30", "pressure", "psia", 0.0),
    SignalSpec("P30", "pressure", "psia", 0.0),
    SignalSpec("T48", "temperature", "degR", 0.0),
    SignalSpec("P50", "pressure", "psia", 0.0),
    SignalSpec("T50", "temperature", "degR", 0.0),
    SignalSpec("P15", "pressure", "psia", 0.0),
)
# alt_ft, mach, dtamb_k, power_pct: the operating condition as stored
CONDITION_COLUMNS = tuple(s.column for s in OPERATING_CONDITION)
MEASURED = ACTUATORS + SENSORS  # nullable: NULL is a missing value
SIGNALS = OPERATING_CONDITION + MEASURED
# Signals outside the catalogue (an engine type's own names) are stored by name in one JSON
# column of the snapshot table; ``stored_at`` names where a signal is: its column, or
# ``other_signals.NAME``.
OTHER_SIGNALS = "other_signals"
_CATALOGUE_COLUMNS = {s.name: s.column for s in MEASURED}


def stored_at(name: str) -> str:
    """Where a signal's values are stored in the snapshot table: a catalogue signal's column
    (``T30`` -> ``t30``), any other's key in ``other_signals`` (``EGT`` ->
    ``other_signals.EGT``)."""
    column = _CATALOGUE_COLUMNS.get(name)
    return column if column is not None else f"{OTHER_SIGNALS}.{name}"


def other_signal(stored: str) -> str | None:
    """The signal name of an ``other_signals.NAME`` place (``stored_at``), else None."""
    prefix = OTHER_SIGNALS + "."
    return stored[len(prefix):] if stored.startswith(prefix) else None
