"""A user's model with the parameter tables a simulator ships: one driven wheel on a body of
mass m (a quarter car, longitudinal only), a saturating Pacejka longitudinal tyre. Stiff at
speed: the wheel-spin mode relaxes at about B C D Fz r^2 / (J vx) 1/s, the body far slower.
`free_rolling` is a "module:function" hook giving the wheel speed that rolls without slip."""
import jax.numpy as jnp

EPS_V = 0.1    # [m/s] the slip's denominator never falls below this (standstill)


def wheel(t, x, u, p):
    """x = [vx, omega] [m/s, rad/s], u = [T] [N m] drive torque; p nested as the TOML's
    [params.body], [params.wheel], [params.tyre] tables."""
    vx, omega = x[0], x[1]
    r, J = p["wheel"]["r_w"], p["wheel"]["J"]
    B, C, D = p["tyre"]["B"], p["tyre"]["C"], p["tyre"]["D"]
    slip = (omega * r - vx) / jnp.maximum(jnp.abs(vx), EPS_V)
    fx = D * p["tyre"]["Fz"] * jnp.sin(C * jnp.arctan(B * slip))
    return jnp.stack([fx / p["body"]["m"], (u[0] - fx * r) / J])


def free_rolling(values):
    """The wheel speed [rad/s] of rolling without slip, vx / r_w, at every operating point."""
    return values["vx"] / values["wheel.r_w"]
