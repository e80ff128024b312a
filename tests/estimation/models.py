"""Small test models for the estimation tests.

``random_model`` draws a stable random model with named signals; ``reference_model``
is a fixed two-spool turbofan-like model laid out like the seed 002 example
(states Nf, Nc; actuators Wf, VSV, VBV; ten turbomachinery health parameters plus
optional actuator biases; the six sensors of seed 002 Table 2 with their noise,
and optional extra sensors; auxiliary thrust, stall margins and T40). Its numbers
are made up (drawn from a fixed seed with physical signs), not C-MAPSS's.
``reference_noise`` gives the seed 002 noise setting for a model.
"""

from __future__ import annotations

import numpy as np

from estimation.model import LinearModel, Signal

HEALTH_10 = (
    "fan_eff", "fan_flow", "lpc_eff", "lpc_flow", "hpc_eff",
    "hpc_flow", "hpt_eff", "hpt_flow", "lpt_eff", "lpt_flow",
)
ACTUATOR_BIAS = ("wf_bias", "vsv_bias", "vbv_bias")
# seed 002 Table 2: sensors and noise standard deviation (the table's fractions of
# trim, here in percent of trim).
SENSORS_6 = (("Nf", "rpm", 0.5), ("Nc", "rpm", 0.5), ("T24", "K", 1.5),
             ("Ps30", "kPa", 1.0), ("T30", "K", 1.5), ("T48", "K", 1.5))
EXTRA_SENSORS = (("P24", "kPa", 1.0), ("T50", "K", 1.5), ("P50", "kPa", 1.0),
                 ("Wf_meas", "kg/s", 1.0), ("P15", "kPa", 1.0), ("T15", "K", 1.5))
AUX = (("Fn", "kN"), ("SmFan", "%"), ("SmLPC", "%"), ("SmHPC", "%"), ("T40", "K"))
INPUTS = (("Wf", "kg/s"), ("VSV", "deg"), ("VBV", "%"))
STATES = (("Nf", "rpm"), ("Nc", "rpm"))
TRIM = {"Nf": 2388.0, "Nc": 9050.0, "Wf": 1.25, "VSV": 12.0, "VBV": 20.0,
        "T24": 642.0, "Ps30": 3100.0, "T30": 1590.0, "T48": 1400.0,
        "P24": 320.0, "T50": 1050.0, "P50": 140.0, "Wf_meas": 1.25, "P15": 150.0,
        "T15": 330.0, "Fn": 120.0, "SmFan": 20.0, "SmLPC": 18.0, "SmHPC": 25.0,
        "T40": 1750.0}


def _stable_a(rng: np.random.Generator, nx: int, dt: float) -> np.ndarray:
    """Discrete A with real poles between 0.5 and 4 rad/s (continuous), mildly coupled."""
    poles = -rng.uniform(0.5, 4.0, nx)
    T = np.eye(nx) + 0.3 * rng.standard_normal((nx, nx))
    # A = exp(Ac dt) with Ac = T diag(poles) T^-1.
    return T @ np.diag(np.exp(poles * dt)) @ np.linalg.inv(T)


def random_model(
    rng: np.random.Generator,
    n_states: int = 2,
    n_inputs: int = 3,
    n_health: int = 10,
    n_sensors: int = 6,
    n_aux: int = 3,
    dt: float = 0.015,
) -> LinearModel:
    """A stable random model; signals x1.., u1.., h1.., y1.., z1.. in percent of trim.

    Steady-state gains are of order one, sensor noise 0.2-1 %.
    """
    A = _stable_a(rng, n_states, dt)
    # Scale input matrices by dt so steady-state gains (I-A)^-1 B stay of order one.
    scale = dt * 2.0
    B = scale * rng.standard_normal((n_states, n_inputs))
    L = scale * rng.standard_normal((n_states, n_health))
    C = rng.standard_normal((n_sensors, n_states))
    D = 0.3 * rng.standard_normal((n_sensors, n_inputs))
    M = rng.standard_normal((n_sensors, n_health))
    F = rng.standard_normal((n_aux, n_states))
    G = 0.3 * rng.standard_normal((n_aux, n_inputs))
    N = rng.standard_normal((n_aux, n_health))
    states = tuple(Signal(f"x{i + 1}", "rpm") for i in range(n_states))
    inputs = tuple(Signal(f"u{i + 1}", "kg/s") for i in range(n_inputs))
    health = tuple(Signal(f"h{i + 1}", "%") for i in range(n_health))
    sensors = tuple(Signal(f"y{i + 1}", "K") for i in range(n_sensors))
    aux = tuple(Signal(f"z{i + 1}", "kN") for i in range(n_aux))
    trim = {s.name: float(rng.uniform(100, 2000)) for s in states + inputs + sensors + aux}
    return LinearModel(
        dt=dt, states=states, inputs=inputs, health=health, sensors=sensors, aux=aux,
        A=A, B=B, C=C, D=D, L=L, M=M, F=F, G=G, N=N, trim=trim,
        sensor_noise_std=rng.uniform(0.2, 1.0, n_sensors),
        operating_condition={"alt_ft": 0.0, "mach": 0.0, "dtamb_k": 0.0, "power_pct": 100.0},
    )


