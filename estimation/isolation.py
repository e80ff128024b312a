"""Single-fault isolation by weighted sum of squared residuals (seed 002).

A fault library lists abrupt health-parameter shifts (seed 002 Table 3). The
steady-state Kalman filter maps a health shift to a quasi-steady shift of its
tuner estimate (seed 002 eq. 19)::

    G_q = [0 I_m] Gamma K G_y,full        Gamma = (I - A_xq + K C_xq A_xq)^-1
    H   = G_q S                           S: (p_full, n_faults) library shifts

so that ``q_hat = H f + v_q`` with ``v_q ~ N(0, P_q)`` (seed 002 eq. 20) and
``f_i = 1`` is the library's nominal magnitude. Each hypothesis is fitted by
weighted least squares and the smallest WSSR wins (seed 002 eq. 21-23). The
same machinery in sensor space (``y_hat``) is the conventional baseline
(seed 002 Table 9); ``max_h_rule`` is the naive rule of seed 002 Table 7.

All deviations are in percent of trim, as in the linear model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtr


class IsolationError(ValueError):
    """A fault library, influence matrix or covariance that cannot be used."""


@dataclass(frozen=True)
class Fault:
    """One fault type: name and health-parameter shifts in percent.

    ``shifts`` maps a health-parameter name (or ``<input>_bias`` for an
    actuator bias) to its abrupt shift in percent of trim.
    """

    name: str
    shifts: Mapping[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, object]:
        return {"name": self.name, "shifts": {k: float(v) for k, v in self.shifts.items()}}

    @classmethod
    def from_dict(cls, d: Mapping[str, object]) -> Fault:
        shifts = d.get("shifts")
        if not isinstance(shifts, Mapping) or not shifts:
            raise IsolationError(f"fault {d.get('name')!r}: 'shifts' must be a non-empty object")
        return cls(name=str(d["name"]), shifts={str(k): float(v) for k, v in shifts.items()})


# seed 002 Table 3: gas path fault types and magnitudes (percent shifts
# relative to a recently archived baseline). Health names follow the
# "<module>_eff" / "<module>_flow" convention; actuator biases are
# "<input>_bias" and map onto the model's B and D columns when the model has
# no health parameter of that name.
SEED_002_FAULTS: tuple[Fault, ...] = (
    Fault("Fan", {"fan_eff": -2.0, "fan_flow": -2.0}),
    Fault("LPC", {"lpc_eff": -4.0, "lpc_flow": -4.0}),
    Fault("HPC", {"hpc_eff": -2.0, "hpc_flow": -2.0}),
    Fault("HPT", {"hpt_eff": -2.0, "hpt_flow": 2.0}),
    Fault("LPT", {"lpt_eff": -2.0, "lpt_flow": 2.0}),
    Fault("Wf", {"wf_bias": -2.0}),
    Fault("VSV", {"vsv_bias": -2.0}),
    Fault("VBV", {"vbv_bias": -10.0}),
)


def default_faults() -> tuple[Fault, ...]:
    """The seed 002 Table 3 library (eight faults)."""
    return SEED_002_FAULTS


def faults_from_list(items: Sequence[Mapping[str, object]] | None) -> tuple[Fault, ...]:
    """Faults from a list of ``{"name", "shifts"}`` dicts; ``None`` -> default library."""
    if items is None:
        return default_faults()
    faults = tuple(Fault.from_dict(d) for d in items)
    names = [f.name for f in faults]
    if len(set(names)) != len(names):
        raise IsolationError(f"fault names must be unique, got {names}")
    return faults


def _canonical(name: str) -> str:
    return name.strip().lower().replace(" ", "_").replace("-", "_")


def signature_matrix(faults: Sequence[Fault], health_names: Sequence[str]) -> np.ndarray:
    """Library shifts as columns over a health vector.

    Returns S : (p, n_faults), S[j, i] = shift of health parameter j in fault i
    (percent). Names are matched case-insensitively; an unknown name raises
    with the list of known ones.
    """
    index = {_canonical(n): j for j, n in enumerate(health_names)}
    S = np.zeros((len(health_names), len(faults)))
    for i, fault in enumerate(faults):
        for name, shift in fault.shifts.items():
            j = index.get(_canonical(name))
            if j is None:
                raise IsolationError(
                    f"fault {fault.name!r} shifts unknown health parameter {name!r}; "
                    f"known: {list(health_names)}"
                )
            S[j, i] += shift
    return S


@dataclass(frozen=True)
class FullHealth:
    """Health vector extended by actuator biases (seed 002 eq. 13).

    names : p_full names; L : (n_x, p_full); M : (n_y, p_full); N : (n_z, p_full).
    An actuator bias b on input j shifts the actual input (u + b), so its
    columns are B[:, j], D[:, j] and G[:, j].
    """

    names: tuple[str, ...]
    L: np.ndarray
    M: np.ndarray
    N: np.ndarray


def full_health(
    L: np.ndarray,
    M: np.ndarray,
    N: np.ndarray,
    B: np.ndarray,
    D: np.ndarray,
    G: np.ndarray,
    health_names: Sequence[str],
    input_names: Sequence[str],
) -> FullHealth:
    """Append an ``<input>_bias`` health parameter per input not already in the health vector."""
    names = list(health_names)
    have = {_canonical(n) for n in names}
    Ls, Ms, Ns = [np.asarray(L, float)], [np.asarray(M, float)], [np.asarray(N, float)]
    for j, u in enumerate(input_names):
        bias = f"{_canonical(u)}_bias"
        if bias in have:
            continue
        names.append(bias)
        Ls.append(np.asarray(B, float)[:, j : j + 1])
        Ms.append(np.asarray(D, float)[:, j : j + 1])
        Ns.append(np.asarray(G, float)[:, j : j + 1])
    return FullHealth(tuple(names), np.hstack(Ls), np.hstack(Ms), np.hstack(Ns))


def steady_state_gain(A: np.ndarray, L: np.ndarray, C: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Open-loop steady-state gain G = C (I - A)^-1 L + M (seed 002 eq. 17), solved not inverted."""
    n = A.shape[0]
    return C @ np.linalg.solve(np.eye(n) - A, L) + M


