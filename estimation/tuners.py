"""Tuner selection V* (docs/math.md section 2) and the design record.

Methods, all returning a ``TunerDesign``:

1. ``subset_tuners``: V* = rows of the identity, best subset of health
   parameters by exhaustive search on the analytic objective.
2. ``svd_tuners``: seed 000 design procedure steps 1-6 (row-scaled SVD of
   G = [L; M; N], V* = V_k^T).
3. ``optimal_tuners``: V* minimising the analytic SSEE (health, or weighted
   aux) over all m x p matrices (seed 003), started from the best of 1 and 2.
4. ``diagnostic_tuners``: SSEE + lambda * sum of pairwise misclassification
   probabilities (seed 002 design 3, eq. 24-26).
5. ``sensor_selection``: exhaustive over sensor subsets of a candidate suite,
   each with its optimal tuners (seed 003).

The objective depends on V* only through its row space (q -> T q for an
invertible T gives the same filter in other coordinates), so the search runs
over a chart of the Grassmannian, V(X) = V0 + X N0 with N0 the orthonormal
complement of V0's rows: m (p - m) free parameters instead of m p, no flat
directions. Gradients are central differences, all perturbed designs
evaluated in one batched call (``theory.batched_errors``).
"""

from __future__ import annotations

import functools
import itertools
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.optimize

from estimation import isolation
from estimation.errors import ConvergenceWarning, DimensionError, UnobservableDesignError
from estimation.kalman import solve_or_nan, steady_state_gain
from estimation.model import LinearModel
from estimation.reduced import ReducedModel, reduced_model
from estimation.theory import (
    WITH_PROCESS_NOISE,
    ErrorProblem,
    Theory,
    analytic_errors,
    batched_errors,
    error_problem,
)

METHODS = ("subset", "svd", "optimal", "diagnostic")


@dataclass(frozen=True, eq=False)
class TunerDesign:
    """A steady-state reduced-order Kalman filter design and its analytic errors.

    model    : the design model (its sensors and health parameters)
    method   : "subset", "svd", "optimal", "diagnostic" or "explicit"
    vstar    : V* [m, p];  reduced: reduced-order matrices (A_xq, C_xq, F_xq, V*^+)
    gain     : K [n, ny] (n = nx + m);  P_prior, P_hat [n, n];  P_q [m, m]
    Gamma    : (I - A_xq + K C_xq A_xq)^-1 [n, n]
    theory   : analytic bias^2 and variance (health and aux)
    Q, Qh, Ph: the noise the design used;  objective: value the method minimised
    variance : how the theory's variance counts noise (``theory.WITH_PROCESS_NOISE``,
               the default, or ``theory.SENSOR_NOISE_ONLY``, the seeds' formula)
    """

    model: LinearModel
    method: str
    vstar: np.ndarray
    reduced: ReducedModel
    gain: np.ndarray
    P_prior: np.ndarray
    P_hat: np.ndarray
    P_q: np.ndarray
    Gamma: np.ndarray
    theory: Theory
    Q: np.ndarray
    Qh: np.ndarray
    Ph: np.ndarray
    objective: float
    variance: str = WITH_PROCESS_NOISE

    @property
    def n_tuners(self) -> int:
        return int(self.vstar.shape[0])

    @property
    def tuner_names(self) -> list[str]:
        return [f"q{i + 1}" for i in range(self.n_tuners)]

    def health_gain(self) -> np.ndarray:
        """Steady-state map from a constant sensor shift to h_hat: [0 V*^+] Gamma K [p, ny]."""
        return self.reduced.health_map() @ self.Gamma @ self.gain


