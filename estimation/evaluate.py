"""Monte Carlo experiments that check the analytic design figures (seeds 002, 003).

- ``ssee_monte_carlo``: seed 002 Table 5. Random fleet health h ~ N(0, P_h) per
  case, the linear model simulated open loop (u = 0) with process and sensor
  noise, the steady-state filter on the simulated sensors, squared error of
  h_hat averaged over the last ``window`` seconds, then over cases; theory
  (``TunerDesign.theory``) next to it per health parameter.
- ``isolation_experiment``: seed 002 Tables 6-9. Each library fault held from
  t = 0 on the full health vector (health plus actuator biases, seed 002
  eq. 13), a decision at every step by WSSR on q_hat, WSSR on y_hat and the
  max-|h_hat| rule; confusion matrices in percent.
- ``sensor_table``: seed 003's SSEE against the number of sensors, best-subset
  against optimal tuners.

Every experiment is batched over cases (one matrix product per step through
``kalman.filter_stream_states``), draws from the ``rng`` it is given and
reports progress as a fraction done through ``progress``.
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from estimation import isolation, theory
from estimation.kalman import filter_stream_states
from estimation.model import LinearModel
from estimation.tuners import (
    TunerDesign,
    best_suites,
    optimal_tuners,
    sensor_selection,
)

Progress = Callable[[float], None]

VARIANTS = ("wssr_q", "wssr_y", "max_h")


class ExperimentError(ValueError):
    """An experiment whose settings or designs do not fit together."""


def _noise_std(cov: np.ndarray, name: str) -> np.ndarray:
    """A factor G with G G^T = cov (Cholesky, or eigen for a semidefinite cov)."""
    cov = 0.5 * (np.asarray(cov, float) + np.asarray(cov, float).T)
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        lam, U = np.linalg.eigh(cov)
        if lam.min() < -1e-10 * max(1.0, lam.max()):
            raise ExperimentError(f"{name} is not positive semidefinite") from None
        return U * np.sqrt(np.clip(lam, 0.0, None))


def _simulate_block(
    A: np.ndarray,
    C: np.ndarray,
    drive_x: np.ndarray,
    drive_y: np.ndarray,
    x: np.ndarray,
    n_steps: int,
    q_factor: np.ndarray | None,
    r_std: np.ndarray | None,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Open-loop truth over one block of steps, batched over cases.

        y[k]   = C x[k] + drive_y + v[k]        v ~ N(0, diag(r_std^2))
        x[k+1] = A x[k] + drive_x + w[k]        w ~ N(0, q_factor q_factor^T)

    drive_x [E, nx] = L h, drive_y [E, ny] = M h (constant health);
    x [E, nx] is x at the block's first step. Returns y [n_steps, E, ny] and
    x after the block.
    """
    E, nx = x.shape
    ny = C.shape[0]
    xs = np.empty((n_steps, E, nx))
    if q_factor is not None:
        w = rng.standard_normal((n_steps, E, nx)) @ q_factor.T
    AT = A.T
    for k in range(n_steps):
        xs[k] = x
        x = x @ AT + drive_x
        if q_factor is not None:
            x = x + w[k]
    y = xs @ C.T + drive_y
    if r_std is not None:
        y += rng.standard_normal((n_steps, E, ny)) * r_std
    return y, x


# ------------------------------------------------------------------ SSEE (Table 5)


