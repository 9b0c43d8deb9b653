"""Kinematic bicycles, u = [delta, F] ([rad, N]): the paper's connection OCP's (eq. "pm"),
x = [X, Y, theta, v] ([m, m, rad, m/s]), a point moving along theta on turns of curvature
tan(delta) / L; and the rigid car's (`rigid_terms`), x = [X, Y, psi, v], its centre of
gravity, body heading and speed. p needs the wheelbase `L` [m] (and `Lr` [m]) and `m` [kg].

One definition serves JAX and CasADi: `kinematic_terms` takes the math functions to use."""
import jax.numpy as jnp
import numpy as np

STATES = ("X", "Y", "theta", "v")
RIGID_STATES = ("X", "Y", "psi", "v")
INPUTS = ("delta", "F")


def kinematic_terms(x, u, L, m, cos, sin, tan):
    """The four derivatives as a tuple, with the given cos/sin/tan (jnp or casadi)."""
    theta, v = x[2], x[3]
    return v * cos(theta), v * sin(theta), v * tan(u[0]) / L, u[1] / m


def rigid_terms(x, u, L, Lr, m, cos, sin, tan, sqrt):
    """The four derivatives of the kinematic bicycle as a rigid car (Rajamani, 'Vehicle
    Dynamics and Control', 2nd ed. 2012, eqs. 2.26-2.29): its rear axle rolls along the body
    without sliding, so its centre of gravity (X, Y), Lr [m] ahead of it, moves at the slip
    beta = atan(Lr tan(delta) / L) beside the body heading psi, at speed v, and the body
    turns at v cos(beta) tan(delta) / L. Turning the wheel at a standstill turns nothing;
    with the math functions given (jnp or casadi)."""
    psi, v = x[2], x[3]
    slip = Lr * tan(u[0]) / L        # tan(beta)
    along = v / sqrt(1 + slip * slip)  # v cos(beta)
    return (along * (cos(psi) - slip * sin(psi)), along * (sin(psi) + slip * cos(psi)),
            along * tan(u[0]) / L, u[1] / m)


def shifted(poses, length):
    """Poses (..., 3+) [X, Y, psi] moved `length` [m] along their heading, the rest of each
    row kept: the centre of gravity's from the rear axle's with length Lr, back with -Lr."""
    out = np.array(poses, float)
    out[..., 0] += length * np.cos(out[..., 2])
    out[..., 1] += length * np.sin(out[..., 2])
    return out


def kinematic_bicycle(t, x, u, p):
    """JAX right-hand side; `L` defaults to Lf + Lr of a vehicle set."""
    L = p["L"] if "L" in p else p["Lf"] + p["Lr"]
    return jnp.stack(kinematic_terms(x, u, L, p["m"], jnp.cos, jnp.sin, jnp.tan))


def rigid_bicycle(t, x, u, p):
    """JAX right-hand side of `rigid_terms`; `L` defaults to Lf + Lr of a vehicle set."""
    L = p["L"] if "L" in p else p["Lf"] + p["Lr"]
    return jnp.stack(rigid_terms(x, u, L, p["Lr"], p["m"], jnp.cos, jnp.sin, jnp.tan, jnp.sqrt))
