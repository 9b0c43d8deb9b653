"""A user's model with a steering clamp: the lateral dynamics (vy, r) of the paper's linear-
tyre bicycle at a constant speed, steered by a rate input through a steering state delta that
the tyres see clipped to +-DELTA_MAX, as simulators limit the steering angle. From
delta = 0 at a constant rate, the clamp is reached at t = DELTA_MAX / rate."""
import jax.numpy as jnp

DELTA_MAX = 0.42       # [rad]


def clamped(t, x, u, p):
    """x = [vy, r, delta] [m/s, rad/s, rad], u = [rate] [rad/s]; p: m [kg], Iz [kg m^2],
    Lf, Lr [m], Caf, Car [N/rad], vx [m/s]."""
    vy, r, delta = x
    steer = jnp.clip(delta, -DELTA_MAX, DELTA_MAX)
    Fyf = -p["Caf"] * ((vy + p["Lf"] * r) / p["vx"] - steer)
    Fyr = -p["Car"] * (vy - p["Lr"] * r) / p["vx"]
    return jnp.stack([(Fyf * jnp.cos(steer) + Fyr) / p["m"] - p["vx"] * r,
                      (p["Lf"] * Fyf * jnp.cos(steer) - p["Lr"] * Fyr) / p["Iz"], u[0]])