def reference_model(
    actuator_bias: bool = False, extra_sensors: int = 0, dt: float = 0.015
) -> LinearModel:
    """Fixed turbofan-like model: 2 states, 3 actuators, 10 (+3) health, 6 (+extra) sensors.

    Actuator-bias health parameters enter exactly like the actuator they bias
    (L and M columns equal to B and D columns), as in seed 002 eq. 13.
    """
    rng = np.random.default_rng(20120611)
    sens = SENSORS_6 + EXTRA_SENSORS[:extra_sensors]
    nx, nu, nh, ny, nz = 2, 3, 10, len(sens), len(AUX)
    A = np.array([[0.9745, 0.0060], [0.0095, 0.9610]])
    if dt != 0.015:
        # Same continuous dynamics at another step: A = exp(Ac dt) via eigen-decomposition.
        w, T = np.linalg.eig(A)
        A = np.real(T @ np.diag(np.exp(np.log(w) * dt / 0.015)) @ np.linalg.inv(T))
    k = dt / 0.015
    B = k * np.array([[0.030, 0.004, -0.006], [0.045, -0.008, 0.002]])
    # Health effects on spool speeds: efficiencies speed spools up, HPT/LPT drive them.
    L = k * (np.abs(rng.normal(0.02, 0.01, (nx, nh))) * rng.choice([-1.0, 1.0], (nx, nh)))
    C = np.zeros((ny, nx))
    C[0, 0] = 1.0  # Nf sensor measures Nf state
    C[1, 1] = 1.0
    C[2:, :] = rng.normal(0.0, 0.8, (ny - 2, nx))
    D = rng.normal(0.0, 0.3, (ny, nu))
    D[:2] = 0.0
    M = rng.normal(0.0, 0.6, (ny, nh))
    M[:2] = 0.0  # speeds respond to health only through the dynamics
    F = rng.normal(0.0, 0.8, (nz, nx))
    G = rng.normal(0.0, 0.3, (nz, nu))
    N = rng.normal(0.0, 0.8, (nz, nh))
    health = tuple(Signal(n, "%") for n in HEALTH_10)
    if actuator_bias:
        L = np.hstack([L, B])
        M = np.hstack([M, D])
        N = np.hstack([N, G])
        health = health + tuple(Signal(n, "%") for n in ACTUATOR_BIAS)
    sensors = tuple(Signal(n, u) for n, u, _ in sens)
    states = tuple(Signal(n, u) for n, u in STATES)
    inputs = tuple(Signal(n, u) for n, u in INPUTS)
    aux = tuple(Signal(n, u) for n, u in AUX)
    names = {s.name for s in states + inputs + sensors + aux}
    return LinearModel(
        dt=dt, states=states, inputs=inputs, health=health, sensors=sensors, aux=aux,
        A=A, B=B, C=C, D=D, L=L, M=M, F=F, G=G, N=N,
        trim={k_: v for k_, v in TRIM.items() if k_ in names},
        sensor_noise_std=np.array([s for _, _, s in sens]),
        operating_condition={"alt_ft": 35000.0, "mach": 0.8, "dtamb_k": 0.0, "power_pct": 85.0},
    )


def reference_noise(model: LinearModel, health_std: float = 2.0) -> dict[str, np.ndarray]:
    """Seed 002 noise setting: Ph = diag(health_std^2) (2 % std), small Q and Qh.

    Returns Q [nx, nx] (process noise of the states), Qh [np, np] (random walk of
    the health parameters per step) and Ph [np, np] (fleet health covariance).
    """
    nx, nh = model.n_states, model.n_health
    return {
        "Q": np.eye(nx) * 1e-4,
        "Qh": np.eye(nh) * 1e-4,
        "Ph": np.eye(nh) * health_std**2,
    }


def scheduled_models(
    points: list[dict[str, float]], base: LinearModel | None = None
) -> list[LinearModel]:
    """``base`` (default the reference model) at each operating point of ``points`` (alt_ft,
    mach, power_pct; dtamb_k 0): health and input effects and the trims vary smoothly with
    power and altitude (made-up numbers of physical signs, not C-MAPSS's), the noise with
    power."""
    from dataclasses import replace

    from estimation.engine.atmosphere import flight_condition

    base = base or reference_model()
    out = []
    for p in points:
        alt, mach, power = p.get("alt_ft", 35000.0), p.get("mach", 0.8), p.get("power_pct", 85.0)
        s = 0.7 + 0.4 * power / 100.0 - 0.1 * alt / 40000.0
        fc = flight_condition(np.array([alt]), np.array([mach]), np.array([0.0]))
        theta, delta = float(fc.theta[0]), float(fc.delta[0])
        trim = {}
        for sig in (*base.states, *base.inputs, *base.sensors, *base.aux):
            if sig.name not in base.trim:
                continue
            v = base.trim[sig.name] * (0.6 + 0.4 * power / 100.0)
            if sig.unit in ("K", "degR"):
                v *= theta
            elif sig.unit in ("kPa", "psia", "kN"):
                v *= delta
            elif sig.unit == "rpm":
                v *= theta ** 0.5
            elif sig.unit in ("kg/s", "pps"):
                v *= delta * theta ** 0.5
            trim[sig.name] = v
        out.append(replace(
            base, L=base.L * s, M=base.M * s, N=base.N * s, B=base.B * (2.0 - s), trim=trim,
            sensor_noise_std=base.sensor_noise_std * (1.2 - 0.2 * power / 100.0),
            operating_condition={"alt_ft": alt, "mach": mach, "dtamb_k": 0.0,
                                 "power_pct": power}))
    return out