def design_filter(
    model: LinearModel,
    vstar: np.ndarray,
    Q: np.ndarray,
    Qh: np.ndarray,
    Ph: np.ndarray,
    method: str = "explicit",
    health_weights: Sequence[float] | np.ndarray | None = None,
    aux_weights: Sequence[float] | np.ndarray | None = None,
    objective: float | None = None,
    variance: str = WITH_PROCESS_NOISE,
) -> TunerDesign:
    """Steady-state filter for a given V* with its analytic errors (docs/math.md sections 2-3).

    variance: see ``theory.analytic_errors``.
    Raises UnobservableDesignError when the sensors cannot estimate the tuners.
    """
    vstar = np.asarray(vstar, float)
    if vstar.ndim != 2 or vstar.shape[1] != model.n_health:
        raise DimensionError(
            f"Incompatible dimensions of V* matrix; expected (m, {model.n_health}) "
            f"but found {vstar.shape}"
        )
    if vstar.shape[0] > model.n_sensors:
        raise UnobservableDesignError(
            f"{vstar.shape[0]} tuners cannot be estimated from {model.n_sensors} sensors"
        )
    red = reduced_model(model, vstar, Q, Qh)
    gain = steady_state_gain(red.A, red.C, red.Q, model.R)
    errs = analytic_errors(model, red, gain.K, np.asarray(Ph, float), variance)
    if objective is None:
        wh = np.ones(model.n_health) if health_weights is None else np.asarray(health_weights)
        wz = np.zeros(model.n_aux) if aux_weights is None else np.asarray(aux_weights)
        objective = float(
            errs.theory.health_squared_error @ wh + errs.theory.aux_squared_error @ wz
        )
    return TunerDesign(
        model, method, vstar, red, gain.K, gain.P_prior, errs.P_hat, errs.P_q, errs.Gamma,
        errs.theory, np.asarray(Q, float), np.asarray(Qh, float), np.asarray(Ph, float),
        float(objective), variance,
    )


# ------------------------------------------------------------------------ subset


