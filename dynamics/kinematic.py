"""Kinematic bicycle of the paper's connection OCP (eq. "pm"): x = [X, Y, theta, v]
([m, m, rad, m/s]), u = [delta, F] ([rad, N]); p needs the wheelbase `L` [m] and `m` [kg].

One definition serves JAX and CasADi: `kinematic_terms` takes the math functions to use."""
import jax.numpy as jnp

STATES = ("X", "Y", "theta", "v")
INPUTS = ("delta", "F")


def kinematic_terms(x, u, L, m, cos, sin, tan):
    """The four derivatives as a tuple, with the given cos/sin/tan (jnp or casadi)."""
    theta, v = x[2], x[3]
    return v * cos(theta), v * sin(theta), v * tan(u[0]) / L, u[1] / m


def kinematic_bicycle(t, x, u, p):
    """JAX right-hand side; `L` defaults to Lf + Lr of a vehicle set."""
    L = p["L"] if "L" in p else p["Lf"] + p["Lr"]
    return jnp.stack(kinematic_terms(x, u, L, p["m"], jnp.cos, jnp.sin, jnp.tan))
