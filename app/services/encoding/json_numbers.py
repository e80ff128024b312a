"""JSON text of float arrays written by numpy, and documents with pre-encoded parts.

A decimated trend carries some 90,000 rounded floats; ``json.dumps`` formats each through
``float.__repr__`` and that alone costs more than the database query. Rounded to a few decimals,
a value's shortest repr is its decimal digits with trailing zeros stripped (keeping one, "1.0"),
so the text of a whole matrix is assembled from integer digits with array operations and comes
out byte for byte as ``json.dumps(np.round(x, decimals).tolist())`` with NaN as ``null``.
Values outside the range where that holds fall back to ``json.dumps``.
"""

from __future__ import annotations

import json
import re
import uuid
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

# Below this magnitude a float64 resolves 1e-4 by far, so the rounded decimal string is the
# shortest one that reads back to the same float (and repr writes no exponent).
_MAX_ABS = 1e9


class RawJSON:
    """Text already encoded as JSON, placed as-is by ``dumps``."""

    __slots__ = ("text",)

    def __init__(self, text: str) -> None:
        self.text = text


def _reference_rows(rounded: np.ndarray) -> list[str]:
    return [
        json.dumps([None if v != v else v for v in row.tolist()], separators=(",", ":"))
        for row in rounded
    ]


def float_rows(matrix: np.ndarray, decimals: int = 4) -> list[str]:
    """JSON array text of each row of ``np.round(matrix, decimals)`` (m, n), NaN as null.

    Equals ``json.dumps(row.tolist(), separators=(",", ":"))`` of each rounded row with NaN
    replaced by None, for 0 <= decimals <= 4.
    """
    values = np.round(np.asarray(matrix, dtype=np.float64), decimals)
    if values.ndim != 2:
        raise ValueError(f"float_rows: expected a 2-d matrix but found shape {values.shape}")
    if not 0 <= decimals <= 4:
        raise ValueError(f"float_rows: decimals must be 0..4, got {decimals}")
    m, n = values.shape
    if m == 0 or n == 0:
        return ["[]"] * m
    nan = np.isnan(values)
    magnitude = np.where(nan, 0.0, np.abs(values))
    if not np.all(magnitude < _MAX_ABS):  # infinity or huge: let json write them
        return _reference_rows(values)
    scale = 10**decimals
    k = np.rint(magnitude * scale).astype(np.int64)
    if not np.array_equal(k / scale, magnitude):  # the digits must read back exactly
        return _reference_rows(values)
    whole, frac = np.divmod(k, scale)
    n_digits = len(str(int(whole.max())))
    has_nan = bool(nan.any())
    live = ~nan

    # One row of characters per value: sign, integer digits, ".", fraction digits, "null"
    # (only with a NaN present), ","; ``keep`` marks the characters written.
    n_frac_max = max(decimals, 1)
    width = 1 + n_digits + 1 + n_frac_max + (4 if has_nan else 0) + 1
    chars = np.empty((m, n, width), dtype=np.uint8)
    keep = np.empty((m, n, width), dtype=bool)
    chars[..., 0] = ord("-")
    keep[..., 0] = np.signbit(values) & live
    rest = whole
    for j in range(n_digits - 1, -1, -1):  # least significant digit last
        rest, digit = np.divmod(rest, 10)
        chars[..., 1 + j] = ord("0") + digit
        # Leading zeros are dropped, the units digit always written.
        keep[..., 1 + j] = live if j == n_digits - 1 else (whole >= 10 ** (n_digits - 1 - j))
    if n_digits > 1 and has_nan:
        keep[..., 1 : n_digits] &= live[..., None]
    dot = 1 + n_digits
    chars[..., dot] = ord(".")
    keep[..., dot] = live
    if decimals == 0:
        chars[..., dot + 1] = ord("0")
        keep[..., dot + 1] = live
    else:
        # Fraction digits up to the last non-zero one, at least one ("1.0").
        rest = frac
        nonzero_after = np.zeros((m, n), dtype=bool)
        for i in range(decimals - 1, -1, -1):
            rest, digit = np.divmod(rest, 10)
            chars[..., dot + 1 + i] = ord("0") + digit
            nonzero_after |= digit != 0
            keep[..., dot + 1 + i] = live if i == 0 else nonzero_after & live
    end = dot + 1 + n_frac_max
    if has_nan:
        chars[..., end : end + 4] = np.frombuffer(b"null", dtype=np.uint8)
        keep[..., end : end + 4] = nan[..., None]
    chars[..., -1] = ord(",")
    keep[..., -1] = True
    keep[:, -1, -1] = False  # no comma after a row's last value

    body = chars[keep].tobytes().decode("ascii")
    lengths = keep.reshape(m, -1).sum(axis=1)
    ends = np.cumsum(lengths).tolist()
    starts = [0, *ends[:-1]]
    return [f"[{body[a:b]}]" for a, b in zip(starts, ends, strict=True)]


def dumps(document: Any, default: Callable[[Any], Any]) -> bytes:
    """``json.dumps`` (compact) of a document that may hold ``RawJSON`` parts, as bytes."""
    raws: list[str] = []
    token = f"@raw-{uuid.uuid4().hex}-"

    def place(value: Any) -> Any:
        if isinstance(value, RawJSON):
            raws.append(value.text)
            return f"{token}{len(raws) - 1}"
        return default(value)

    text = json.dumps(document, default=place, separators=(",", ":"))
    if raws:
        text = re.sub(f'"{token}(\\d+)"', lambda match: raws[int(match.group(1))], text)
    return text.encode()


def number_objects(columns: Mapping[str, pa.ChunkedArray | pa.Array], n: int) -> pa.Array:
    """Per row, one JSON object of the row's numbers by column name (``{"N1":98.5,"EGT":505}``),
    written column-wise by Arrow (its float text is the shortest that reads back to the same
    float); a null value has no key, a row of nulls is null. ``n``: the number of rows.

    Without a null anywhere (a type's own signals as most uploads carry them), each row is
    one join of its key texts and numbers (the same text, in a third of the time)."""
    if columns and all(values.null_count == 0 for values in columns.values()):
        parts: list[Any] = []
        for k, (name, values) in enumerate(columns.items()):
            parts += [("{" if k == 0 else ",") + json.dumps(name) + ":",
                      pc.cast(pc.cast(values, pa.float64()), pa.string())]
        whole = pc.binary_join_element_wise(*parts, "}", "")
        return whole.combine_chunks() if isinstance(whole, pa.ChunkedArray) else whole
    pieces = []
    for name, values in columns.items():
        text = pc.cast(pc.cast(values, pa.float64()), pa.string())
        piece = pc.binary_join_element_wise(json.dumps(name) + ":", text, ",", "")
        pieces.append(pc.fill_null(piece, ""))
    if not pieces:
        return pa.nulls(n, pa.string())
    body = pc.utf8_rtrim(pc.binary_join_element_wise(*pieces, ""), characters=",")
    empty = pc.equal(pc.binary_length(body), 0)
    text = pc.binary_join_element_wise("{", body, "}", "")
    joined = pc.if_else(empty, pa.scalar(None, pa.string()), text)
    return joined.combine_chunks() if isinstance(joined, pa.ChunkedArray) else joined
