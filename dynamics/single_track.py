"""The CommonRoad single-track model (ST; Althoff and Wuersching, 'CommonRoad: Vehicle
Models', 2020) as a pure JAX right-hand side, term for term as vehicle_dynamics_st.py of
commonroad-vehicle-models 3.0.2 computes it.

x = [X, Y, delta, v, psi, r, beta] ([m, m, rad, m/s, rad, rad/s, rad]: position, front
steering angle, speed, yaw, yaw rate, slip angle at the centre of gravity), u = [ddelta, a]
([rad/s, m/s^2]: steering rate, longitudinal acceleration). Tyre forces are linear in the
slip angles with load transfer from the acceleration (C_S [1/rad] per unit load, friction mu).

As published:
- the inputs are constrained first: the steering rate is clipped to [ddelta_min,
  ddelta_max] and set to 0 at a steering stop; the acceleration is clipped to
  [-a_max, a_max * min(1, v_switch / v)] and set to 0 at a speed limit;
- below |v| = v_kinematic (0.1 m/s) the model switches to the kinematic single-track model
  about the centre of gravity (the dynamic one divides by v and by v^2); above it the dynamic
  model holds all the way down, so its yaw and slip modes, whose rates grow like 1/v, make
  it stiff as v falls towards that threshold (at 0.5 m/s already);
- in the kinematic branch the slip rate is the published expression
  lr ddelta / (L cos^2 delta (1 + (tan^2 delta lr / L)^2)), whose last term differs from the
  exact derivative of atan(tan delta lr / L) ((tan delta lr / L)^2); it is kept as published,
  so that results agree with CommonRoad's.
"""
import jax.numpy as jnp

STATES = ("X", "Y", "delta", "v", "psi", "r", "beta")
INPUTS = ("ddelta", "a")
G = 9.81    # [m/s^2], as in vehicle_dynamics_st.py


def constrained_inputs(delta, v, ddelta, a, p):
    """(steering rate, acceleration) after CommonRoad's steering and acceleration limits."""
    stop = ((delta <= p["delta_min"]) & (ddelta <= 0)) | ((delta >= p["delta_max"]) & (ddelta >= 0))
    ddelta = jnp.where(stop, 0.0, jnp.clip(ddelta, p["ddelta_min"], p["ddelta_max"]))
    # Above v_switch the engine's power, not grip, limits acceleration: a_max v_switch / v.
    upper = p["a_max"] * p["v_switch"] / jnp.maximum(v, p["v_switch"])
    at_limit = ((v <= p["v_min"]) & (a <= 0)) | ((v >= p["v_max"]) & (a >= 0))
    a = jnp.where(at_limit, 0.0, jnp.clip(a, -p["a_max"], upper))
    return ddelta, a


def _kinematic(x, ddelta, a, p):
    """The low-speed branch: kinematic single track about the centre of gravity."""
    delta, v, psi, beta = x[2], x[3], x[4], x[6]
    L, lr = p["Lf"] + p["Lr"], p["Lr"]
    beta_ks = jnp.arctan(jnp.tan(delta) * lr / L)
    d_beta = lr * ddelta / (L * jnp.cos(delta) ** 2 * (1 + (jnp.tan(delta) ** 2 * lr / L) ** 2))
    dd_psi = (a * jnp.cos(beta) * jnp.tan(delta) - v * jnp.sin(beta) * d_beta * jnp.tan(delta)
              + v * jnp.cos(beta) * ddelta / jnp.cos(delta) ** 2) / L
    return jnp.stack([v * jnp.cos(beta_ks + psi), v * jnp.sin(beta_ks + psi), ddelta, a,
                      v * jnp.cos(beta_ks) * jnp.tan(delta) / L, dd_psi, d_beta])


def _dynamic(x, ddelta, a, v, p):
    """The dynamic branch, at a speed v [m/s] kept away from 0 by the caller."""
    delta, psi, r, beta = x[2], x[4], x[5], x[6]
    lf, lr, h, m, Iz, mu = p["Lf"], p["Lr"], p["h"], p["m"], p["Iz"], p["mu"]
    L = lf + lr
    front = p["CSf"] * (G * lr - a * h)     # per-unit-mass load times stiffness, front axle
    rear = p["CSr"] * (G * lf + a * h)
    dr = (-mu * m / (v * Iz * L) * (lf**2 * front + lr**2 * rear) * r
          + mu * m / (Iz * L) * (lr * rear - lf * front) * beta
          + mu * m / (Iz * L) * lf * front * delta)
    dbeta = ((mu / (v**2 * L) * (rear * lr - front * lf) - 1) * r
             - mu / (v * L) * (rear + front) * beta
             + mu / (v * L) * front * delta)
    return jnp.stack([v * jnp.cos(beta + psi), v * jnp.sin(beta + psi), ddelta, a, r, dr, dbeta])


def single_track(t, x, u, p):
    """CommonRoad ST right-hand side; p as `vehicles.st_params` gives it."""
    v = x[3]
    ddelta, a = constrained_inputs(x[2], v, u[0], u[1], p)
    low = jnp.abs(v) < p["v_kinematic"]
    # Both branches are evaluated; the dynamic one sees a safe speed so that neither its
    # value nor its derivative is NaN where it is not selected.
    v_dyn = jnp.where(low, p["v_kinematic"], v)
    return jnp.where(low, _kinematic(x, ddelta, a, p), _dynamic(x, ddelta, a, v_dyn, p))