@dataclass(frozen=True)
class SseeExperiment:
    """Monte Carlo squared estimation error of h_hat next to the analytic figures.

    health_names    : p names
    squared_error   : (p,) experimental mean squared error, percent^2
    standard_error  : (p,) its standard error across cases
    theory_bias2, theory_variance : (p,) analytic terms of the design
    n_cases, duration, window : experiment settings (s)
    """

    health_names: tuple[str, ...]
    squared_error: np.ndarray
    standard_error: np.ndarray
    theory_bias2: np.ndarray
    theory_variance: np.ndarray
    n_cases: int
    duration: float
    window: float

    @property
    def theory_squared_error(self) -> np.ndarray:
        return self.theory_bias2 + self.theory_variance

    @property
    def ssee(self) -> float:
        return float(np.sum(self.squared_error))

    @property
    def ssee_theory(self) -> float:
        return float(np.sum(self.theory_squared_error))

    def to_dict(self) -> dict[str, object]:
        return {
            "n_cases": self.n_cases,
            "duration_s": self.duration,
            "window_s": self.window,
            "health": {
                "names": list(self.health_names),
                "squared_error": self.squared_error.tolist(),
                "standard_error": self.standard_error.tolist(),
                "theory_bias2": self.theory_bias2.tolist(),
                "theory_variance": self.theory_variance.tolist(),
                "theory_squared_error": self.theory_squared_error.tolist(),
            },
            "ssee_health": self.ssee,
            "ssee_health_theory": self.ssee_theory,
        }


def ssee_monte_carlo(
    design: TunerDesign,
    n_cases: int = 200,
    *,
    rng: np.random.Generator,
    duration: float = 30.0,
    window: float = 10.0,
    process_noise: bool = True,
    start: str = "healthy",
    chunk: int = 512,
    progress: Progress | None = None,
) -> SseeExperiment:
    """Seed 002 Table 5 experiment for one design.

    Each case draws h ~ N(0, P_h) (design.Ph), runs the design model open loop
    for ``duration`` s at its dt with sensor noise R (and state process noise
    design.Q when ``process_noise``), filters with the design's steady-state
    gain and averages (h_hat - h)^2 over the last ``window`` s. Cases run in
    batches of ``chunk``.

    start : "healthy" (seed 002: truth from x = 0 and filter from x_hat = 0;
            slow states, e.g. metal temperatures, may not have settled by the
            window) or "steady" (truth at its steady state (I - A)^-1 L h and
            filter at Gamma K G_y h, plus a draw of the joint fluctuation
            [x~; e] from its stationary covariance (``theory.joint_covariance``;
            e ~ N(0, P_hat) alone without process noise): the stationary regime
            the theory describes, exactly).

    The theory columns are the design's analytic errors for the noise actually
    simulated: variance with process noise when ``process_noise`` (the design's
    figures when it was made ``WITH_PROCESS_NOISE``, the default), from sensor
    noise only otherwise.
    """
    model = design.model
    dt = model.dt
    n_steps = int(round(duration / dt))
    n_win = int(round(window / dt))
    if n_cases < 2 or not 0 < n_win <= n_steps:
        raise ExperimentError(
            f"need n_cases >= 2 and 0 < window <= duration, got {n_cases}, {window}, {duration}"
        )
    red = design.reduced
    nx, p = model.n_states, model.n_health
    ph_factor = _noise_std(design.Ph, "Ph")
    q_factor = _noise_std(design.Q, "Q") if process_noise else None
    if start not in ("healthy", "steady"):
        raise ExperimentError(f"start must be 'healthy' or 'steady', got {start!r}")
    Gy, _ = model.steady_state_gains()
    mean_map = isolation.filter_steady_state_map(red.A, red.C, design.gain, Gy)
    mode = theory.WITH_PROCESS_NOISE if process_noise else theory.SENSOR_NOISE_ONLY
    if mode == design.variance:
        expected = design.theory
    else:
        expected = theory.analytic_errors(model, red, design.gain, design.Ph, mode).theory
    n = red.A.shape[0]
    joint = np.zeros((nx + n, nx + n))
    if q_factor is not None:
        joint = theory.joint_covariance(model, red, design.gain)
    else:
        joint[nx:, nx:] = theory.analytic_errors(
            model, red, design.gain, design.Ph, theory.SENSOR_NOISE_ONLY
        ).P_hat
    spread = _noise_std(joint, "stationary covariance")
    per_case = np.empty((n_cases, p))
    done = 0
    while done < n_cases:
        E = min(chunk, n_cases - done)
        h = rng.standard_normal((E, p)) @ ph_factor.T
        x0, xh0 = np.zeros((E, nx)), None
        if start == "steady":
            # x_hat[-1] and x[0] = A x[-1] + L h + w[-1]: the joint state one step
            # apart, as in the joint system (theory module docstring).
            fluct = rng.standard_normal((E, nx + n)) @ spread.T
            x_prev = np.linalg.solve(np.eye(nx) - model.A, model.L @ h.T).T + fluct[:, :nx]
            x0 = x_prev @ model.A.T + h @ model.L.T
            if q_factor is not None:
                x0 += rng.standard_normal((E, nx)) @ q_factor.T
            xh0 = h @ mean_map.T + fluct[:, nx:]
        y, _ = _simulate_block(
            model.A, model.C, h @ model.L.T, h @ model.M.T, x0, n_steps,
            q_factor, model.sensor_noise_std, rng,
        )
        x_hat = filter_stream_states(red.A, red.C, design.gain, y, x0=xh0)
        h_hat = x_hat[-n_win:, :, nx:] @ red.vstar_pinv.T  # seed 002 eq. 11
        per_case[done : done + E] = np.mean((h_hat - h) ** 2, axis=0)
        done += E
        if progress is not None:
            progress(done / n_cases)
    return SseeExperiment(
        tuple(model.health_names),
        per_case.mean(axis=0),
        per_case.std(axis=0, ddof=1) / np.sqrt(n_cases),
        np.array(expected.health_bias2),
        np.array(expected.health_variance),
        n_cases,
        n_steps * dt,
        n_win * dt,
    )


