"""Shooting (paper Algorithm 3): the pure-pursuit steer angle towards each selected point, all
shootings of one expansion integrated in one vectorised call of the zoo's driver, and for each
its travelled distance g, its distance H to the destination and its validity verdict."""
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from stepzoo import dynamics
from stepzoo.dynamics.linear import lateral_matrix
from stepzoo.dynamics.models import steered
from stepzoo.integrators import integrate_batch, kept_programs, method
from stepzoo.search.world.validity import ValidityChecker


CHECK_SPACING_M = 0.2  # [m] at most between the poses of a shooting checked for collision


class Shots(NamedTuple):
    states: np.ndarray  # (B, N+1, 5) [X, Y, psi, vy, r] at steps of h
    steer: np.ndarray   # (B,) [rad] the steer at each shooting's end (its constant steer if
    #                     instant; rate-limited, it ramps there from steer0)
    steer0: np.ndarray  # (B,) [rad] the steer at each shooting's start
    g: np.ndarray       # (B,) [m] distance travelled along each shooting
    H: np.ndarray       # (B,) [m] distance from each end to the destination
    valid: np.ndarray   # (B,) bool: finite and collision-free; invalid ones cost infinity
    free: np.ndarray    # (B,) int: leading rows that are finite and collision-free (N+1 if valid)
    travelled: np.ndarray  # (B, N+1) [m] distance along each shooting up to each row


def pure_pursuit(state, points, wheelbase, delta_max) -> np.ndarray:
    """(B,) [rad]: the steer of the circle from `state` [X, Y, psi, ...] (or one state per
    point, (B, 3+)) through each point (B, 2) [m], delta = atan(2 L sin(alpha) / l_d),
    clipped to +-delta_max."""
    points, state = np.asarray(points, float), np.asarray(state, float)
    dx, dy = points[:, 0] - state[..., 0], points[:, 1] - state[..., 1]
    alpha = np.arctan2(dy, dx) - state[..., 2]
    lookahead = np.maximum(np.hypot(dx, dy), 1e-9)
    steer = np.arctan(2 * wheelbase * np.sin(alpha) / lookahead)
    return np.minimum(np.maximum(steer, -delta_max), delta_max)


