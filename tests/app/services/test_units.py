"""Unit conversions: each affine pair checked against the textbook formula or a round trip."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from app.services.units import QUANTITIES, UnknownUnitError, affine


def convert(values: np.ndarray, quantity: str, src: str, dst: str, **kw: float) -> np.ndarray:
    a, b = affine(quantity, src, dst, **kw)
    return a * values + b


def test_temperatures_match_the_textbook_formulas() -> None:
    celsius = np.array([-40.0, 0.0, 15.0, 100.0])
    kelvin = celsius + 273.15
    rankine = kelvin * 9.0 / 5.0
    fahrenheit = celsius * 9.0 / 5.0 + 32.0
    np.testing.assert_allclose(convert(celsius, "temperature", "degC", "degR"), rankine)
    np.testing.assert_allclose(convert(fahrenheit, "temperature", "degF", "degR"), rankine)
    np.testing.assert_allclose(convert(kelvin, "temperature", "K", "degR"), rankine)
    # -40 is the same in Celsius and Fahrenheit.
    assert convert(np.array([-40.0]), "temperature", "degC", "degF")[0] == pytest.approx(-40.0)


def test_temperature_differences_have_no_zero_shift() -> None:
    np.testing.assert_allclose(
        convert(np.array([9.0]), "temperature_difference", "degF", "K"), [5.0]
    )
    np.testing.assert_allclose(
        convert(np.array([5.0]), "temperature_difference", "degC", "K"), [5.0]
    )


def test_pressure_flow_and_speed() -> None:
    # 1 standard atmosphere: 101.325 kPa = 14.6959 psia = 1.01325 bar.
    np.testing.assert_allclose(
        convert(np.array([101.325]), "pressure", "kPa", "psia"), [14.6959488], rtol=1e-7
    )
    np.testing.assert_allclose(convert(np.array([1.01325]), "pressure", "bar", "kPa"), [101.325])
    # 3600 pph is one pound per second; one pound is 0.45359237 kg.
    np.testing.assert_allclose(convert(np.array([3600.0]), "mass_flow", "pph", "pps"), [1.0])
    np.testing.assert_allclose(
        convert(np.array([1.0]), "mass_flow", "kg/s", "pps"), [1 / 0.45359237]
    )
    np.testing.assert_allclose(
        convert(np.array([2 * np.pi]), "rotational_speed", "rad/s", "rpm"), [60.0]
    )


def test_percent_of_a_reference_speed() -> None:
    np.testing.assert_allclose(
        convert(np.array([50.0, 100.0]), "rotational_speed", "%", "rpm", reference=9000.0),
        [4500.0, 9000.0],
    )
    with pytest.raises(UnknownUnitError, match="reference"):
        affine("rotational_speed", "%", "rpm")


@pytest.mark.parametrize("quantity", sorted(QUANTITIES))
def test_every_pair_round_trips(quantity: str) -> None:
    values = np.array([-3.5, 0.0, 1.0, 1234.5])
    for src, dst in itertools.permutations(QUANTITIES[quantity].units, 2):
        back = convert(convert(values, quantity, src, dst), quantity, dst, src)
        np.testing.assert_allclose(back, values, rtol=1e-12, atol=1e-9)


def test_unknown_unit_names_the_known_ones() -> None:
    with pytest.raises(UnknownUnitError, match="furlong.*known units: .*degR"):
        affine("temperature", "furlong", "degR")
