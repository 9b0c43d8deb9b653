"""Kinematic bicycle of the paper's connection OCP (eq. "pm"): x = [X, Y, theta, v]
([m, m, rad, m/s]), u = [delta, F] ([rad, N]); p needs the wheelbase `L` [m] and `m` [kg].

One definition serves JAX and CasADi: `kinematic_terms` takes the math functions to use."""
import jax.numpy as jnp
import numpy as np

STATES = ("X", "Y", "theta", "v")
INPUTS = ("delta", "F")


def kinematic_terms(x, u, L, m, cos, sin, tan):
    """The four derivatives as a tuple, with the given cos/sin/tan (jnp or casadi)."""
    theta, v = x[2], x[3]
    return v * cos(theta), v * sin(theta), v * tan(u[0]) / L, u[1] / m


def body_slip(delta, L, Lr):
    """[rad] the angle from the body of a car rolling without slip (its rear axle does not
    slide) to the path of its centre of gravity, Lr [m] ahead of the rear axle,
    when that path curves at tan(delta) / L [1/m], the kinematic bicycle's at steer delta
    [rad] (L the wheelbase [m]): asin(Lr tan(delta) / L), the same forwards and backwards.
    The kinematic bicycle moves its (X, Y) along theta: a car whose centre of gravity keeps
    to that path faces theta - body_slip."""
    return np.arcsin(np.clip(Lr * np.tan(delta) / L, -1.0, 1.0))


def kinematic_bicycle(t, x, u, p):
    """JAX right-hand side; `L` defaults to Lf + Lr of a vehicle set."""
    L = p["L"] if "L" in p else p["Lf"] + p["Lr"]
    return jnp.stack(kinematic_terms(x, u, L, p["m"], jnp.cos, jnp.sin, jnp.tan))
