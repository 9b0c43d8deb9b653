"""A user's own model, written outside stepzoo: two masses on springs with dampers, the first
tied to a wall, a force F on the second. Linear, so its eigenvalues set every step limit."""
import jax.numpy as jnp

MASSES = 2


def chain(t, x, u, p):
    """x = [x1, x2, v1, v2] [m, m, m/s, m/s], u = [F] [N]; p: k [N/m], c [N s/m], m [kg]."""
    x1, x2, v1, v2 = x
    k, c, m = p["k"], p["c"], p["m"]
    a1 = (-k * x1 + k * (x2 - x1) - c * v1 + c * (v2 - v1)) / m
    a2 = (-k * (x2 - x1) - c * (v2 - v1) + u[0]) / m
    return jnp.stack([v1, v2, a1, a2])