class Shooter:
    """Integrates B shootings of n_steps steps of h [s] from one node with `method_name`, on
    the reduced dynamic bicycle (paper eq. 4) at constant speed vx [m/s]; `reverse`: backwards
    at vx on the kinematic bicycle (the tyre model of eq. 4 holds for forward travel only; at
    parking speeds the car rolls without slip), the lateral states vy, r reported as 0;
    `tight`: forwards on the kinematic bicycle, the car at parking speed, which turns at
    L / tan(delta) where eq. 4's understeer at vx widens the turn (3.3 m instead of 2.6 m at
    full lock for the default car at 5 m/s).

    `max_steer_rate` [rad/s] or None (instant): with a rate, the steer is a state (the model
    `dynamics.models.steered`) and each shooting ramps it at a constant rate from the node's
    steer to its end steer, which lies within max_steer_rate times the horizon of it, as
    Hybrid A*'s and CommonRoad's steer-rate inputs do, except from a standstill (a start steer
    of NaN: the start, a cusp), where the driver turns the wheel before moving off and the
    shooting holds its end steer; without, each shooting holds one steer, set at once, as the
    paper. Rate-limited, the kinematic shootings drive the kinematic bicycle as a rigid car
    (dynamics "kinematic_cg": its (X, Y) the centre of gravity, psi the body, as the dynamic
    bicycle's), so that every row of a plan is one car's pose: turning the wheel at a
    standstill turns the body nowhere, and the centre of gravity sets off at the new steer's
    slip beside the body; without, the paper's kinematic bicycle (eq. pm), whose (X, Y)
    moves along its psi."""

    def __init__(self, checker: ValidityChecker, vehicle: str, vx: float, method_name: str,
                 h: float, n_steps: int, batch: int, delta_max: float, reverse: bool = False,
                 tight: bool = False, max_steer_rate: float | None = None):
        self.reverse = reverse
        self.kinematic = reverse or tight
        self.rate = max_steer_rate
        kinematic = "kinematic" if max_steer_rate is None else "kinematic_cg"
        self.model = dynamics.model(kinematic if self.kinematic else "dynamic5")
        self.rhs = self.model.rhs if self.rate is None else steered(self.model.rhs)
        self.checker = checker
        self.method = method(method_name)
        self.method_name = method_name
        self.h, self.n_steps, self.batch, self.delta_max = h, n_steps, batch, delta_max
        p = self.model.params(vehicle, vx)
        self.wheelbase = p["Lf"] + p["Lr"]
        self.vx = float(vx)
        # Every leaf batched once: the driver then sees the same shapes at every expansion and
        # compiles once per (method, batch, n_steps).
        self.p = {k: jnp.full((batch,), float(v)) for k, v in p.items()}
        self.scalars = {k: float(v) for k, v in p.items()}

    @property
    def duration(self) -> float:
        """[s] of one shooting."""
        return self.n_steps * self.h

    def end_steers(self, steer0, target) -> np.ndarray:
        """(B,) [rad] the end steers of shootings from steers `steer0` aiming at `target`
        (B,): the target, within max_steer_rate times the horizon of steer0 (rate-limited)."""
        target = np.asarray(target, float)
        if self.rate is None:
            return target
        reach = self.rate * self.duration
        with np.errstate(invalid="ignore"):
            return np.where(np.isnan(steer0), target, np.clip(target, steer0 - reach,
                                                              steer0 + reach))

    def start_steers(self, steer0, steer) -> np.ndarray:
        """(B,) [rad] the start steers of shootings to end steers `steer` (B,) from `steer0`
        (one or (B,), NaN: from a standstill, where the shooting starts at its end steer)."""
        steer0 = np.broadcast_to(np.asarray(steer0, float), np.shape(steer))
        return np.where(np.isnan(steer0), steer, steer0)

    def integrate(self, x0, steer, steer0=None) -> np.ndarray:
        """(B, 5) states and (B,) end steers (and, rate-limited, (B,) start steers, NaN: from a
        standstill) -> (B, N+1, 5) trajectories."""
        return integrate_together([(self, x0, steer, steer0)])[0]

    def model_inputs(self, x0, steer, steer0=None) -> tuple[np.ndarray, np.ndarray]:
        """The model's initial states and inputs of `integrate`'s shootings: (B, d) and (B, m)
        NumPy arrays (NumPy arguments go straight into the jitted driver; jnp conversions
        here would each be a separate dispatch, costing more than the integration itself)."""
        x0, steer = np.asarray(x0, float), np.asarray(steer, float)
        B = len(x0)
        if self.kinematic:
            speed = -self.vx if self.reverse else self.vx
            x0 = np.column_stack([x0[:, :3], np.full(B, speed)])  # [X, Y, theta, v]
        if self.rate is None:
            inputs = steer[:, None]
        else:
            # The steer a state, its constant rate the input.
            steer0 = self.start_steers(steer0, steer)
            x0, inputs = np.column_stack([x0, steer0]), ((steer - steer0) / self.duration)[:, None]
        if self.kinematic:
            inputs = np.column_stack([inputs, np.zeros(B)])            # [delta or rate, F = 0]
        return x0, inputs

    def poses(self, x) -> np.ndarray:
        """(B, N+1, 5) [X, Y, psi, vy, r] from the model's trajectories `x` (B, N+1, d): the
        kinematic bicycle's lateral states reported as 0."""
        x = np.asarray(x)
        if not self.kinematic:
            return x[..., :5]
        out = np.zeros((*x.shape[:2], 5))
        out[..., :3] = x[..., :3]
        return out

    def settled(self, x0, steer0, settle) -> np.ndarray:
        """`x0` (B, 5) with the lateral states (vy, r) of the rows `settle` (B,) bool at the
        dynamic bicycle's steady state for their steer `steer0` (B,) [rad]: -A^-1 b of its
        linear lateral dynamics (dynamics.linear.lateral_matrix)."""
        x0 = np.array(x0, float)
        if self.kinematic or settle is None or not np.any(settle):
            return x0
        rows = np.flatnonzero(settle)
        delta = np.asarray(steer0, float)[rows]
        A, b = lateral_matrix(self.vx, delta, self.scalars, np)
        x0[rows, 3:5] = -np.linalg.solve(np.moveaxis(A, 2, 0), b.T[..., None])[..., 0]
        return x0

    def shoot(self, state, points, destination, steer0=0.0, settle=None) -> Shots:
        """Shoot from `state` (5,), or from one state per point (B, 5), at steer `steer0`
        [rad] (one or (B,); NaN: from a standstill), towards each of `points` (B, 2) [m]."""
        start = np.broadcast_to(np.asarray(state, float), (self.batch, 5))
        return self.shoot_steers(start, self.aim(start, points, steer0), destination, steer0,
                                 settle)

    def aim(self, state, points, steer0=0.0) -> np.ndarray:
        """(B,) [rad] the end steers of shootings from `state` (5,) or (B, 5) at steer `steer0`
        towards `points` (B, 2) [m]: pure pursuit, within the steer rate's reach."""
        start = np.broadcast_to(np.asarray(state, float), (self.batch, 5))
        if self.reverse:
            # Backwards, the car follows the circle of curvature -tan(delta)/L relative to
            # its direction of travel psi + pi: pure pursuit on the flipped pose, negated.
            flipped = start[:, :3] + (0.0, 0.0, np.pi)
            steer = -pure_pursuit(flipped, points, self.wheelbase, self.delta_max)
        else:
            steer = pure_pursuit(start, points, self.wheelbase, self.delta_max)
        return self.end_steers(steer0, steer)

    def shoot_steers(self, state, steer, destination, steer0=0.0, settle=None) -> Shots:
        """Shoot from `state` (5,), or one state per steer (B, 5), at steer `steer0` [rad]
        (rate-limited; NaN: from a standstill), to the end steers `steer` (B,) [rad]; the
        shootings `settle` (B,) bool start at the lateral steady state of their steer
        (`settled`)."""
        start = self.launch(state, steer, steer0, settle)
        return self.shots(self.integrate(start, steer, steer0), steer, steer0, destination)

    def launch(self, state, steer, steer0=0.0, settle=None) -> np.ndarray:
        """(B, 5) the start states of `shoot_steers`' shootings."""
        start = np.broadcast_to(np.asarray(state, float), (self.batch, 5))
        if settle is not None:
            start = self.settled(start, self.start_steers(steer0, steer), settle)
        return start

    def shots(self, states, steer, steer0, destination) -> Shots:
        """The Shots of shootings integrated to `states` (K, N+1, 5), to end steers `steer`
        (K,) [rad] from `steer0` (one or (K,); NaN: from a standstill), towards `destination`
        [X, Y, ...] [m]: distances, and validity against the checker."""
        steer = np.asarray(steer, float)
        steer0 = np.broadcast_to(np.asarray(steer0, float), steer.shape)
        # A blown-up shooting is a result (an invalid one), so its overflow warnings are noise;
        # first_collision treats non-finite poses as collisions, so it needs no branch either.
        with np.errstate(invalid="ignore", over="ignore"):
            step = states[:, 1:, :2] - states[:, :-1, :2]
            travelled = np.zeros(states.shape[:2])
            np.cumsum(np.hypot(step[..., 0], step[..., 1]), axis=1, out=travelled[:, 1:])
            H = np.hypot(*(states[:, -1, :2] - destination[:2]).T)
            rows = states.shape[1]
            # Every stride-th pose and the last: first_collision checks the straight
            # interpolation between them, which strays from the arc by s^2 / (8 R), 2 mm for
            # s = CHECK_SPACING_M on the tightest turn (R = 2.6 m), far inside the margin.
            stride = max(1, int(CHECK_SPACING_M / max(self.vx * self.h, 1e-12)))
            checked = np.unique(np.r_[np.arange(0, rows, stride), rows - 1])
            hit = self.checker.first_invalid(states[:, checked, :3])
            # Rows before the last checked pose that is clear are clear.
            first = np.where(hit > 0, checked[np.maximum(hit - 1, 0)] + 1,
                             np.where(hit == 0, 0, -1))
        finite = np.isfinite(states).all(axis=2)
        free = np.minimum(np.where(first >= 0, first, rows),
                          np.where(finite.all(axis=1), rows, np.argmin(finite, axis=1)))
        valid = free == rows
        steer0 = steer if self.rate is None else self.start_steers(steer0, steer)
        return Shots(states, steer, steer0, travelled[:, -1], H, valid, free, travelled)


