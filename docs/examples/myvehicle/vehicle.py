"""My single-track vehicle in JAX: seven states, linear tyres with load transfer, and the
steering angle the tyres see clamped to +-0.42 rad, as the simulator this model comes from
limits it.

x = [X, Y, delta, v, psi, r, beta]: position [m], steering angle [rad], speed [m/s], yaw
[rad], yaw rate [rad/s], slip angle at the centre of gravity [rad].
u = [ddelta, a]: steering rate [rad/s], longitudinal acceleration [m/s^2].
"""
import jax.numpy as jnp

STEER_MAX = 0.42   # [rad]
G = 9.81           # [m/s^2]


def single_track(t, x, u, p):
    """dx/dt; p: m [kg], Iz [kg m^2], lf, lr, h [m], mu [-], csf, csr [1/rad]."""
    X, Y, delta, v, psi, r, beta = x
    ddelta, a = u
    steer = jnp.clip(delta, -STEER_MAX, STEER_MAX)       # the clamp
    lf, lr = p["lf"], p["lr"]
    L = lf + lr
    kf = p["mu"] * p["csf"] * (G * lr - a * p["h"]) / L   # front cornering, per unit mass
    kr = p["mu"] * p["csr"] * (G * lf + a * p["h"]) / L   # rear
    dr = p["m"] / p["Iz"] * (lf * kf * (steer - beta - lf * r / v)
                             - lr * kr * (lr * r / v - beta))
    dbeta = (kf * (steer - beta - lf * r / v) + kr * (lr * r / v - beta)) / v - r
    return jnp.stack([v * jnp.cos(psi + beta), v * jnp.sin(psi + beta), ddelta, a,
                      r, dr, dbeta])
