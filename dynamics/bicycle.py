"""The dynamic bicycle of the paper: the reduced 5-state form (eq. 4, constant speed) and
the full 6-state form (eq. 1), as pure JAX right-hand sides f(t, x, u, p) -> dx/dt.

Sign convention of the paper: longitudinal tyre forces Fxf, Fxr [N] are positive when they
oppose the motion (the paper writes -Fxf cos(delta) - Fxr in dvx and -Fxf sin(delta) in dvy).

The lateral tyre forces follow a tyre law of `tyres` (linear by default); `reduced(tyre)`
and `full(tyre)` give one right-hand side per law (the same function object on every call,
so that compiled code is shared).
"""
from functools import cache

import jax.numpy as jnp

from stepzoo.dynamics.tyres import tyre_law, tyre_name

REDUCED_STATES = ("X", "Y", "psi", "vy", "r")
REDUCED_INPUTS = ("delta",)
FULL_STATES = ("X", "Y", "psi", "vx", "vy", "r")
FULL_INPUTS = ("delta", "Fxf", "Fxr")


def lateral_forces(vx, vy, r, delta, p, tyre=None):
    """Front and rear lateral tyre forces [N] (slip angles per NOTES.md, small-angle form)."""
    alpha_f = (vy + p["Lf"] * r) / vx - delta
    alpha_r = (vy - p["Lr"] * r) / vx
    law = tyre_law(tyre)
    return law(alpha_f, p, "f"), law(alpha_r, p, "r")


def _planar(psi, vx, vy, r, delta, Fxf, p, tyre):
    """Shared kinematics and lateral dynamics: (dX, dY, dpsi, dvy, dr, Fyf)."""
    Fyf, Fyr = lateral_forces(vx, vy, r, delta, p, tyre)
    c, s = jnp.cos(psi), jnp.sin(psi)
    front_lat = Fyf * jnp.cos(delta) - Fxf * jnp.sin(delta)
    dvy = (front_lat + Fyr) / p["m"] - vx * r
    dr = (p["Lf"] * front_lat - p["Lr"] * Fyr) / p["Iz"]
    return vx * c - vy * s, vx * s + vy * c, r, dvy, dr, Fyf


def reduced(tyre: str | None = None):
    """5-state dynamic bicycle with the named tyre law (default linear)."""
    return _reduced(tyre_name(tyre))


def full(tyre: str | None = None):
    """6-state dynamic bicycle with the named tyre law (default linear)."""
    return _full(tyre_name(tyre))


@cache
def _reduced(tyre):
    def reduced_bicycle(t, x, u, p):
        """5-state dynamic bicycle, x = [X, Y, psi, vy, r] ([m, m, rad, m/s, rad/s]),
        u = [delta] [rad]; p holds the vehicle set (with its tyre parameters) plus `vx`
        [m/s] and `Fxf` [N] (default 0)."""
        X, Y, psi, vy, r = x
        dX, dY, dpsi, dvy, dr, _ = _planar(psi, p["vx"], vy, r, u[0], p.get("Fxf", 0.0), p, tyre)
        return jnp.stack([dX, dY, dpsi, dvy, dr])
    return reduced_bicycle


@cache
def _full(tyre):
    def full_bicycle(t, x, u, p):
        """6-state dynamic bicycle, x = [X, Y, psi, vx, vy, r], u = [delta, Fxf, Fxr]
        ([rad, N, N]); p holds the vehicle set with its tyre parameters."""
        X, Y, psi, vx, vy, r = x
        delta, Fxf, Fxr = u[0], u[1], u[2]
        dX, dY, dpsi, dvy, dr, Fyf = _planar(psi, vx, vy, r, delta, Fxf, p, tyre)
        dvx = (-Fxf * jnp.cos(delta) - Fyf * jnp.sin(delta) - Fxr) / p["m"] + vy * r
        return jnp.stack([dX, dY, dpsi, dvx, dvy, dr])
    return full_bicycle


reduced_bicycle = reduced()
full_bicycle = full()
