"""Auxiliary-output gains at a power setting, where the controller holds the fan speed.

The linearised engine's steady-state gains G_z (aux per health parameter) and G_u,z (aux per
input) hold the inputs fixed: a deteriorated engine at the same fuel flow. The built-in engine
is flown at a power setting, which the controller turns into a demanded corrected fan speed
(``actuators.demanded_corrected_fan_speed``): at steady state Nf sits on its demand and the fuel
flow is whatever holds it there. A deteriorated engine burns more fuel at the same power
setting and gives nearly the same thrust. Its aux outputs (thrust, stall margins, T40, BPR)
change by

    dz = G_z h + G_u,z du,  with the loop input (Wf) fixed by  0 = G_y,Nf h + G_u,Nf du,

so, eliminating the loop input's deviation, with k = G_u,z[:, Wf] / G_u,Nf[Wf]:

    dz = (G_z - k G_y,Nf) h + (G_u,z - k G_u,Nf) du

whose input gain is zero in the loop input's column: the measured fuel flow, noisy (its
sensor noise in percent of trim is about three times larger at cruise than at take-off) and
biased by a fuel-metering bias that moves neither speed nor thrust, is not needed; the other
inputs (the scheduled VSV and VBV commands) keep their own, now closed-loop, gains.
All in percent of trim per percent.
"""

from __future__ import annotations

import numpy as np

from estimation.errors import DimensionError


def held_speed_aux_gains(
    G_z: np.ndarray,
    G_uz: np.ndarray,
    G_y_held: np.ndarray,
    G_u_held: np.ndarray,
    loop: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Aux gains with the held sensor at its demand through the loop input (see the module).

    G_z [..., nz, p], G_uz [..., nz, nu]: open-loop aux gains of health and inputs;
    G_y_held [..., p], G_u_held [..., nu]: the held sensor's row of G_y and G_u,y;
    loop: the column of the input the controller moves (its G_u_held entry must not be 0).
    Returns (G_z closed [..., nz, p], G_uz closed [..., nz, nu]); the loop column is 0.
    """
    G_z = np.asarray(G_z, float)
    G_uz = np.asarray(G_uz, float)
    G_y_held = np.asarray(G_y_held, float)
    G_u_held = np.asarray(G_u_held, float)
    if G_y_held.shape[-1] != G_z.shape[-1] or G_u_held.shape[-1] != G_uz.shape[-1]:
        raise DimensionError(
            f"held-sensor rows {G_y_held.shape}, {G_u_held.shape} do not match the aux gains "
            f"{G_z.shape}, {G_uz.shape}"
        )
    pivot = G_u_held[..., loop]
    if np.any(pivot == 0.0):
        raise ValueError("the loop input does not move the held sensor (zero gain)")
    k = G_uz[..., :, loop] / pivot[..., None]  # [..., nz]
    closed_z = _minus(G_z, k[..., :, None] * G_y_held[..., None, :])
    closed_uz = _minus(G_uz, k[..., :, None] * G_u_held[..., None, :])
    closed_uz[..., loop] = 0.0  # exactly, not to rounding
    return closed_z, closed_uz


def _minus(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a - b, written over ``b`` (a product made for it) when that has the result's shape: one
    array where there would be two (a schedule's gains are tens of megabytes per chunk of
    records); the same differences."""
    if b.shape == np.broadcast_shapes(a.shape, b.shape):
        return np.subtract(a, b, out=b)
    return a - b
