"""Array namespaces: the cycle functions run on numpy arrays or on Python floats.

The gas path, the atmosphere and the controller are written once against a
small namespace ``xp`` (sqrt, log, exp, maximum, minimum, clip, where, abs,
asarray, zeros_like, interp, col, stack). ``NP`` maps it onto numpy (a batch of
engines, arrays [B]); ``SCALAR`` onto the ``math`` module and Python floats (one
engine), where an operation costs tens of nanoseconds instead of the
microsecond numpy spends on a one-element array. Both evaluate the same
formulas in the same order, so they agree to rounding.

On floats ``math`` raises where numpy returns nan (log or sqrt of a negative
number, a negative number to a fractional power gives a complex); callers of
the scalar path catch ``SCALAR_ERRORS`` and redo that evaluation with numpy.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from types import SimpleNamespace
from typing import Any

import numpy as np

SCALAR_ERRORS = (ArithmeticError, ValueError, TypeError)


def _np_col(a: np.ndarray, i: int) -> np.ndarray:
    return a[..., i]


def _np_stack(items: Sequence[Any]) -> np.ndarray:
    return np.stack(items, axis=-1)


NP: Any = SimpleNamespace(
    sqrt=np.sqrt, log=np.log, exp=np.exp, maximum=np.maximum, minimum=np.minimum,
    clip=np.clip, where=np.where, abs=np.abs, asarray=np.asarray, zeros_like=np.zeros_like,
    interp=np.interp, col=_np_col, stack=_np_stack,
)


def _identity(a: float, dtype: object = None) -> float:
    return a


def _clip(a: float, lo: float, hi: float) -> float:
    return min(max(a, lo), hi)


def _where(c: bool, a: float, b: float) -> float:
    return a if c else b


def _zero(a: float) -> float:
    return 0.0


def _interp(x: float, xp: Sequence[float], fp: Sequence[float]) -> float:
    """np.interp for one point on sorted lists (same formula: slope (x - x_j) + f_j)."""
    if x <= xp[0]:
        return fp[0]
    if x >= xp[-1]:
        return fp[-1]
    j = bisect_right(xp, x) - 1
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    return slope * (x - xp[j]) + fp[j]


def _col(a: Sequence[float], i: int) -> float:
    return a[i]


def _stack(items: Sequence[float]) -> list[float]:
    return list(items)


SCALAR: Any = SimpleNamespace(
    sqrt=math.sqrt, log=math.log, exp=math.exp, maximum=max, minimum=min,
    clip=_clip, where=_where, abs=abs, asarray=_identity, zeros_like=_zero,
    interp=_interp, col=_col, stack=_stack,
)
