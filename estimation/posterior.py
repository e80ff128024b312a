"""Confidence per event: posterior over the fault hypotheses and ambiguity groups.

Under hypothesis i (fault i at its fitted magnitude) the residuals are Gaussian with the
weights of the fit, so the data's likelihood, maximised over the magnitude, is

    l_i ∝ exp(-WSSR_i / 2)          (seed 002 eq. 21-23; same dof for every hypothesis)

and WSSR_i of the true fault is chi-squared with ``dof`` degrees of freedom (n sensor values,
one magnitude fitted): ``fit_probability`` = P(chi2_dof >= min_i WSSR_i) says whether any
hypothesis explains the event at all (the posterior only ranks the library's faults)
and with the library's prior pi_i the WSSR posterior is p_i ∝ pi_i l_i. Model error (the
linearisation of a deteriorated engine) inflates WSSR; a ``scale`` s > 1 divides it
(WSSR / s) so one record's mismatch does not make the posterior overconfident.

The design's measured confusion C (rows true, columns isolated, on the nonlinear engine,
``estimation.evaluate_engine``) gives a second, empirical posterior of the isolated fault j,
P(true = i | isolated = j) = pi_i C_ij / sum_k pi_k C_kj (Bayes on the confusion column,
``confusion_posterior``). The event posterior combines both: the WSSR posterior times the
probability that the design isolates j when i is true,

    p_i ∝ pi_i l_i C_ij        (j = argmin WSSR; C_ij floored so no outcome is impossible)

which keeps faults the design confuses on the engine (its nonlinearity, invisible faults)
from being reported with the confidence the linear chi-squared alone would give.

Ambiguity groups: faults the design cannot tell apart, from the confusion (i and j linked when
C_ij + C_ji exceeds ``threshold`` percent; groups are the connected components), and per
event the smallest set of hypotheses holding ``mass`` of the posterior, named "HPT or Wf".

Pure numpy/scipy.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats


class PosteriorError(ValueError):
    """Inputs whose shapes or values do not fit together."""


@dataclass(frozen=True)
class FaultPosterior:
    """Posterior over the fault hypotheses of one or more events.

    faults    : n_f names
    wssr_only : (..., n_f) posterior from the WSSR likelihoods and the prior
    posterior : (..., n_f) that times the confusion column of the isolated fault (equal to
                ``wssr_only`` without a confusion matrix)
    isolated  : (...) index of the smallest WSSR
    fit_probability : (...) chi-squared tail probability of the smallest WSSR
    """

    faults: tuple[str, ...]
    wssr_only: np.ndarray
    posterior: np.ndarray
    isolated: np.ndarray
    fit_probability: np.ndarray

    def credible_set(self, mass: float = 0.9) -> list[tuple[str, ...]]:
        """Per event (flattened), the fewest faults whose posterior sums to ``mass``."""
        out = []
        for p in self.posterior.reshape(-1, len(self.faults)):
            order = np.argsort(-p, kind="stable")
            n = int(np.searchsorted(np.cumsum(p[order]), mass - 1e-12) + 1)
            out.append(tuple(self.faults[i] for i in order[:n]))
        return out

    def label(self, mass: float = 0.9) -> list[str]:
        """"HPT" or "HPT or Wf" per event: the credible set in words."""
        return [" or ".join(s) for s in self.credible_set(mass)]


def fault_posterior(
    wssr: np.ndarray,
    dof: np.ndarray | int,
    faults: Sequence[str],
    prior: np.ndarray | None = None,
    confusion: np.ndarray | None = None,
    scale: float = 1.0,
    floor: float = 0.5,
    confusion_power: float = 1.0,
) -> FaultPosterior:
    """Posterior over fault hypotheses (see the module docstring).

    wssr      : (..., n_f) WSSR per hypothesis; dof : (...) or int chi-squared dof
    prior     : (n_f,) library frequencies (default uniform)
    confusion : (n_f, n_f) measured confusion in percent (rows true, columns isolated)
    scale     : WSSR inflation for model error (> 0); floor : percent added to every
                confusion cell so an outcome never seen is improbable, not impossible
    confusion_power : beta, the weight of the confusion column (C_ij^beta; ``fit_tempering``)
    """
    wssr = np.asarray(wssr, float)
    n_f = len(faults)
    if wssr.shape[-1] != n_f:
        raise PosteriorError(f"wssr: last dimension {wssr.shape[-1]}, {n_f} faults")
    if scale <= 0:
        raise PosteriorError("scale must be positive")
    pi = np.full(n_f, 1.0 / n_f) if prior is None else np.asarray(prior, float)
    if pi.shape != (n_f,) or np.any(pi < 0) or pi.sum() <= 0:
        raise PosteriorError("prior must be n_f non-negative numbers, not all zero")
    pi = pi / pi.sum()
    d = np.broadcast_to(np.asarray(dof, float), wssr.shape[:-1])
    logl = -0.5 * wssr / scale
    logp = np.log(np.maximum(pi, 1e-300)) + logl
    logp -= logp.max(axis=-1, keepdims=True)
    p = np.exp(logp)
    p /= p.sum(axis=-1, keepdims=True)
    isolated = np.argmin(wssr, axis=-1)
    post = p
    if confusion is not None:
        C = np.asarray(confusion, float)
        if C.shape != (n_f, n_f):
            raise PosteriorError(f"confusion must be ({n_f}, {n_f}), found {C.shape}")
        C = np.nan_to_num(C) + floor
        C = C / C.sum(axis=1, keepdims=True)  # P(isolated j | true i)
        col = np.moveaxis(C[:, isolated], 0, -1)  # (..., n_f): P(isolated | true i)
        post = p * col**confusion_power
        post /= post.sum(axis=-1, keepdims=True)
    fit = stats.chi2.sf(np.min(wssr, axis=-1) / scale, d)
    return FaultPosterior(tuple(faults), p, post, isolated, np.asarray(fit))


SCALE_GRID = tuple(float(x) for x in np.geomspace(0.5, 64.0, 29))
POWER_GRID = (0.0, 0.25, 0.5, 0.75, 1.0)
LOG_FLOOR = 1e-6  # a true fault given less still costs log(1e-6), not minus infinity


@dataclass(frozen=True)
class Tempering:
    """The event posterior's scale s and confusion weight beta fitted on events of known
    fault (``fit_tempering``): log_score, the mean log posterior of the true fault there, and
    the same with the untempered defaults (``default_score``), over ``events`` events."""

    scale: float
    confusion_power: float
    log_score: float
    default_score: float
    events: int

    def to_dict(self) -> dict[str, float | int]:
        return {"wssr_scale": self.scale, "confusion_power": self.confusion_power,
                "log_score": self.log_score, "default_score": self.default_score,
                "events": self.events}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Tempering:
        return cls(float(d["wssr_scale"]), float(d["confusion_power"]), float(d["log_score"]),
                   float(d["default_score"]), int(d["events"]))


def fit_tempering(
    wssr: np.ndarray, dof: np.ndarray | int, truth: np.ndarray, faults: Sequence[str],
    confusion: np.ndarray | None, default_scale: float = 1.0,
    scales: Sequence[float] = SCALE_GRID, powers: Sequence[float] = POWER_GRID,
) -> Tempering:
    """The scale s and confusion weight beta of ``fault_posterior`` that make its confidence
    honest on events of known fault truth [E] (indices of ``faults``), with WSSR [E, n_f]:
    the pair of the grids that maximises the mean log posterior of the true fault (a proper
    score: it rewards a posterior that is right as often as it says). The WSSR of a linearised
    fit on a nonlinear engine is larger than chi-squared and the isolated fault's confusion
    column already follows from the WSSR, so the product of the two, untempered, claims more
    than it knows. Fit on events other than those the confusion was measured on."""
    wssr = np.asarray(wssr, float)
    truth = np.asarray(truth, int)
    rows = np.arange(len(truth))

    def score(scale: float, power: float) -> float:
        post = fault_posterior(wssr, dof, faults, confusion=confusion, scale=scale,
                               confusion_power=power).posterior
        return float(np.mean(np.log(np.maximum(post[rows, truth], LOG_FLOOR))))

    grid = [(score(s, b), s, b) for s in scales
            for b in (powers if confusion is not None else (1.0,))]
    best, s, b = max(grid, key=lambda g: g[0])
    return Tempering(s, b, best, score(default_scale, 1.0), len(truth))


def confusion_posterior(
    confusion: np.ndarray, prior: np.ndarray | None = None, floor: float = 0.0
) -> np.ndarray:
    """P(true = i | isolated = j) by Bayes on the confusion [n_f, n_f] (columns sum to 1)."""
    C = np.nan_to_num(np.asarray(confusion, float)) + floor
    C = C / C.sum(axis=1, keepdims=True)
    n_f = C.shape[0]
    pi = np.full(n_f, 1.0 / n_f) if prior is None else np.asarray(prior, float) / np.sum(prior)
    joint = pi[:, None] * C
    with np.errstate(invalid="ignore", divide="ignore"):
        return joint / joint.sum(axis=0, keepdims=True)


RELIABILITY_EDGES = (0.0, 0.5, 0.7, 0.9, 0.99, 1.0)


@dataclass(frozen=True)
class Reliability:
    """How often events named with a confidence are right, binned by that confidence.

    edges [B + 1]; count, confidence (mean in the bin), hit_rate [B] (NaN: empty bin);
    calibration_error: the count-weighted mean of |hit_rate - confidence| (expected
    calibration error).
    """

    edges: tuple[float, ...]
    count: np.ndarray
    confidence: np.ndarray
    hit_rate: np.ndarray
    calibration_error: float

    def rows(self) -> list[tuple[float, float, int, float, float]]:
        """(low, high, count, mean confidence, hit rate) of each non-empty bin."""
        return [(self.edges[b], self.edges[b + 1], int(self.count[b]),
                 float(self.confidence[b]), float(self.hit_rate[b]))
                for b in range(len(self.count)) if self.count[b]]


def reliability(
    confidence: np.ndarray, hit: np.ndarray, edges: Sequence[float] = RELIABILITY_EDGES,
) -> Reliability:
    """Bin events by the confidence of the fault they name [N] (the last bin closed) and
    compare with how often that fault was the true one, hit [N] bool."""
    confidence = np.asarray(confidence, float)
    hit = np.asarray(hit, bool)
    if confidence.shape != hit.shape:
        raise PosteriorError("confidence and hit must have the same shape")
    e = np.asarray(edges, float)
    b = np.clip(np.searchsorted(e, confidence, side="right") - 1, 0, len(e) - 2)
    count = np.bincount(b, minlength=len(e) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(b, confidence, len(e) - 1) / count
        rate = np.bincount(b, hit.astype(float), len(e) - 1) / count
    gap = np.abs(np.nan_to_num(rate - mean))
    error = float(np.sum(count * gap) / max(count.sum(), 1))
    return Reliability(tuple(float(x) for x in e), count, mean, rate, error)


@dataclass(frozen=True)
class AmbiguityGroups:
    """Faults the design cannot tell apart.

    groups    : tuples of fault names (connected components, singletons included)
    threshold : percent of C_ij + C_ji above which i and j are linked
    """

    groups: tuple[tuple[str, ...], ...]
    threshold: float

    def group_of(self, fault: str) -> tuple[str, ...]:
        return next(g for g in self.groups if fault in g)

    def label(self, fault: str) -> str:
        return " or ".join(self.group_of(fault))

    def group_correct(self, confusion: np.ndarray, faults: Sequence[str]) -> float:
        """Percent correct when naming a fault's group counts as right (mean over rows)."""
        C = np.nan_to_num(np.asarray(confusion, float))
        idx = {f: i for i, f in enumerate(faults)}
        rows = []
        for i, f in enumerate(faults):
            rows.append(sum(C[i, idx[g]] for g in self.group_of(f)))
        return float(np.mean(rows))


def ambiguity_groups(
    confusion: np.ndarray, faults: Sequence[str], threshold: float = 10.0
) -> AmbiguityGroups:
    """Connected components of the graph linking i and j when C_ij + C_ji > threshold (%)."""
    C = np.nan_to_num(np.asarray(confusion, float))
    n = len(faults)
    if C.shape != (n, n):
        raise PosteriorError(f"confusion must be ({n}, {n}), found {C.shape}")
    link = (C + C.T) > threshold
    seen = [False] * n
    groups = []
    for s in range(n):
        if seen[s]:
            continue
        stack, comp = [s], []
        seen[s] = True
        while stack:
            i = stack.pop()
            comp.append(i)
            for j in np.flatnonzero(link[i]):
                if not seen[j]:
                    seen[j] = True
                    stack.append(int(j))
        groups.append(tuple(faults[i] for i in sorted(comp)))
    return AmbiguityGroups(tuple(groups), threshold)