# ----------------------------------------------------------- isolation (Tables 6-9)


@dataclass(frozen=True)
class FaultInfluence:
    """Fault influence of one design over a fault library (seed 002 eq. 19-20).

    faults : names; S_full (p_full, n_f) shifts over full_names (health + biases)
    H_q (m, n_f), P_q (m, m): tuner space; H_y (ny, n_f), P_y (ny, ny): y_hat space
    S_design (p, n_f): shifts restricted to the design's health parameters
    """

    faults: tuple[str, ...]
    full_names: tuple[str, ...]
    S_full: np.ndarray
    H_q: np.ndarray
    P_q: np.ndarray
    H_y: np.ndarray
    P_y: np.ndarray
    S_design: np.ndarray


def fault_influence(
    design: TunerDesign,
    faults: Sequence[isolation.Fault] | None = None,
    truth: LinearModel | None = None,
) -> FaultInfluence:
    """H and covariances for WSSR isolation of ``design`` (docs/math.md section 4).

    truth : model whose health (plus actuator biases) the faults shift; default
            the design model. It must share the design model's states and sensors.
    """
    lib = isolation.default_faults() if faults is None else tuple(faults)
    truth = _truth_model(design, truth)
    full = _full(truth)
    S = isolation.signature_matrix(lib, full.names)
    Gy_full = isolation.steady_state_gain(truth.A, full.L, truth.C, full.M)
    red = design.reduced
    H_q = isolation.tuner_fault_influence(red.A, red.C, design.gain, Gy_full, S, red.n_tuners)
    H_y = isolation.sensor_fault_influence(red.A, red.C, design.gain, Gy_full, S)
    P_y = red.C @ design.P_hat @ red.C.T
    rows = [full.names.index(n) for n in design.model.health_names]
    return FaultInfluence(
        tuple(f.name for f in lib), full.names, S, H_q, design.P_q, H_y,
        0.5 * (P_y + P_y.T), S[rows],
    )


def _truth_model(design: TunerDesign, truth: LinearModel | None) -> LinearModel:
    if truth is None:
        truth = design.model
    else:
        truth = truth.select_sensors(design.model.sensor_names)
    names = _full(truth).names
    missing = [n for n in design.model.health_names if n not in names]
    if missing:
        raise ExperimentError(f"truth model lacks the design's health parameters {missing}")
    if not (np.allclose(truth.A, design.model.A) and truth.dt == design.model.dt):
        raise ExperimentError("truth and design models have different dynamics (A, dt)")
    return truth


def _full(truth: LinearModel) -> isolation.FullHealth:
    """Truth health vector plus actuator biases (seed 002 eq. 13)."""
    return isolation.full_health(
        truth.L, truth.M, truth.N, truth.B, truth.D, truth.G,
        truth.health_names, truth.input_names,
    )