def filter_steady_state_map(
    A_xq: np.ndarray, C_xq: np.ndarray, K: np.ndarray, G_y: np.ndarray
) -> np.ndarray:
    """x_hat_ss per unit health shift: Gamma K G_y (seed 002 eq. 18), shape (n_x + m, p_full)."""
    n = A_xq.shape[0]
    return np.linalg.solve(np.eye(n) - A_xq + K @ C_xq @ A_xq, K @ G_y)


def tuner_fault_influence(
    A_xq: np.ndarray, C_xq: np.ndarray, K: np.ndarray, G_y: np.ndarray, S: np.ndarray, m: int
) -> np.ndarray:
    """Fault influence in tuner space H = [0 I_m] Gamma K G_y S (seed 002 eq. 19-20).

    Returns H : (m, n_faults), the quasi-steady change of q_hat for each
    library fault at its nominal magnitude.
    """
    X = filter_steady_state_map(A_xq, C_xq, K, G_y)
    return X[-m:, :] @ S


def sensor_fault_influence(
    A_xq: np.ndarray, C_xq: np.ndarray, K: np.ndarray, G_y: np.ndarray, S: np.ndarray
) -> np.ndarray:
    """Fault influence on the filter's sensor estimate y_hat = C_xq x_hat: (n_y, n_faults).

    Seed 002 footnote 2 isolates on y_hat (less noisy than y). Its quasi-steady
    shift is C_xq Gamma K G_y S, which equals the conventional G_y S whenever
    the filter reproduces the measured shift (as many tuners as sensors).
    """
    return C_xq @ filter_steady_state_map(A_xq, C_xq, K, G_y) @ S


def whitener(P: np.ndarray, name: str = "P_q", rtol: float = 1e-10) -> np.ndarray:
    """W with W P W^T = I on the range of P (pseudo-inverse square root).

    Returns W : (r, n), r = numerical rank. A covariance with directions of
    zero variance (y_hat may live in a subspace) is handled as a
    pseudo-inverse, so WSSR ignores those directions.
    """
    P = np.asarray(P, float)
    if P.ndim != 2 or P.shape[0] != P.shape[1]:
        raise IsolationError(f"{name} must be square, found shape {P.shape}")
    P = 0.5 * (P + P.T)
    lam, U = np.linalg.eigh(P)
    if lam.max() <= 0.0:
        raise IsolationError(f"{name} has no positive variance")
    if lam.min() < -1e-8 * lam.max():
        raise IsolationError(f"{name} is not positive semidefinite (eigenvalue {lam.min():.3g})")
    keep = lam > rtol * lam.max()
    return (U[:, keep] / np.sqrt(lam[keep])).T


