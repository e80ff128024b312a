"""Float columns written by numpy equal json.dumps of the rounded numbers, byte for byte; the
JSON objects of a type's own signals are the same text with or without a null among them."""

from __future__ import annotations

import json
from datetime import UTC, datetime

import numpy as np
import pyarrow as pa
import pytest

from app.services.encoding.json_numbers import RawJSON, dumps, float_rows, number_objects


def _reference(matrix: np.ndarray, decimals: int) -> list[str]:
    return [
        json.dumps([None if np.isnan(v) else v for v in row.tolist()], separators=(",", ":"))
        for row in np.round(matrix, decimals)
    ]


@pytest.mark.parametrize("decimals", [0, 1, 2, 3, 4])
@pytest.mark.parametrize("scale", [1e-6, 1e-4, 1e-2, 1.0, 1e2, 1e5, 1e8, 4e8])
def test_rows_equal_json_dumps(decimals: int, scale: float) -> None:
    rng = np.random.default_rng(int(scale * 1e6) % 2**32 + decimals)
    matrix = rng.normal(size=(6, 257)) * scale
    matrix[0, :8] = [np.nan, -0.0, 0.0, -1e-7, 1.0, 0.00005, -0.00005, 0.99995]
    matrix[1, ::3] = np.nan
    matrix[2] = np.round(matrix[2], 1)  # trailing zeros to strip
    assert float_rows(matrix, decimals) == _reference(matrix, decimals)


def test_values_out_of_range_fall_back_to_json() -> None:
    matrix = np.array([[1.5, 2e9, -3e12], [np.inf, 0.25, np.nan]])
    assert float_rows(matrix, 4) == [
        json.dumps(row, separators=(",", ":"))
        for row in ([1.5, 2e9, -3e12], [float("inf"), 0.25, None])
    ]


def test_empty_rows_and_shape_errors() -> None:
    assert float_rows(np.empty((3, 0))) == ["[]"] * 3
    assert float_rows(np.empty((0, 5))) == []
    with pytest.raises(ValueError, match="2-d"):
        float_rows(np.zeros(4))


def test_dumps_places_raw_parts_as_if_they_were_values() -> None:
    rng = np.random.default_rng(7)
    matrix = rng.normal(size=(3, 11))
    when = datetime(2026, 1, 2, 3, 4, 5, tzinfo=UTC)
    texts = float_rows(matrix)
    document = {"a": [RawJSON(t) for t in texts], "when": when, "name": '"@raw-x-0"'}
    plain = {"a": [json.loads(t) for t in texts], "when": "2026-01-02T03:04:05Z",
             "name": '"@raw-x-0"'}

    def default(value: object) -> object:
        assert isinstance(value, datetime)
        return value.isoformat().replace("+00:00", "Z")

    assert dumps(document, default) == json.dumps(plain, separators=(",", ":")).encode()


@pytest.mark.parametrize("chunked", [False, True])
def test_number_objects_without_nulls_are_the_general_text(chunked: bool) -> None:
    """A type's own signals without a missing value take the one-join path: the same text as
    the path that skips nulls (the same column with one null added elsewhere), and each
    object reads back as the row's floats."""
    rng = np.random.default_rng(5)
    n = 400
    values = {name: rng.normal(0, 1e4, n) * 10.0 ** rng.integers(-9, 9, n)
              for name in ("N1", "EGT", 'odd "name"')}
    values["EGT"][:3] = [20.0, -0.0, 1e21]

    def column(v: np.ndarray) -> pa.Array | pa.ChunkedArray:
        array = pa.array(v, from_pandas=True)
        return pa.chunked_array([array[:150], array[150:]]) if chunked else array

    fast = number_objects({k: column(v) for k, v in values.items()}, n)
    general = number_objects({**{k: column(v) for k, v in values.items()},
                              "gap": column(np.full(n, np.nan))}, n)
    assert fast.to_pylist() == general.to_pylist()
    for k, text in enumerate(fast.to_pylist()):
        assert json.loads(text) == {name: v[k] for name, v in values.items()}