def integrate_together(requests) -> list[np.ndarray]:
    """[(B, N+1, 5) trajectories] of each request (shooter, x0 (B, 5), steer (B,), steer0) as
    that shooter's `integrate` gives them, all integrated in one call of one compiled program
    (the same shootings to rounding: each trajectory is its own in the driver's batch)."""
    shooters = [r[0] for r in requests]
    # Compiled once per (method, rhs, steps) of each shooter and the shapes, as the driver
    # compiles one call: shooters of other finders with the same models share the program.
    static = tuple((s.method_name, s.rhs, s.n_steps) for s in shooters)
    args = [(*shooter.model_inputs(x0, steer, steer0), shooter.p, shooter.h)
            for shooter, x0, steer, steer0 in requests]
    # Kept across processes where the command keeps the driver's programs (a warm start-up
    # then traces none of the shooters' models and methods).
    xs = jax.device_get(kept_programs.call(_together, "shooting._together", (static,), {},
                                           (args,), {}))
    return [shooter.poses(x) for shooter, x in zip(shooters, xs)]


@partial(jax.jit, static_argnums=0)
def _together(static, args):
    """The driver's trajectories of each (x0, inputs, p, h) of `args` with its (method, rhs,
    n_steps) of `static`, traced into one program."""
    return [integrate_batch(method_name, rhs, x0, u, p, h, n_steps).x
            for (method_name, rhs, n_steps), (x0, u, p, h) in zip(static, args)]