def _evaluate(problem: ErrorProblem, V: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Objective of a stack of V* [b, m, p], in chunks to bound memory; NaN = unobservable."""
    out = np.empty(V.shape[0])
    for i in range(0, V.shape[0], chunk):
        out[i : i + chunk] = batched_errors(problem, V[i : i + chunk]).objective
    return out


def _check_tuner_count(model: LinearModel, m: int) -> None:
    if not 1 <= m <= model.n_health:
        raise ValueError(f"number of tuners must be 1..{model.n_health}, got {m}")
    if m > model.n_sensors:
        raise UnobservableDesignError(
            f"{m} tuners cannot be estimated from {model.n_sensors} sensors "
            "(at most one tuner per sensor)"
        )


def best_subset(problem: ErrorProblem, p: int, m: int) -> tuple[np.ndarray, float]:
    """Exhaustive best subset (p choose m) of health parameters as tuners: (V*, objective)."""
    combos = list(itertools.combinations(range(p), m))
    V = np.zeros((len(combos), m, p))
    rows = np.arange(m)
    for i, c in enumerate(combos):
        V[i, rows, list(c)] = 1.0
    obj = _evaluate(problem, V)
    if not np.any(np.isfinite(obj)):
        raise UnobservableDesignError(
            f"no subset of {m} health parameters is observable from these sensors"
        )
    best = int(np.nanargmin(obj))
    return V[best], float(obj[best])


def subset_tuners(
    model: LinearModel,
    m: int,
    Q: np.ndarray,
    Qh: np.ndarray,
    Ph: np.ndarray,
    health_weights: Sequence[float] | np.ndarray | None = None,
    aux_weights: Sequence[float] | np.ndarray | None = None,
    *,
    variance: str = WITH_PROCESS_NOISE,
) -> TunerDesign:
    """Best subset of m health parameters as tuners (conventional approach, seed 003)."""
    _check_tuner_count(model, m)
    problem = error_problem(model, Q, Qh, Ph, health_weights, aux_weights, variance)
    V, _ = best_subset(problem, model.n_health, m)
    return design_filter(
        model, V, Q, Qh, Ph, "subset", health_weights, aux_weights, variance=variance
    )


def ols_select(A: np.ndarray, deltas: np.ndarray, m: int) -> np.ndarray:
    """Greedy orthogonal least squares: for each shift in ``deltas`` [n, r], the m columns
    of A [r, p] chosen one at a time, each the column that most reduces the residual
    after orthogonalising against those already chosen. Returns indices [n, m].
    Vectorised over the shifts.
    """
    A = np.asarray(A, float)
    n, p = deltas.shape[0], A.shape[1]
    W = np.broadcast_to(A, (n,) + A.shape).copy()  # columns orthogonalised per shift
    r = np.array(deltas, dtype=float)
    chosen = np.zeros((n, m), dtype=int)
    taken = np.zeros((n, p), dtype=bool)
    rows = np.arange(n)
    for step in range(m):
        norm2 = np.einsum("nrp,nrp->np", W, W)
        proj = np.einsum("nrp,nr->np", W, r)
        with np.errstate(divide="ignore", invalid="ignore"):
            score = np.where((norm2 > 1e-24) & ~taken, proj**2 / norm2, -np.inf)
        j = np.argmax(score, axis=1)
        chosen[:, step] = j
        taken[rows, j] = True
        qv = W[rows, :, j] / np.sqrt(np.maximum(norm2[rows, j], 1e-300))[:, None]  # [n, r]
        r -= qv * np.einsum("nr,nr->n", qv, r)[:, None]
        W -= qv[:, :, None] * np.einsum("nr,nrp->np", qv, W)[:, None, :]
    return chosen


def ols_tally(
    model: LinearModel,
    m: int,
    rng: np.random.Generator,
    n_draws: int = 2000,
    max_shift: float = 3.0,
    directions: Sequence[float] | np.ndarray | None = None,
    aux: Sequence[str] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Subset tuners by the orthogonal-least-squares tally of seed 000.

    The row-scaled G = [L; M; N_aux] of the SVD design (step 2) multiplies random
    health shifts p (each element uniform in 0..max_shift percent in its direction
    of degradation); OLS picks the m columns that best explain each shift
    delta = W G p; the m columns picked most often are the tuners.
    directions [p]: +1 or -1 per health parameter; default -1 except turbine flow
    capacities (names ending in ``t_flow``: hpt_flow, lpt_flow), which rise.
    Returns (V* [m, p] rows of the identity, tally [p] of selections).
    """
    names = model.aux_names if aux is None else list(aux)
    idx = model.index("aux", names) if names else []
    G = np.vstack([model.L, model.M, model.N[idx]])
    norms = np.linalg.norm(G, axis=1)
    WG = np.divide(1.0, norms, out=np.zeros_like(norms), where=norms > 0)[:, None] * G
    p = model.n_health
    if directions is None:
        sign = np.array([1.0 if n.lower().endswith("t_flow") else -1.0 for n in model.health_names])
    else:
        sign = np.asarray(directions, float)
        if sign.shape != (p,):
            raise DimensionError(f"directions: expected ({p},), found {sign.shape}")
    shifts = rng.uniform(0.0, max_shift, (n_draws, p)) * sign
    picks = ols_select(WG, shifts @ WG.T, m)
    tally = np.bincount(picks.ravel(), minlength=p)
    best = np.sort(np.argsort(-tally, kind="stable")[:m])
    return np.eye(p)[best], tally


# --------------------------------------------------------------------------- SVD


def svd_vstar(
    model: LinearModel,
    m: int,
    aux: Sequence[str] | None = None,
    row_weights: Sequence[float] | np.ndarray | None = None,
) -> np.ndarray:
    """SVD tuners, seed 000 design procedure steps 1-5: V* = V_k^T [m, p].

    1. G = [L; M; N_aux] (aux: the auxiliary outputs to include; default all).
    2. W = diag(1 / ||g_i||) times optional extra row weights [nx + ny + n_aux]
       (rows of zero norm carry no information and get weight 0).
    3. SVD of W G = (W U) Sigma V^T.  4-5. keep the k = m largest terms, V* = V_k^T
       (U* = U_k Sigma_k = G V_k, which is L V*^+ etc. in the reduced model).
    """
    names = model.aux_names if aux is None else list(aux)
    idx = model.index("aux", names) if names else []
    G = np.vstack([model.L, model.M, model.N[idx]])
    norms = np.linalg.norm(G, axis=1)
    w = np.divide(1.0, norms, out=np.zeros_like(norms), where=norms > 0)  # step 2
    if row_weights is not None:
        extra = np.asarray(row_weights, float)
        if extra.shape != w.shape:
            raise DimensionError(
                f"Incompatible dimensions of SVD row weights; expected {w.shape} "
                f"(states, sensors, aux rows) but found {extra.shape}"
            )
        w = w * extra
    _, _, Vt = np.linalg.svd(w[:, None] * G, full_matrices=True)  # step 3
    return Vt[:m].copy()  # step 5: V* = V_k^T


def svd_tuners(
    model: LinearModel,
    m: int,
    Q: np.ndarray,
    Qh: np.ndarray,
    Ph: np.ndarray,
    aux: Sequence[str] | None = None,
    row_weights: Sequence[float] | np.ndarray | None = None,
    health_weights: Sequence[float] | np.ndarray | None = None,
    aux_weights: Sequence[float] | np.ndarray | None = None,
    *,
    variance: str = WITH_PROCESS_NOISE,
) -> TunerDesign:
    """SVD tuners (seed 000 steps 1-6) with the steady-state filter for them."""
    _check_tuner_count(model, m)
    V = svd_vstar(model, m, aux, row_weights)
    return design_filter(
        model, V, Q, Qh, Ph, "svd", health_weights, aux_weights, variance=variance
    )


# ----------------------------------------------------------------------- optimal


class SearchResult(NamedTuple):
    """vstar [m, p]; objective at vstar; start_objective; iterations; evaluations."""

    vstar: np.ndarray
    objective: float
    start_objective: float
    iterations: int
    evaluations: int


def _chart(V0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal rows spanning V0's row space [m, p] and their complement [p - m, p]."""
    m, p = V0.shape
    Qfull, _ = np.linalg.qr(V0.T, mode="complete")
    return Qfull[:, :m].T, Qfull[:, m:].T


def chart_gradient(
    objective: Callable[[np.ndarray], np.ndarray],
    base: np.ndarray,
    comp: np.ndarray,
    X: np.ndarray,
    step: float = 1e-5,
) -> tuple[float, np.ndarray]:
    """Value and central-difference gradient [m, p - m] of f(base + X comp) at X.

    All 2 m (p - m) + 1 designs go to ``objective`` as one stack. Where a
    perturbed design is infeasible (near the observability boundary) the
    one-sided difference of the other side is used.
    """
    m, q = X.shape
    k = m * q
    eye = np.eye(k).reshape(k, m, q)
    stack = np.concatenate([X[None], X[None] + step * eye, X[None] - step * eye])
    vals = objective(base + stack @ comp)
    f = float(vals[0])
    fwd, bwd = vals[1 : k + 1], vals[k + 1 :]
    with np.errstate(invalid="ignore"):
        grad = (fwd - bwd) / (2.0 * step)
        grad = np.where(np.isfinite(grad), grad, (fwd - f) / step)
        grad = np.where(np.isfinite(grad), grad, (f - bwd) / step)
    return f, np.where(np.isfinite(grad), grad, 0.0).reshape(m, q)


class _ChartObjective:
    """f and gradient over the flattened chart coordinates, for scipy.optimize."""

    def __init__(self, objective, base, comp, step, penalty):  # type: ignore[no-untyped-def]
        self.objective, self.base, self.comp = objective, base, comp
        self.step, self.penalty, self.count = step, penalty, 0

    def __call__(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        m, q = self.base.shape[0], self.comp.shape[0]
        f, grad = chart_gradient(self.objective, self.base, self.comp, x.reshape(m, q), self.step)
        self.count += 2 * m * q + 1
        if not np.isfinite(f):
            return self.penalty, np.zeros(m * q)
        return f, grad.ravel()


def gradient_search(
    objective: Callable[[np.ndarray], np.ndarray],
    V0: np.ndarray,
    step: float = 1e-5,
    max_iter: int = 200,
    restarts: int = 3,
    gtol: float = 1e-7,
) -> SearchResult:
    """Minimise a row-space-invariant objective of V [m, p] from V0 (seed 003 search).

    objective maps a stack [b, m, p] to values [b] (NaN = infeasible). Each pass
    minimises f(V0 + X N0) over X [m, p - m] by BFGS with central-difference
    gradients (one batched call of 2 m (p - m) + 1 designs per gradient); the
    chart is re-centred after each pass. Never returns worse than V0.
    """
    V0 = np.asarray(V0, float)
    m, p = V0.shape
    f0 = float(objective(V0[None])[0])
    if not np.isfinite(f0):
        raise UnobservableDesignError("the starting tuners are not observable")
    best_V, best_f = V0.copy(), f0
    iterations = evaluations = 0
    hit_limit = False
    if m == p:
        return SearchResult(best_V, best_f, f0, 0, 1)
    for _ in range(restarts):
        base, comp = _chart(best_V)
        k = m * (p - m)
        # Penalty for infeasible points: finite so the line search can back off.
        penalty = 10.0 * (abs(best_f) + 1.0)
        fun = _ChartObjective(objective, base, comp, step, penalty)
        res = scipy.optimize.minimize(
            fun, np.zeros(k), jac=True, method="BFGS",
            options={"maxiter": max_iter, "gtol": gtol * max(1.0, abs(best_f))},
        )
        iterations += int(res.nit)
        evaluations += fun.count
        hit_limit = res.status == 1  # scipy: maximum number of iterations reached
        V_new = base + res.x.reshape(m, p - m) @ comp
        f_new = float(objective(V_new[None])[0])
        evaluations += 1
        if not (np.isfinite(f_new) and f_new < best_f - 1e-12 * abs(best_f)):
            break
        improved = best_f - f_new
        best_V, best_f = V_new, f_new
        if improved <= 1e-9 * abs(best_f):
            break
    if hit_limit:
        warnings.warn(
            f"tuner search stopped at its iteration limit ({max_iter} per pass) while still "
            f"improving: objective {best_f:.6g} from {f0:.6g}; raise max_iter for more",
            ConvergenceWarning,
            stacklevel=2,
        )
    if best_f == f0:
        return SearchResult(V0.copy(), f0, f0, iterations, evaluations)
    # Report V* with orthonormal rows: same filter, well-conditioned numbers.
    Vn, _ = _chart(best_V)
    return SearchResult(_sign_fix(Vn, best_V), best_f, f0, iterations, evaluations)


def _sign_fix(Vn: np.ndarray, V: np.ndarray) -> np.ndarray:
    """Orthonormal basis of V's row space, rotated to be as close to V's rows as possible."""
    # Procrustes: T = argmin ||T Vn - V|| over orthogonal T keeps tuners recognisable.
    U, _, Wt = np.linalg.svd(V @ Vn.T)
    return (U @ Wt) @ Vn


def optimal_tuners(
    model: LinearModel,
    m: int,
    Q: np.ndarray,
    Qh: np.ndarray,
    Ph: np.ndarray,
    health_weights: Sequence[float] | np.ndarray | None = None,
    aux_weights: Sequence[float] | np.ndarray | None = None,
    start: np.ndarray | None = None,
    max_iter: int = 200,
    multi_start: bool = False,
    *,
    variance: str = WITH_PROCESS_NOISE,
) -> TunerDesign:
    """Optimal tuners (seed 003, Simon & Garg 2010): argmin over V* [m, p] of the analytic
    objective w_h . SSE_h + w_z . SSE_z (default: health SSEE).

    Starts from ``start`` or from the better of the best subset and the SVD tuners
    (SVD rows weighted towards the aux outputs in the objective); with
    ``multi_start`` the other of the two is searched from as well and the better
    end point kept. Never returns a design worse than its start.
    """
    _check_tuner_count(model, m)
    problem = error_problem(model, Q, Qh, Ph, health_weights, aux_weights, variance)
    if start is not None:
        starts = [np.asarray(start, float)]
    else:
        cands = start_candidates(model, problem, m)
        starts = [c.vstar for c in (cands if multi_start else cands[:1])]
    result = search_from_starts(lambda V: _evaluate(problem, V), starts, max_iter)
    return design_filter(
        model, result.vstar, Q, Qh, Ph, "optimal", health_weights, aux_weights,
        variance=variance,
    )


class Start(NamedTuple):
    """A starting point of the optimal search: method ("subset" or "svd"), V*, objective."""

    method: str
    vstar: np.ndarray
    objective: float


def start_candidates(model: LinearModel, problem: ErrorProblem, m: int) -> list[Start]:
    """Best-subset and SVD tuners with their objectives, best first (observable ones only).

    The SVD stacks the aux rows the objective weights (seed 000 step 1).
    """
    candidates = []
    try:
        candidates.append(Start("subset", *best_subset(problem, model.n_health, m)))
    except UnobservableDesignError:
        pass
    aux = [a for a, w in zip(model.aux_names, problem.aux_weights, strict=True) if w > 0]
    V_svd = svd_vstar(model, m, aux)
    f_svd = _evaluate(problem, V_svd[None])[0]
    if np.isfinite(f_svd):
        candidates.append(Start("svd", V_svd, float(f_svd)))
    if not candidates:
        raise UnobservableDesignError(
            f"neither subset nor SVD tuners ({m}) are observable from these sensors"
        )
    return sorted(candidates, key=lambda c: c.objective)


def _start(model: LinearModel, problem: ErrorProblem, m: int) -> np.ndarray:
    """Better of the best subset and the SVD tuners under the problem's objective."""
    return start_candidates(model, problem, m)[0].vstar


def search_from_starts(
    objective: Callable[[np.ndarray], np.ndarray],
    starts: Sequence[np.ndarray],
    max_iter: int = 200,
) -> SearchResult:
    """gradient_search from each start; the best result (ties: the earlier start)."""
    best: SearchResult | None = None
    for V0 in starts:
        r = gradient_search(objective, V0, max_iter=max_iter)
        if best is None or r.objective < best.objective:
            best = r
    assert best is not None
    return best


# ------------------------------------------------------------ diagnostics-aware


class FaultProblem(NamedTuple):
    """Fault influence data: Gy_full [ny, p_full] (health plus actuator biases),
    signatures S [p_full, n_faults], fault names."""

    Gy_full: np.ndarray
    S: np.ndarray
    faults: tuple[str, ...]


def fault_problem(
    model: LinearModel, faults: Sequence[isolation.Fault] | None = None
) -> FaultProblem:
    """G_y over the full health vector (seed 002 eq. 13, 17) and the library signatures."""
    full = isolation.full_health(
        model.L, model.M, model.N, model.B, model.D, model.G,
        model.health_names, model.input_names,
    )
    lib = isolation.default_faults() if faults is None else tuple(faults)
    S = isolation.signature_matrix(lib, full.names)
    n = model.n_states
    Gy_full = model.C @ np.linalg.solve(np.eye(n) - model.A, full.L) + full.M
    return FaultProblem(Gy_full, S, tuple(f.name for f in lib))


def misclassification_sum(
    K: np.ndarray,
    Phi: np.ndarray,
    P_hat: np.ndarray,
    faults: FaultProblem,
    n_states: int,
) -> np.ndarray:
    """Sum over fault pairs of PMC_{b|a} (seed 002 eq. 24-26) for a stack of designs [b].

    K [b, n, ny], Phi [b, n, n], P_hat [b, n, n] as in ``theory.BatchedErrors``;
    H = [0 I_m] Gamma K G_y,full S, P_q = [0 I_m] P_hat [0 I_m]^T per design.
    """
    b, n, _ = Phi.shape
    out = np.full(b, np.nan)
    with np.errstate(all="ignore"):
        X = solve_or_nan(np.eye(n) - Phi, K @ faults.Gy_full)
    H = X[:, n_states:, :] @ faults.S
    Pq = P_hat[:, n_states:, n_states:]
    for i in range(b):
        if not (np.all(np.isfinite(H[i])) and np.all(np.isfinite(Pq[i]))):
            continue
        try:
            out[i] = float(np.sum(isolation.misclassification_probability(H[i], Pq[i])))
        except isolation.IsolationError:
            continue
    return out


def diagnostic_tuners(
    model: LinearModel,
    m: int,
    Q: np.ndarray,
    Qh: np.ndarray,
    Ph: np.ndarray,
    lam: float,
    faults: Sequence[isolation.Fault] | None = None,
    health_weights: Sequence[float] | np.ndarray | None = None,
    aux_weights: Sequence[float] | np.ndarray | None = None,
    start: np.ndarray | None = None,
    max_iter: int = 200,
    *,
    variance: str = WITH_PROCESS_NOISE,
) -> TunerDesign:
    """Diagnostics-aware optimal tuners (seed 002 KF design 3): minimise

        SSEE(V*) + lam * sum_{a != b} PMC_{b|a}(V*)

    over V* [m, p], started from the better (under this objective) of the SSEE-optimal
    tuners and ``start``. Faults default to seed 002 Table 3; actuator biases
    enter through B, D (seed 002 eq. 13).
    """
    _check_tuner_count(model, m)
    problem = error_problem(model, Q, Qh, Ph, health_weights, aux_weights, variance)
    fp = fault_problem(model, faults)

    def objective(V: np.ndarray) -> np.ndarray:
        out = np.empty(V.shape[0])
        for i in range(0, V.shape[0], 256):
            e = batched_errors(problem, V[i : i + 256])
            pmc = misclassification_sum(e.K, e.Phi, e.P_hat, fp, model.n_states)
            out[i : i + 256] = e.objective + lam * pmc
        return out

    ssee_opt = optimal_tuners(
        model, m, Q, Qh, Ph, health_weights, aux_weights, max_iter=max_iter, variance=variance
    )
    starts = [ssee_opt.vstar] + ([np.asarray(start, float)] if start is not None else [])
    vals = objective(np.stack(starts))
    V0 = starts[int(np.nanargmin(vals))]
    result = gradient_search(objective, V0, max_iter=max_iter)
    return design_filter(
        model, result.vstar, Q, Qh, Ph, "diagnostic", health_weights, aux_weights,
        objective=result.objective, variance=variance,
    )


def diagnostic_objective_terms(
    design: TunerDesign, faults: Sequence[isolation.Fault] | None = None
) -> np.ndarray:
    """PMC matrix [n_faults, n_faults] (rows true fault) of a finished design."""
    fp = fault_problem(design.model, faults)
    nx = design.model.n_states
    X = design.Gamma @ design.gain @ fp.Gy_full
    H = X[nx:, :] @ fp.S
    return isolation.misclassification_probability(H, design.P_q)


# ------------------------------------------------------------ sensor selection


class SensorSuite(NamedTuple):
    """One candidate sensor suite: sensors, tuners m, best-subset and optimal objectives
    (NaN where no design is observable), and the optimal V* [m, p] (None if NaN)."""

    sensors: tuple[str, ...]
    n_tuners: int
    subset_objective: float
    optimal_objective: float
    vstar: np.ndarray | None


def sensor_selection(
    model: LinearModel,
    base: Sequence[str],
    optional: Sequence[str],
    Q: np.ndarray,
    Qh: np.ndarray,
    Ph: np.ndarray,
    n_tuners: int | None = None,
    health_weights: Sequence[float] | np.ndarray | None = None,
    aux_weights: Sequence[float] | np.ndarray | None = None,
    max_iter: int = 200,
    progress: Callable[[int, int], None] | None = None,
    *,
    variance: str = WITH_PROCESS_NOISE,
) -> list[SensorSuite]:
    """Combined sensor and tuner selection (seed 003): every subset of ``optional``
    added to ``base``, each with its best-subset and optimal tuners.

    n_tuners defaults to min(number of sensors, p) per suite (seed 003's
    table); a fixed n_tuners larger than a suite's sensors marks it NaN.
    Returns one SensorSuite per subset (2^len(optional)), in enumeration order;
    pick the best per size with ``best_suites``.

    Each suite's search starts from the best, under that suite's objective, of its
    best subset, its SVD tuners and the optimal V* already found for the other
    suites with the same number of tuners (V* lives in health space, so it
    carries over; neighbouring suites share most of their optimum). A start is
    never worse than the suite's own subset and SVD tuners.
    """
    p = model.n_health
    out: list[SensorSuite] = []
    found: dict[int, list[np.ndarray]] = {}  # optimal V* of earlier suites, by m
    subsets = [
        c for r in range(len(optional) + 1) for c in itertools.combinations(optional, r)
    ]
    for i, extra in enumerate(subsets):
        sensors = tuple(base) + tuple(extra)
        sub = model.select_sensors(list(sensors))
        m = min(len(sensors), p) if n_tuners is None else n_tuners
        cands: list[Start] = []
        problem = error_problem(sub, Q, Qh, Ph, health_weights, aux_weights, variance)
        if 1 <= m <= len(sensors):
            try:
                cands = start_candidates(sub, problem, m)
            except UnobservableDesignError:
                cands = []
        fs = next((c.objective for c in cands if c.method == "subset"), math.nan)
        if not cands:
            out.append(SensorSuite(sensors, m, fs, math.nan, None))
        else:
            objective = functools.partial(_evaluate, problem)
            V0 = cands[0].vstar
            if found.get(m):
                earlier = np.stack(found[m])
                vals = objective(earlier)
                if np.any(np.isfinite(vals)) and np.nanmin(vals) < cands[0].objective:
                    V0 = earlier[int(np.nanargmin(vals))]
            res = gradient_search(objective, V0, max_iter=max_iter)
            found.setdefault(m, []).append(res.vstar)
            out.append(SensorSuite(sensors, m, fs, res.objective, res.vstar))
        if progress is not None:
            progress(i + 1, len(subsets))
    return out


def best_suites(suites: Sequence[SensorSuite], by: str = "optimal") -> dict[int, SensorSuite]:
    """Best suite per number of sensors, by ``optimal`` or ``subset`` objective."""
    key = "optimal_objective" if by == "optimal" else "subset_objective"
    best: dict[int, SensorSuite] = {}
    for s in suites:
        v = getattr(s, key)
        if not np.isfinite(v):
            continue
        n = len(s.sensors)
        if n not in best or v < getattr(best[n], key):
            best[n] = s
    return dict(sorted(best.items()))
