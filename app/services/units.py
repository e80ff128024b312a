"""Engineering units per physical quantity and the affine conversions between them.

Every known unit maps to the quantity's SI unit as ``si = scale * value + offset``; a
conversion between two units of one quantity is then again affine, ``y = a * x + b``, so it
applies to whole columns (numpy or pyarrow) at once and keeps nulls null.
Percent of a reference (``%`` of a design spool speed) is linear in the reference's unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

RANKINE_PER_KELVIN = 1.8
PA_PER_PSI = 6894.757293168
KG_PER_LBM = 0.45359237
FT_PER_M = 1.0 / 0.3048


class UnknownUnitError(ValueError):
    """A unit that is not known for the quantity (the message lists the known ones)."""


@dataclass(frozen=True)
class Quantity:
    """A physical quantity: its SI unit and every known unit as (scale, offset) to SI."""

    name: str
    si_unit: str
    units: dict[str, tuple[float, float]]

    def to_si(self, unit: str) -> tuple[float, float]:
        try:
            return self.units[unit]
        except KeyError:
            known = ", ".join(self.units)
            raise UnknownUnitError(
                f"unknown unit {unit!r} for {self.name}; known units: {known}"
            ) from None


_ZERO_C = 273.15
_ZERO_F_IN_R = 459.67

QUANTITIES: dict[str, Quantity] = {
    q.name: q
    for q in (
        Quantity(
            "temperature",
            "K",
            {
                "K": (1.0, 0.0),
                "degR": (1.0 / RANKINE_PER_KELVIN, 0.0),
                "R": (1.0 / RANKINE_PER_KELVIN, 0.0),
                "degC": (1.0, _ZERO_C),
                "C": (1.0, _ZERO_C),
                "degF": (1.0 / RANKINE_PER_KELVIN, _ZERO_F_IN_R / RANKINE_PER_KELVIN),
                "F": (1.0 / RANKINE_PER_KELVIN, _ZERO_F_IN_R / RANKINE_PER_KELVIN),
            },
        ),
        # A temperature offset (dTamb) converts without the zero shift.
        Quantity(
            "temperature_difference",
            "K",
            {
                "K": (1.0, 0.0),
                "degC": (1.0, 0.0),
                "C": (1.0, 0.0),
                "degR": (1.0 / RANKINE_PER_KELVIN, 0.0),
                "R": (1.0 / RANKINE_PER_KELVIN, 0.0),
                "degF": (1.0 / RANKINE_PER_KELVIN, 0.0),
                "F": (1.0 / RANKINE_PER_KELVIN, 0.0),
            },
        ),
        Quantity(
            "pressure",
            "Pa",
            {
                "Pa": (1.0, 0.0),
                "hPa": (100.0, 0.0),
                "mbar": (100.0, 0.0),
                "kPa": (1e3, 0.0),
                "MPa": (1e6, 0.0),
                "bar": (1e5, 0.0),
                "psia": (PA_PER_PSI, 0.0),
                "psi": (PA_PER_PSI, 0.0),
                "inHg": (3386.389, 0.0),
            },
        ),
        Quantity(
            "rotational_speed",
            "rad/s",
            {
                "rad/s": (1.0, 0.0),
                "rpm": (2.0 * math.pi / 60.0, 0.0),
                "rps": (2.0 * math.pi, 0.0),
                "Hz": (2.0 * math.pi, 0.0),
            },
        ),
        Quantity(
            "mass_flow",
            "kg/s",
            {
                "kg/s": (1.0, 0.0),
                "kg/h": (1.0 / 3600.0, 0.0),
                "pps": (KG_PER_LBM, 0.0),
                "lbm/s": (KG_PER_LBM, 0.0),
                "lb/s": (KG_PER_LBM, 0.0),
                "pph": (KG_PER_LBM / 3600.0, 0.0),
                "lbm/h": (KG_PER_LBM / 3600.0, 0.0),
            },
        ),
        Quantity("percent", "%", {"%": (1.0, 0.0), "fraction": (100.0, 0.0)}),
        Quantity("length", "m", {"m": (1.0, 0.0), "ft": (1.0 / FT_PER_M, 0.0)}),
        Quantity("dimensionless", "1", {"1": (1.0, 0.0), "-": (1.0, 0.0)}),
    )
}

PERCENT = "%"


def affine(
    quantity: str, from_unit: str, to_unit: str, *, reference: float | None = None
) -> tuple[float, float]:
    """Coefficients ``(a, b)`` with ``value_in_to_unit = a * value_in_from_unit + b``.

    ``reference`` is the value of 100 % in ``to_unit`` (a design spool speed); with it,
    ``%`` is a unit of the quantity, converting as ``y = x / 100 * reference``.
    """
    try:
        q = QUANTITIES[quantity]
    except KeyError:
        raise UnknownUnitError(f"unknown quantity {quantity!r}") from None
    if from_unit == to_unit:
        return 1.0, 0.0
    if from_unit == PERCENT and PERCENT not in q.units:
        if reference is None:
            raise UnknownUnitError(f"unit '%' needs a 100 % reference for {quantity}")
        q.to_si(to_unit)  # the reference's unit must be known
        return reference / 100.0, 0.0
    s_from, o_from = q.to_si(from_unit)
    s_to, o_to = q.to_si(to_unit)
    # si = s_from * x + o_from = s_to * y + o_to
    return s_from / s_to, (o_from - o_to) / s_to


def known_units(quantity: str, *, with_percent: bool = False) -> tuple[str, ...]:
    units = tuple(QUANTITIES[quantity].units)
    return units + (PERCENT,) if with_percent and PERCENT not in units else units