@dataclass(frozen=True)
class Isolation:
    """Result of single-fault isolation over a batch of estimate shifts.

    faults    : names, length n_f
    wssr      : (..., n_f) weighted sum of squared residuals per hypothesis (eq. 23)
    magnitude : (..., n_f) fitted f_i (eq. 21), 1.0 = the library's nominal shift
    isolated  : (...) index of the isolated fault (argmin WSSR)
    """

    faults: tuple[str, ...]
    wssr: np.ndarray
    magnitude: np.ndarray
    isolated: np.ndarray

    def isolated_names(self) -> np.ndarray:
        return np.asarray(self.faults, dtype=object)[self.isolated]


def _check_influence(H: np.ndarray, P: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    H = np.asarray(H, float)
    if H.ndim != 2:
        raise IsolationError(f"fault influence matrix {name} must be 2-D, found {H.shape}")
    if np.asarray(P).shape != (H.shape[0], H.shape[0]):
        raise IsolationError(
            f"covariance for {name}: expected ({H.shape[0]}, {H.shape[0]}) "
            f"but found {np.asarray(P).shape}"
        )
    W = whitener(P, f"covariance for {name}")
    Hw = W @ H
    if np.any(np.sum(Hw**2, axis=0) <= 0.0):
        raise IsolationError(f"{name} has a fault column with no weighted signature")
    return W, Hw


def wssr_isolate(
    shift: np.ndarray, H: np.ndarray, P: np.ndarray, faults: Sequence[str] | None = None
) -> Isolation:
    """Weighted least-squares single-fault isolation (seed 002 eq. 21-23).

    shift : (..., m) change of the estimate (q_hat or y_hat) against its baseline
    H     : (m, n_f) fault influence matrix; P : (m, m) covariance of the estimate

        f_i    = (H_i^T P^-1 H_i)^-1 H_i^T P^-1 q          (eq. 21)
        WSSR_i = (q - H_i f_i)^T P^-1 (q - H_i f_i)        (eq. 22-23)

    computed in whitened coordinates (W P W^T = I) for a whole batch at once.
    """
    W, Hw = _check_influence(H, P, "H")
    shift = np.asarray(shift, float)
    if shift.shape[-1] != H.shape[0]:
        raise IsolationError(f"shift: expected last dimension {H.shape[0]}, found {shift.shape}")
    names = tuple(faults) if faults is not None else tuple(f"f{i}" for i in range(H.shape[1]))
    if len(names) != H.shape[1]:
        raise IsolationError(f"{len(names)} fault names for {H.shape[1]} columns of H")
    qw = shift @ W.T  # (..., r)
    norm2 = np.sum(Hw**2, axis=0)  # H_i^T P^-1 H_i
    proj = qw @ Hw  # H_i^T P^-1 q
    f = proj / norm2
    total = np.sum(qw**2, axis=-1, keepdims=True)
    wssr = np.maximum(total - proj * f, 0.0)  # q^T P^-1 q - (H_i^T P^-1 q)^2 / (H_i^T P^-1 H_i)
    return Isolation(names, wssr, f, np.argmin(wssr, axis=-1))


def max_h_rule(
    h_shift: np.ndarray, S: np.ndarray, faults: Sequence[str] | None = None
) -> Isolation:
    """Naive isolation on the largest health-estimate change (seed 002 Table 7).

    h_shift : (..., p) change of h_hat; S : (p, n_f) library signatures.
    The score of fault i is the root-sum-square of h_shift over the health
    parameters the fault shifts (a module's efficiency and flow capacity; the
    absolute value for a single actuator bias); the largest score wins. A fault
    whose parameters are not in the estimated health vector scores 0.

    Returned as an ``Isolation`` whose ``wssr`` holds minus the score (so the
    argmin convention holds) and whose ``magnitude`` holds the score.
    """
    S = np.asarray(S, float)
    h_shift = np.asarray(h_shift, float)
    if h_shift.shape[-1] != S.shape[0]:
        raise IsolationError(
            f"h_shift: expected last dimension {S.shape[0]}, found {h_shift.shape}"
        )
    support = (S != 0.0).astype(float)  # (p, n_f)
    score = np.sqrt((h_shift**2) @ support)
    names = tuple(faults) if faults is not None else tuple(f"f{i}" for i in range(S.shape[1]))
    return Isolation(names, -score, score, np.argmax(score, axis=-1))


def misclassification_probability(
    H: np.ndarray, P: np.ndarray, magnitudes: np.ndarray | float = 1.0
) -> np.ndarray:
    """Pairwise probability of misclassification PMC[a, b] = P(b | a) (seed 002 eq. 24-26).

        q_a = H_a f_a
        q_b = H_b sqrt(q_a^T P^-1 q_a) / sqrt(H_b^T P^-1 H_b)                 (eq. 26)
        D_M = min(||q_a - q_b||_{P^-1}, ||q_a + q_b||_{P^-1})                (eq. 25)
        PMC_{b|a} = 1 - Phi(D_M / 2)                                         (eq. 24)

    Returns (n_f, n_f) with a zero diagonal; rows are the true fault.
    """
    _, Hw = _check_influence(H, P, "H")
    f = np.broadcast_to(np.asarray(magnitudes, float), (Hw.shape[1],))
    qa = Hw * f  # whitened q_a per column
    len_a = np.linalg.norm(qa, axis=0)  # (n_f,)
    unit = Hw / np.linalg.norm(Hw, axis=0)
    # q_b scaled to the weighted length of q_a: row a, column b
    qb = unit[:, None, :] * len_a[None, :, None]  # (r, a, b)
    d_minus = np.linalg.norm(qa[:, :, None] - qb, axis=0)
    d_plus = np.linalg.norm(qa[:, :, None] + qb, axis=0)
    pmc = 1.0 - ndtr(0.5 * np.minimum(d_minus, d_plus))
    np.fill_diagonal(pmc, 0.0)
    return pmc


def confusion_percent(true_index: np.ndarray, isolated: np.ndarray, n_faults: int) -> np.ndarray:
    """Confusion matrix in percent: rows true fault, columns isolated fault.

    true_index, isolated : same shape, integer fault indices. Rows with no
    samples are NaN.
    """
    t = np.asarray(true_index).ravel()
    i = np.asarray(isolated).ravel()
    counts = np.zeros((n_faults, n_faults))
    np.add.at(counts, (t, i), 1.0)
    rows = counts.sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return 100.0 * counts / rows


def correct_rate(percent: np.ndarray) -> float:
    """Overall correct isolation rate: mean of the diagonal (equal samples per fault)."""
    return float(np.nanmean(np.diag(percent)))


def bounded_fit(
    a: np.ndarray, b: np.ndarray, c: np.ndarray | float, bounds: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Seed 002 eq. 21-23 from its sums with the magnitude held to ``bounds`` (times the
    library's nominal shift): WSSR_i and f_i of every fault.

    a_i = H_i^T W H_i, b_i = H_i^T W q, c = q^T W q (any leading batch shape; ``c`` without
    the fault axis). WSSR_i(f) = c - 2 f b_i + f^2 a_i is a parabola in f, so its least value
    on the interval is at the free fit b_i / a_i clipped into it. A hypothesis that explains
    the change only at a magnitude the library does not mean (a fault of almost no signature
    scaled up a hundredfold, a large fault scaled down to a tenth, any fault with its sign
    reversed) then pays for it in WSSR instead of winning. A fault without signature
    (a_i = 0): f = 0, WSSR = c.
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    c = np.asarray(c, float)[..., None]
    lo, hi = bounds
    ok = a > 0
    f = np.where(ok, np.clip(b / np.where(ok, a, 1.0), lo, hi), 0.0)
    wssr = np.where(ok, np.maximum(c - 2.0 * f * b + f * f * a, 0.0), c)
    return wssr, f
