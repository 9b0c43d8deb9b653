"""Longitudinal quarter-car models with wheel-spin dynamics and a saturating tyre: stiff at
low speed (the wheel's slip mode, rate R^2 dFx/dkappa / (J v)), bounded by the tyre (the
magic formula saturates at D Fz), and physically unstable past the friction peak (the
wheel locks or spins). Written from the textbook equations (Pacejka, Tyre and Vehicle
Dynamics, 3rd ed., 2012, ch. 4 eq. 4.49 and ch. 7 eq. 7.7; Rajamani, Vehicle Dynamics and
Control, 2nd ed., 2012, sec. 4.2 and 13.3).

The wheel's state is its slip velocity v_slip = R omega - v [m/s] (omega the wheel's speed
[rad/s]): free rolling is v_slip = 0 at every speed, so an envelope over the speed needs no
second initial state tied to it. Longitudinal slip kappa = v_slip / v (SAE, driving > 0).

- quarter_car:       x = [s, v, v_slip] ([m, m/s, m/s]), u = [T] (wheel torque [N m],
  braking < 0); the tyre's force follows the slip at once.
- two_axle: x = [s, v, v_slip_f, v_slip_r], u = [T_f, T_r]: the whole car on one front and
  one rear wheel (a longitudinal single track, static axle loads m g l_r / L and m g l_f /
  L): two wheel modes, both real, that share the car's speed.
- quarter_car_relax: x = [s, v, v_slip, kappa_t]: the tyre's force follows a transient slip
  kappa_t over the relaxation length sigma (Pacejka 2012, sec. 7.2): the wheel and the
  tyre's carcass then form an oscillator of R sqrt(C_kappa / (J sigma)) [rad/s] whose
  damping ratio v / (2 sigma omega_n) is small at low speed: a lightly damped mode.

Parameters: a 1600 kg passenger car's quarter (m = 400 kg, Fz = m g), a 16-inch wheel with
tyre and brake disc (J = 1.2 kg m^2, R = 0.31 m), and the magic formula's longitudinal
coefficients for dry tarmac (B = 10, C = 1.9, D = 1, E = 0.97; Pacejka 2012, as tabulated
by MathWorks for its Tire-Road Interaction (Magic Formula) block)."""
from typing import Any

import jax.numpy as jnp

G = 9.81                 # [m/s^2]
SOURCE = ("Pacejka, Tyre and Vehicle Dynamics, 3rd ed., 2012 (eq. 4.49, magic formula; sec. "
          "7.2, transient slip); Rajamani, Vehicle Dynamics and Control, 2nd ed., 2012 (sec. "
          "4.2, 13.3, wheel dynamics); dry-tarmac coefficients B 10, C 1.9, D 1, E 0.97 as "
          "MathWorks tabulates them (Simscape Driveline, Tire-Road Interaction (Magic Formula))")
PARAMS = {"m": 400.0, "J": 1.2, "R": 0.31, "B": 10.0, "C": 1.9, "D": 1.0, "E": 0.97,
          "sigma": 0.25, "v_min": 1.0}
# The whole car of two_axle: mass [kg], axle distances from the centre of gravity [m], and
# each axle's two wheels as one of twice the inertia [kg m^2].
CAR = dict(PARAMS, m=1600.0, J=2.4, lf=1.2, lr=1.4)


def magic_formula(kappa, p):
    """Longitudinal force per unit load [-] at slip kappa: D sin(C atan(B k - E (B k -
    atan(B k)))), slope B C D at zero slip, peak D."""
    Bk = p["B"] * kappa
    return p["D"] * jnp.sin(p["C"] * jnp.arctan(Bk - p["E"] * (Bk - jnp.arctan(Bk))))


def _speed(v, p):
    # The slip divides by the speed; below v_min [m/s] (a car nearly at rest, outside every
    # envelope here) it divides by v_min instead, as simulators do, so f stays finite.
    return jnp.maximum(v, p["v_min"])


def _motion(v, v_slip, fx, T, p):
    """(ds, dv, dv_slip) for the tyre force fx [N] and wheel torque T [N m]."""
    dv = fx / p["m"]
    domega = (T - p["R"] * fx) / p["J"]
    return v, dv, p["R"] * domega - dv


def quarter_car(t, x, u, p):
    """Quarter car, tyre force F(kappa) at once; p: m, J, R, B, C, D, E, v_min."""
    v, v_slip = x[1], x[2]
    fx = p["m"] * G * magic_formula(v_slip / _speed(v, p), p)
    return jnp.stack(_motion(v, v_slip, fx, u[0], p))


def two_axle(t, x, u, p):
    """Longitudinal single track: both axles' forces on the car, each wheel its own slip;
    p: m, J (per axle), R, lf, lr [m], B, C, D, E, v_min."""
    v, slip_f, slip_r = x[1], x[2], x[3]
    L, speed = p["lf"] + p["lr"], _speed(v, p)
    fx_f = p["m"] * G * p["lr"] / L * magic_formula(slip_f / speed, p)
    fx_r = p["m"] * G * p["lf"] / L * magic_formula(slip_r / speed, p)
    dv = (fx_f + fx_r) / p["m"]
    wheel = [p["R"] * (T - p["R"] * fx) / p["J"] - dv for T, fx in ((u[0], fx_f), (u[1], fx_r))]
    return jnp.stack([v, dv, *wheel])


def quarter_car_relax(t, x, u, p):
    """Quarter car with transient slip: sigma dkappa_t/dt = v_slip - v kappa_t (Pacejka 2012,
    eq. 7.7, with V_sx = -v_slip); the force F(kappa_t). p: also sigma [m]."""
    v, v_slip, kappa_t = x[1], x[2], x[3]
    fx = p["m"] * G * magic_formula(kappa_t, p)
    dkappa = (v_slip - _speed(v, p) * kappa_t) / p["sigma"]
    return jnp.stack([*_motion(v, v_slip, fx, u[0], p), dkappa])


PROBLEMS: dict[str, dict[str, Any]] = {
    "quarter_car": dict(
        rhs=quarter_car, states=("s", "v", "v_slip"), inputs=("T",), x0=(0.0, 20.0, 0.0),
        u0=(-800.0,), t_span=(0.0, 0.5),
        description="quarter car braking, wheel-spin dynamics, magic-formula tyre (3 states)"),
    "two_axle": dict(
        rhs=two_axle, states=("s", "v", "v_slip_f", "v_slip_r"), inputs=("T_f", "T_r"),
        x0=(0.0, 20.0, 0.0, 0.0), u0=(-2400.0, -1200.0), t_span=(0.0, 0.5), params=CAR,
        description="car braking on two wheels (longitudinal single track), magic-formula "
                    "tyres (4 states)"),
    "quarter_car_relax": dict(
        rhs=quarter_car_relax, states=("s", "v", "v_slip", "kappa_t"), inputs=("T",),
        x0=(0.0, 5.0, 0.0, 0.0), u0=(-800.0,), t_span=(0.0, 0.5),
        description="quarter car with transient tyre slip: a lightly damped wheel-tyre mode "
                    "(4 states)"),
}