@dataclass(frozen=True)
class Confusion:
    """Confusion matrix of one isolation variant: rows true fault, columns isolated, percent."""

    variant: str
    faults: tuple[str, ...]
    percent: np.ndarray

    @property
    def correct_rate(self) -> float:
        """Overall correct isolation rate in percent (seed 002 tables' last line)."""
        return isolation.correct_rate(self.percent)

    def to_dict(self) -> dict[str, object]:
        return {
            "faults": list(self.faults),
            "percent": self.percent.tolist(),
            "correct_rate": self.correct_rate,
        }


@dataclass(frozen=True)
class IsolationExperiment:
    """Confusion matrices per variant, and the settings of the run."""

    confusion: Mapping[str, Confusion]
    duration: float
    runs_per_fault: int
    settle: float
    noise: bool


def isolation_experiment(
    design: TunerDesign,
    faults: Sequence[isolation.Fault] | None = None,
    *,
    rng: np.random.Generator,
    truth: LinearModel | None = None,
    duration: float = 300.0,
    runs_per_fault: int = 1,
    settle: float = 0.0,
    noise: bool = True,
    process_noise: bool = True,
    max_h_design: TunerDesign | None = None,
    diagnostic: TunerDesign | None = None,
    start: str = "healthy",
    block: int = 2000,
    progress: Progress | None = None,
) -> IsolationExperiment:
    """Seed 002 Tables 6-9: confusion matrices of single-fault isolation.

    Each fault of the library (default seed 002 Table 3) is applied from t = 0
    at its nominal size on the truth model (default the design model, extended
    by actuator biases through B, D), simulated open loop for ``duration`` s
    with sensor noise R (and process noise design.Q) when ``noise``; the
    design's filter starts from 0 (the healthy baseline) and a decision is made
    at every step after ``settle`` s:

    - ``wssr_q``: WSSR on q_hat with H_q, P_q (seed 002 Table 6)
    - ``wssr_y``: WSSR on y_hat = C_xq x_hat with H_y, C_xq P_hat C_xq^T (Table 9)
    - ``max_h``: largest module change of h_hat (Table 7), from ``max_h_design``
      (seed 002 design 2, health plus actuator biases) when given, else from
      the design itself (faults outside its health vector then never win)
    - ``wssr_q_diagnostic``: WSSR on q_hat of ``diagnostic`` (Table 8), if given

    start : "healthy" (seed 002: truth and filter from 0, the fault present
            from t = 0, so the filter's transient is part of the statistics) or
            "steady" (truth at its faulty steady state, each filter at its
            quasi-steady estimate Gamma K G_y h plus a draw from N(0, P_hat):
            the stationary state when there is no process noise).
    """
    lib = isolation.default_faults() if faults is None else tuple(faults)
    truth_model = _truth_model(design, truth)
    designs: dict[str, TunerDesign] = {"main": design}
    if max_h_design is not None:
        designs["max_h"] = max_h_design
    if diagnostic is not None:
        designs["diagnostic"] = diagnostic
    for name, d in designs.items():
        if d.model.sensor_names != design.model.sensor_names or d.model.dt != design.model.dt:
            raise ExperimentError(f"{name} design must use the same sensors and dt as the design")
    infl = {name: fault_influence(d, lib, truth_model) for name, d in designs.items()}
    ref = infl["main"]
    full = _full(truth_model)
    n_f = len(lib)
    E = n_f * runs_per_fault
    true_index = np.repeat(np.arange(n_f), runs_per_fault)
    h_full = ref.S_full.T[true_index]  # (E, p_full)
    drive_x, drive_y = h_full @ full.L.T, h_full @ full.M.T
    nx = truth_model.n_states
    n_steps = int(round(duration / design.model.dt))
    n_settle = int(round(settle / design.model.dt))
    q_factor = _noise_std(design.Q, "Q") if (noise and process_noise) else None
    r_std = truth_model.sensor_noise_std if noise else None

    variants: dict[str, tuple[TunerDesign, Callable[[np.ndarray], np.ndarray]]] = {}
    red = design.reduced
    variants["wssr_q"] = (
        design,
        lambda x: isolation.wssr_isolate(x[..., nx:], ref.H_q, ref.P_q).isolated,
    )
    variants["wssr_y"] = (
        design,
        lambda x: isolation.wssr_isolate(x @ red.C.T, ref.H_y, ref.P_y).isolated,
    )
    hd = designs.get("max_h", design)
    hi = infl.get("max_h", ref)
    variants["max_h"] = (
        hd,
        lambda x: isolation.max_h_rule(
            x[..., nx:] @ hd.reduced.vstar_pinv.T, hi.S_design
        ).isolated,
    )
    if diagnostic is not None:
        di = infl["diagnostic"]
        variants["wssr_q_diagnostic"] = (
            diagnostic,
            lambda x: isolation.wssr_isolate(x[..., nx:], di.H_q, di.P_q).isolated,
        )

    counts = {v: np.zeros((n_f, n_f)) for v in variants}
    filters = {id(d): d for d, _ in variants.values()}
    if start == "healthy":
        x_true = np.zeros((E, nx))
        x_hat = {k: np.zeros((E, d.reduced.A.shape[0])) for k, d in filters.items()}
    elif start == "steady":
        x_true = np.linalg.solve(np.eye(nx) - truth_model.A, drive_x.T).T
        Gy_full = isolation.steady_state_gain(truth_model.A, full.L, truth_model.C, full.M)
        x_hat = {}
        for k, d in filters.items():
            mean = isolation.filter_steady_state_map(d.reduced.A, d.reduced.C, d.gain, Gy_full)
            spread = _noise_std(d.P_hat, "P_hat")
            z = rng.standard_normal((E, spread.shape[0]))
            x_hat[k] = h_full @ mean.T + (z @ spread.T if noise else 0.0)
    else:
        raise ExperimentError(f"start must be 'healthy' or 'steady', got {start!r}")
    # Bound the per-block arrays (steps x engines x states) to a few tens of MB.
    widest = max(d.reduced.A.shape[0] for d in filters.values())
    block = max(1, min(block, int(4e6 // (E * widest))))
    done = 0
    while done < n_steps:
        nb = min(block, n_steps - done)
        y, x_true = _simulate_block(
            truth_model.A, truth_model.C, drive_x, drive_y, x_true, nb, q_factor, r_std, rng
        )
        est = {}
        for key, d in filters.items():
            est[key] = filter_stream_states(d.reduced.A, d.reduced.C, d.gain, y, x0=x_hat[key])
            x_hat[key] = est[key][-1]
        first = max(0, n_settle - done)
        if first < nb:
            truth_block = np.broadcast_to(true_index, (nb - first, E))
            for v, (d, decide) in variants.items():
                iso_idx = decide(est[id(d)][first:])
                np.add.at(counts[v], (truth_block, iso_idx), 1.0)
        done += nb
        if progress is not None:
            progress(done / n_steps)
    out = {}
    names = tuple(f.name for f in lib)
    for v, c in counts.items():
        rows = c.sum(axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[v] = Confusion(v, names, 100.0 * c / rows)
    return IsolationExperiment(out, n_steps * design.model.dt, runs_per_fault, settle, noise)


def max_h_companion(
    design: TunerDesign,
    faults: Sequence[isolation.Fault] | None = None,
    truth: LinearModel | None = None,
    max_iter: int = 200,
) -> TunerDesign:
    """Seed 002 design 2 for the max-|h_hat| rule: the design's health vector
    extended by the library's actuator biases, optimal tuners (same m) that
    minimise the SSEE of the original health parameters only.

    The added biases get the mean random-walk variance (Qh) and the mean fleet
    spread (P_h) of the others: design 2 must expect them to move, which is
    what costs it accuracy on the turbomachinery parameters (seed 002 Table 5).
    """
    lib = isolation.default_faults() if faults is None else tuple(faults)
    truth_model = _truth_model(design, truth)
    full = _full(truth_model)
    used = {isolation._canonical(k) for f in lib for k in f.shifts}
    have = list(design.model.health_names)
    extra = [n for n in full.names if n not in have and isolation._canonical(n) in used]
    if not extra:
        return design
    idx = [full.names.index(n) for n in have + extra]
    model = _with_health(design.model, [full.names[i] for i in idx],
                         full.L[:, idx], full.M[:, idx], full.N[:, idx])
    p, k = len(have), len(extra)
    qh_extra = float(np.mean(np.diag(design.Qh)))
    Qh = np.zeros((p + k, p + k))
    Qh[:p, :p] = design.Qh
    Qh[p:, p:] = np.eye(k) * qh_extra
    Ph = np.zeros((p + k, p + k))
    Ph[:p, :p] = design.Ph
    Ph[p:, p:] = np.eye(k) * float(np.mean(np.diag(design.Ph)))
    weights = np.concatenate([np.ones(p), np.zeros(k)])
    return optimal_tuners(
        model, design.n_tuners, design.Q, Qh, Ph, health_weights=weights, max_iter=max_iter
    )


def _with_health(
    model: LinearModel, names: Sequence[str], L: np.ndarray, M: np.ndarray, N: np.ndarray
) -> LinearModel:
    """The model with another health vector (names and L, M, N columns)."""
    from dataclasses import replace

    from estimation.model import Signal

    return replace(model, health=tuple(Signal(n, "%") for n in names), L=L, M=M, N=N)


# ---------------------------------------------------- SSEE vs sensors (seed 003)


@dataclass(frozen=True)
class SensorTableRow:
    """Best suite of one size: SSEE with best-subset tuners and with optimal tuners."""

    n_sensors: int
    subset_ssee: float
    subset_sensors: tuple[str, ...]
    optimal_ssee: float
    optimal_sensors: tuple[str, ...]

    def to_dict(self) -> dict[str, object]:
        return {
            "n_sensors": self.n_sensors,
            "subset_ssee": self.subset_ssee,
            "subset_sensors": list(self.subset_sensors),
            "optimal_ssee": self.optimal_ssee,
            "optimal_sensors": list(self.optimal_sensors),
        }


def sensor_table(
    model: LinearModel,
    base: Sequence[str],
    optional: Sequence[str],
    Q: np.ndarray,
    Qh: np.ndarray,
    Ph: np.ndarray,
    *,
    max_iter: int = 200,
    progress: Progress | None = None,
) -> list[SensorTableRow]:
    """Seed 003's table: for each suite size, the best suite (base plus optional
    sensors) with best-subset tuners and with optimal tuners (m = min(sensors, p)).

    All suites go through one ``tuners.sensor_selection`` call, so each suite's
    search may start from the optimum of a neighbouring suite; a suite whose
    tuners the sensors cannot observe (redundant sensors) is NaN there and drops
    out of the table. Should a suite still fail numerically, the suites are
    designed one at a time and the failing one is left out with a warning.
    """
    def tick(done: int, total: int) -> None:
        if progress is not None:
            progress(done / total)

    try:
        suites = sensor_selection(
            model, base, optional, Q, Qh, Ph, max_iter=max_iter, progress=tick
        )
    except np.linalg.LinAlgError:
        subsets = [
            c for r in range(len(optional) + 1) for c in itertools.combinations(optional, r)
        ]
        suites = []
        for i, extra in enumerate(subsets):
            sensors = list(base) + list(extra)
            try:
                suites += sensor_selection(model, sensors, [], Q, Qh, Ph, max_iter=max_iter)
            except np.linalg.LinAlgError as exc:
                warnings.warn(f"sensor suite {sensors} left out: {exc}", stacklevel=2)
            tick(i + 1, len(subsets))
    by_subset = best_suites(suites, "subset")
    by_optimal = best_suites(suites, "optimal")
    rows = []
    for n in sorted(set(by_subset) | set(by_optimal)):
        s, o = by_subset.get(n), by_optimal.get(n)
        rows.append(
            SensorTableRow(
                n,
                s.subset_objective if s else float("nan"),
                s.sensors if s else (),
                o.optimal_objective if o else float("nan"),
                o.sensors if o else (),
            )
        )
    return rows
