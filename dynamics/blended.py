"""The car the tracking replay drives (search/plans/tracking.py): a single-track model with Fiala
tyres (a friction limit), the steer angle a state whose rate is limited, the speed a state,
valid forwards and backwards, blended into the kinematic single track at low speed, where the
dynamic one is singular (its slip angles divide by the speed).

x = [X, Y, psi, vx, vy, r, delta] ([m, m, rad, m/s, m/s, rad/s, rad]: centre of gravity,
heading, body-frame velocity, yaw rate, front steer angle), u = [ddelta, a] ([rad/s, m/s^2]:
steering rate and longitudinal acceleration, constrained as CommonRoad's single track
constrains them: `single_track.constrained_inputs`).

- Dynamic branch: each axle's slip angle from its velocity in the wheel's own frame,
  atan(lateral / |longitudinal|), so that the tyre force opposes the sliding backwards as
  well as forwards; the force is the Fiala law of `tyres` (saturating at mu Fz). The
  longitudinal acceleration acts along the body; combined slip is not modelled.
- Kinematic branch: rolling without slip (rear axle without lateral speed), yaw rate
  vx tan(delta) / L, lateral speed Lr times it; its derivatives are those of these values.
- Blend: x' = w f_dynamic + (1 - w) f_kinematic with w rising linearly from 0 at
  |vx| = v_blend_low to 1 at v_blend_high (Kabzan et al., 'AMZ Driverless: The full
  autonomous racing system', J. Field Robotics 37, 2020, Sec. 4.1 blends the same two).
"""
import jax.numpy as jnp

from stepzoo.dynamics.single_track import constrained_inputs
from stepzoo.dynamics.tyres import fiala

STATES = ("X", "Y", "psi", "vx", "vy", "r", "delta")
INPUTS = ("ddelta", "a")


def kinematic_lateral(vx, delta, p):
    """(vy [m/s], r [rad/s]) of the car rolling without slip at speed vx, steer delta."""
    r = vx * jnp.tan(delta) / (p["Lf"] + p["Lr"])
    return p["Lr"] * r, r


def _slip(along, across, v_floor):
    """Slip angle [rad] of a wheel moving `along` its plane and `across` it [m/s]."""
    return jnp.arctan(across / jnp.maximum(jnp.abs(along), v_floor))


def blend_weight(vx, p):
    """The dynamic model's weight in the blend at speed vx [m/s]: 0 up to |vx| = v_blend_low,
    1 from v_blend_high [m/s] (p), linear between."""
    return jnp.clip((jnp.abs(vx) - p["v_blend_low"]) / (p["v_blend_high"] - p["v_blend_low"]),
                    0.0, 1.0)


def blended_single_track(t, x, u, p):
    """Right-hand side; p: m, Iz, Lf, Lr, Caf, Car, mu, Fzf, Fzr (Fiala tyres), the steering
    and acceleration limits of `vehicles.st_params`, v_blend_low, v_blend_high [m/s]."""
    psi, vx, vy, r, delta = x[2], x[3], x[4], x[5], x[6]
    ddelta, a = constrained_inputs(delta, vx, u[0], u[1], p)
    c, s = jnp.cos(psi), jnp.sin(psi)
    cd, sd = jnp.cos(delta), jnp.sin(delta)
    # Dynamic: the slip angles stay finite below v_blend_low, where the blend ignores them.
    vf = vy + p["Lf"] * r
    alpha_f = _slip(vx * cd + vf * sd, vf * cd - vx * sd, p["v_blend_low"])
    alpha_r = _slip(vx, vy - p["Lr"] * r, p["v_blend_low"])
    Fyf, Fyr = fiala(alpha_f, p, "f"), fiala(alpha_r, p, "r")
    dynamic = jnp.stack([
        vx * c - vy * s, vx * s + vy * c, r,
        a + vy * r - Fyf * sd / p["m"],
        (Fyf * cd + Fyr) / p["m"] - vx * r,
        (p["Lf"] * Fyf * cd - p["Lr"] * Fyr) / p["Iz"], ddelta])
    # Kinematic: pose moved by the rolling car's own lateral speed and yaw rate.
    L = p["Lf"] + p["Lr"]
    vy_k, r_k = kinematic_lateral(vx, delta, p)
    dr_k = (a * jnp.tan(delta) + vx * ddelta / cd**2) / L
    kinematic = jnp.stack([vx * c - vy_k * s, vx * s + vy_k * c, r_k, a, p["Lr"] * dr_k, dr_k,
                           ddelta])
    w = blend_weight(vx, p)
    return w * dynamic + (1 - w) * kinematic
