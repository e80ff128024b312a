"""Exceptions of the built-in engine model."""

from __future__ import annotations


class EnvelopeError(ValueError):
    """An operating condition lies outside the envelope the model is built for."""


class EngineConvergenceError(RuntimeError):
    """The gas-path balance or the steady-state solver did not converge.

    Raised instead of returning an operating point that does not satisfy the
    balances; the message says which engines (batch rows) and how far off.
    """
