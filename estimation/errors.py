"""Exceptions and warnings of the estimation package.

Each subclasses the built-in a caller would catch anyway (python-control's
``ControlDimension(ValueError)``, statsmodels' ``ConvergenceWarning``).
"""

from __future__ import annotations


class DimensionError(ValueError):
    """A matrix or vector has the wrong shape; the message names it and the expected shape."""


class ModelFormatError(ValueError):
    """A model dict (``fleethealth.linear-model/1``) is malformed; the message names the key."""


class DesignSpecError(ValueError):
    """A design spec (``fleethealth.design-spec/1``) is malformed; the message names the key."""


class UnknownSignalError(KeyError):
    """A signal name is not in the model's list of that kind (sensor, health parameter...)."""

    def __str__(self) -> str:  # KeyError quotes its argument; a sentence reads better
        return str(self.args[0]) if self.args else ""


class SingularModelError(ValueError):
    """The model has no steady state (I - A singular: an integrator or an eigenvalue at 1)."""


class UnobservableDesignError(ValueError):
    """The tuner design cannot be estimated from the chosen sensors.

    Raised when the reduced-order pair (A_xq, C_xq) is not detectable, typically
    with more tuners than the sensors allow, or when the Riccati solution does not
    give a stabilising gain.
    """


class ConvergenceWarning(UserWarning):
    """An iterative search or recursion stopped before meeting its tolerance."""
