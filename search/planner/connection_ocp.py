"""The connection of the paper (Section 2.4): a minimum-time optimal control problem on the
kinematic bicycle from a tree node to the goal pose, solved with IPOPT through CasADi's nlpsol.
With the car's limits, the steer is a state whose rate is the bounded control and v^2 kappa is
bounded; without, the steer is a control, as the paper. One parametrised solver per (N,
shooting, method, options) is built once and called with the problem's numbers as parameters
and bounds."""
from dataclasses import dataclass
from functools import cache
import math
from math import pi
from time import perf_counter
from typing import Callable, NamedTuple

import casadi as ca
import jax.numpy as jnp
import numpy as np

from stepzoo.dynamics.kinematic import (kinematic_bicycle, kinematic_terms, rigid_bicycle,
                                         rigid_terms, shifted)
from stepzoo.dynamics.models import steered
from stepzoo.integrators import integrate, method as zoo_method
from stepzoo.integrators.methods import TABLEAUS
from stepzoo.integrators.steps import rk_slopes, weighted
from stepzoo.search.proofs.car_bounds import reeds_shepp_words

# Multiple shooting solved as many seeded problems as single shooting, faster and without
# retries (docs/studies/measurements-behind-defaults-2026-11.md has the numbers).
DEFAULT_SHOOTING = "multiple"
# rk4 costs what Euler costs here (the NLP dominates) but is faithful: a re-simulation 10
# times finer ends micrometres from the goal, against decimetres for the paper's Euler.
DEFAULT_METHOD = "rk4"
# The paper leaves F free, which makes minimum time degenerate (infinite force, zero time):
# F is bounded by m * A_MAX, a firm but ordinary passenger-car acceleration/braking level.
A_MAX = 4.0            # [m/s^2]
TF_BOUNDS = (0.1, 30.0)  # [s]; the lower bound keeps dt = t_f/N away from zero
# Below the per-metre bound's speed the steer may still turn this fraction of its rate at a
# standstill: the bound's gradient does not vanish at v = 0 (a cusp), where IPOPT needs it.
STANDSTILL_RATE = 0.05   # [1]
THETA_MARGIN = 2 * pi  # [rad] beyond the start and goal headings: room for one loop, no more
END_TOL = 1e-6         # [m, rad, m/s] end-constraint residual accepted as success
MAX_TRIES = 3          # solves (one per winding and first direction, and one more in a
#                        corridor where a solution touches) before giving up


MIN_ROOM = 0.01        # [m] the least room a disc of the corridor gets: a guess touching
#                        an obstacle leaves the solve a sliver, not an empty set
ROOM_SHIFTS = (0.25, 0.5, 1.0, 2.0)  # [m] how far a corridor ball's centre may lie from
ROOM_DIRECTIONS = 8                  # its disc's, in this many directions (_rooms)
CRAWL_DT = 0.005         # [s] the time step the crawl guess is built on (_crawl_guess)
CRAWL_MAX_STEPS = 24000  # its steps at most: 120 s
CRAWL_SNAP_M = 1e-3      # [m] it is at a joint of its path this close to it
CRAWL_SPACING_M = 0.02   # [m] between the path's poses it interpolates


class Corridor(NamedTuple):
    """What the connection keeps clear of (rate-limited): the car's body as discs of
    `radius` [m] at `offsets` (J,) [m] along its heading psi from (X, Y), and `clearance`,
    points (..., 2) [m] -> (...) [m] a lower bound of their distance to the nearest obstacle
    (OccupancyMap.clearance)."""
    offsets: np.ndarray
    radius: float
    clearance: Callable


@dataclass(frozen=True)
class Connection:
    """A solved (or failed) connection; arrays hold IPOPT's last iterate on failure."""
    success: bool        # IPOPT converged and the end constraint holds
    status: str          # IPOPT's return status
    tf: float            # [s]
    t: np.ndarray        # (N+1,) [s]
    states: np.ndarray   # (N+1, 4) [X, Y, theta, v] in [m, m, rad, m/s] (steer_rates: the
    #                      rigid car's [X, Y, psi, v], its centre of gravity and body)
    inputs: np.ndarray   # (N, 2) [delta rad, F N], piecewise constant (delta: at each
    #                      interval's start if steer_rates)
    solve_s: float       # wall time of `connect`: guess and every IPOPT try [s]
    shooting: str        # "single" | "multiple"
    steer_rates: np.ndarray | None = None  # (N,) [rad/s] the steer's rate over each interval
    #                      (the steer a state, piecewise linear); None: the steer a control


@cache
def step_function(method: str, steered: bool = False) -> ca.Function:
    """One step x_{n+1} = step(x_n, u_n, h, L, m, Lr) of an explicit tableau of the zoo, on
    the paper's kinematic bicycle (Lr unused); `steered`: on the rigid car (dynamics
    kinematic_cg: Lr [m] from the rear axle to its centre of gravity), the state [X, Y, psi,
    v, delta], the inputs [ddelta, F] (dynamics.models.steered)."""
    if method not in TABLEAUS:
        raise KeyError(f"unknown method {method!r}; known: {', '.join(TABLEAUS)}")
    tab = TABLEAUS[method]
    if not tab.explicit:
        raise ValueError(f"method {method!r} is implicit; the connection needs an explicit one")
    x, u = ca.SX.sym("x", 4 + steered), ca.SX.sym("u", 2)
    h, L, m, Lr = ca.SX.sym("h"), ca.SX.sym("L"), ca.SX.sym("m"), ca.SX.sym("Lr")
    if steered:
        f = lambda t, y: ca.vertcat(*rigid_terms(y, ca.vertcat(y[4], u[1]), L, Lr, m, ca.cos,
                                                 ca.sin, ca.tan, ca.sqrt), u[0])
    else:
        f = lambda t, y: ca.vertcat(*kinematic_terms(y, u, L, m, ca.cos, ca.sin, ca.tan))
    x_next = x + h * weighted(tab.b, rk_slopes(tab.a, tab.c, f, 0.0, x, h, tab.needed))
    return ca.Function(f"step_{method}{'_steered' * steered}", [x, u, h, L, m, Lr], [x_next])


def unwrap(theta, reference):
    """The 2*pi-equivalent of heading `theta` nearest `reference` [rad]."""
    return reference + float(np.remainder(theta - reference + pi, 2 * pi) - pi)


@cache
def _open_loop(N: int, method: str, steered: bool = False) -> ca.Function:
    """States (4 or 5, N+1) of the discrete model from x0 under inputs (2, N), step h."""
    step = step_function(method, steered)
    x0, us = ca.MX.sym("x0", 4 + steered), ca.MX.sym("u", 2, N)
    h, L, m, Lr = ca.MX.sym("h"), ca.MX.sym("L"), ca.MX.sym("m"), ca.MX.sym("Lr")
    xs = step.mapaccum("roll", N)(x0, us, h, L, m, Lr)
    return ca.Function(f"open_loop{N}", [x0, us, h, L, m, Lr], [ca.horzcat(x0, xs)])


def _mod(a):
    """Angle in [0, 2 pi) [rad]."""
    return np.remainder(a, 2 * pi)


def _dubins_words(alpha, beta, d):
    """(turn signs, normalised segment lengths) of the six Dubins words from heading alpha to
    heading beta over distance d, both headings measured from the chord (unit radius)."""
    sa, sb, c_a, c_b = np.sin(alpha), np.sin(beta), np.cos(alpha), np.cos(beta)
    cab = np.cos(alpha - beta)
    words = []
    p2 = 2 + d * d - 2 * cab + 2 * d * (sa - sb)
    if p2 >= 0:
        tmp = np.arctan2(c_b - c_a, d + sa - sb)
        words.append(((1, 0, 1), (_mod(tmp - alpha), np.sqrt(p2), _mod(beta - tmp))))
    p2 = 2 + d * d - 2 * cab + 2 * d * (sb - sa)
    if p2 >= 0:
        tmp = np.arctan2(c_a - c_b, d - sa + sb)
        words.append(((-1, 0, -1), (_mod(alpha - tmp), np.sqrt(p2), _mod(tmp - beta))))
    p2 = -2 + d * d + 2 * cab + 2 * d * (sa + sb)
    if p2 >= 0:
        p = np.sqrt(p2)
        tmp = np.arctan2(-c_a - c_b, d + sa + sb) - np.arctan2(-2, p)
        words.append(((1, 0, -1), (_mod(tmp - alpha), p, _mod(tmp - beta))))
    p2 = d * d - 2 + 2 * cab - 2 * d * (sa + sb)
    if p2 >= 0:
        p = np.sqrt(p2)
        tmp = np.arctan2(c_a + c_b, d - sa - sb) - np.arctan2(2, p)
        words.append(((-1, 0, 1), (_mod(alpha - tmp), p, _mod(beta - tmp))))
    c = (6 - d * d + 2 * cab + 2 * d * (sa - sb)) / 8
    if abs(c) <= 1:
        p = _mod(2 * pi - np.arccos(c))
        t = _mod(alpha - np.arctan2(c_a - c_b, d - sa + sb) + p / 2)
        words.append(((-1, 1, -1), (t, p, _mod(alpha - beta - t + p))))
    c = (6 - d * d + 2 * cab + 2 * d * (sb - sa)) / 8
    if abs(c) <= 1:
        p = _mod(2 * pi - np.arccos(c))
        t = _mod(-alpha + np.arctan2(c_b - c_a, d + sa - sb) + p / 2)
        words.append(((1, -1, 1), (t, p, _mod(beta - alpha - t + p))))
    return words


def _advance(pose, sign, length, radius):
    """Pose [X, Y, theta] after driving `length` [m] on a turn of `sign` (0 straight); an
    array of lengths (n,) gives poses (3, n)."""
    x, y, th = pose
    if sign == 0:
        return np.stack(np.broadcast_arrays(x + length * np.cos(th), y + length * np.sin(th),
                                            th))
    dth = sign * length / radius
    return np.array([x + sign * radius * (np.sin(th + dth) - np.sin(th)),
                     y + sign * radius * (np.cos(th) - np.cos(th + dth)), th + dth])


def _arrives(start, segs, goal, radius) -> bool:
    """Whether driving `segs` (turn sign, signed length [m]) from `start` ends at `goal`."""
    pose = start
    for sign, length in segs:
        pose = _advance(pose, sign, length, radius)
    miss = np.r_[pose[:2] - goal[:2], np.sin((pose[2] - goal[2]) / 2)]
    return bool(np.abs(miss).max() < 1e-6 * (1 + radius))


def dubins_paths(start, goal, radius):
    """Forward paths of curvature <= 1/radius (Dubins 1957) from pose `start` to `goal`
    ([X, Y, theta], [m, rad]), shortest first: lists of (turn sign, length [m]). Each word of
    the closed form is driven and kept only if it arrives, so a degenerate case cannot slip
    through."""
    start, goal = np.asarray(start, float), np.asarray(goal, float)
    dx, dy = goal[:2] - start[:2]
    chord = np.arctan2(dy, dx)
    paths = []
    for signs, lengths in _dubins_words(_mod(start[2] - chord), _mod(goal[2] - chord),
                                        np.hypot(dx, dy) / radius):
        segs = [(s, radius * q) for s, q in zip(signs, lengths)]
        if _arrives(start, segs, goal, radius):
            paths.append(segs)
    return sorted(paths, key=lambda segs: sum(q for _, q in segs))


def reeds_shepp_paths(start, goal, radius):
    """Paths of curvature <= 1/radius forwards and backwards (Reeds & Shepp 1990) from pose
    `start` to `goal`, shortest first: lists of (turn sign, signed length [m], negative
    backwards); each word driven and kept only if it arrives, as dubins_paths."""
    start, goal = np.asarray(start, float), np.asarray(goal, float)
    paths = []
    for ok, segs in reeds_shepp_words(start[None], goal, radius):
        segs = [(turn, float(q[0])) for turn, q in segs]
        if ok[0] and _arrives(start, segs, goal, radius):
            paths.append(segs)
    return sorted(paths, key=lambda segs: sum(abs(q) for _, q in segs))


def guess_paths(start, goal, radius, reverse) -> list:
    """The paths the connection's guesses drive from pose `start` to `goal` ([X, Y, theta],
    [m, rad]) at turning radius `radius` [m]: dubins_paths, then with reverse gear
    reeds_shepp_paths."""
    paths = dubins_paths(start, goal, radius)
    return paths + reeds_shepp_paths(start, goal, radius) if reverse else paths


def path_poses(start, segs, radius, spacing) -> np.ndarray:
    """(K, 3) poses [X, Y, theta] along the path `segs` (from dubins_paths or
    reeds_shepp_paths) from `start`, at most `spacing` [m] apart, both ends included."""
    pose = np.asarray(start, float)
    poses = [pose[None]]
    for sign, length in segs:
        n = max(1, math.ceil(abs(length) / spacing))
        # _advance is elementwise: an array of lengths gives (3, n) poses at once.
        poses.append(_advance(pose, sign, length * np.arange(1, n + 1) / n, radius).T)
        pose = poses[-1][-1]
    return np.vstack(poses)


def _fastest_profile(s_total, v0, a_max, v_max, v_goal):
    """Switch times (t1, t2, tf) [s] of the minimum-time speed profile over s_total [m]:
    accelerate at a_max until t1, cruise until t2, brake at a_max until tf."""
    if v_goal is None:
        reach = (v_max ** 2 - v0 ** 2) / (2 * a_max)
        if s_total <= reach:
            tf = (np.sqrt(v0 ** 2 + 2 * a_max * s_total) - v0) / a_max
            return tf, tf, tf
        t1 = (v_max - v0) / a_max
        tf = t1 + (s_total - reach) / v_max
        return t1, tf, tf
    peak = min(v_max, np.sqrt(max(a_max * s_total + (v0 ** 2 + v_goal ** 2) / 2, 0.0)))
    t1, t3 = max(peak - v0, 0.0) / a_max, max(peak - v_goal, 0.0) / a_max
    s13 = (peak ** 2 - v0 ** 2) / (2 * a_max) + (peak ** 2 - v_goal ** 2) / (2 * a_max)
    cruise = max(s_total - s13, 0.0) / max(peak, 1e-9)
    return t1, t1 + cruise, t1 + cruise + t3


def _runs(segs) -> list:
    """The path `segs` as runs driven one way: [(direction +1 or -1, [(turn, length [m])])]."""
    runs: list[tuple[int, list[tuple[int, float]]]] = []
    for sign, length in segs:
        if length == 0:
            continue
        way = 1 if length > 0 else -1
        if runs and runs[-1][0] == way:
            runs[-1][1].append((sign, abs(length)))
        else:
            runs.append((way, [(sign, abs(length))]))
    return runs or [(1, [(0, 0.0)])]


class _Guess(NamedTuple):
    """A connection guess: a Dubins or Reeds-Shepp path driven as fast as the car can."""
    turn: float   # [rad] net heading change
    tf: float     # [s] its duration
    runs: list    # the runs between cusps (_runs)
    plans: list   # per run (start speed [m/s], (t1, t2, t_end) [s]) (_fastest_profile)


class _Solution(NamedTuple):
    """One OCP solve: whether it met the goal, IPOPT's status, t_f [s], the states (N+1, 4),
    the inputs (N, 2) [delta, F] and, steered, the steer rates (N,) [rad/s]."""
    success: bool
    status: str
    tf: float
    states: np.ndarray
    inputs: np.ndarray
    steer_rates: np.ndarray | None


def _profile(segs, radius, start, a_max, v_max, v_goal, v_back=0.0) -> _Guess:
    """Net heading change [rad], t_f [s], and the runs between cusps with their fastest
    speed profiles [(start speed [m/s], (t1, t2, t_end) [s])] of driving the path `segs`
    (signed lengths: backwards below 0) of turning radius `radius` [m]: each run from rest to
    rest (the first from the start's speed, after braking to rest straight ahead if the start
    moves the other way; the last to v_goal), at most v_max forwards and v_back backwards
    [m/s]. Ignoring the map, this is the continuous optimum for the shortest Dubins path:
    turning costs no speed in this model."""
    turn = sum(s * q / radius for s, q in segs)
    runs, plans = _runs(segs), []
    if start[3] * runs[0][0] < 0:
        runs.insert(0, (1 if start[3] > 0 else -1, [(0, start[3] ** 2 / (2 * a_max))]))
    for k, (way, run) in enumerate(runs):
        v0 = max(way * start[3], 0.0) if k == 0 else 0.0
        v_end = (None if v_goal is None else max(way * v_goal, 0.0)) if k == len(runs) - 1 \
            else 0.0
        plans.append((v0, _fastest_profile(sum(q for _, q in run), v0, a_max,
                                           v_max if way > 0 else v_back, v_end)))
    return _Guess(turn, float(sum(profile[2] for _, profile in plans)), runs, plans)


def _steer_ramps(signs, steer0, delta_max, rate_max, dt):
    """(N,) scaled steer rates [1] (of rate_max) that follow the steers signs * delta_max
    (N,) from steer0 [rad] as fast as rate_max [rad/s] allows, over intervals of dt [s]."""
    rates, steer, step = np.zeros(len(signs)), steer0, rate_max * dt
    for i, sign in enumerate(signs):
        change = float(np.clip(sign * delta_max - steer, -step, step))
        rates[i], steer = change / step, steer + change
    return rates


def _progress(t, runs, plans, a_max):
    """(run index, time into it [s], distance along it [m]) at time `t` [s] of driving `runs`
    at their speed profiles `plans` (from `_profile`)."""
    ends = np.cumsum([profile[2] for _, profile in plans])
    k = min(int(np.searchsorted(ends, t)), len(runs) - 1)
    v0, (t1, t2, _) = plans[k]
    tau = t - (ends[k - 1] if k else 0.0)
    # Accelerate until t1, cruise until t2, then brake.
    a1, a2, a3 = min(tau, t1), min(max(tau - t1, 0.0), t2 - t1), max(tau - t2, 0.0)
    peak = v0 + a_max * t1
    return k, tau, v0 * a1 + a_max * a1 ** 2 / 2 + peak * (a2 + a3) - a_max * a3 ** 2 / 2


def _guess_inputs(N, runs, plans, a_max):
    """Scaled inputs (2, N) [steer sign, acceleration / a_max] at the midpoints of N equal
    intervals of driving `runs` at their speed profiles `plans` (from `_profile`)."""
    tf = float(sum(profile[2] for _, profile in plans))
    steer, acc = np.zeros(N), np.zeros(N)
    for i, t in enumerate((np.arange(N) + 0.5) * tf / N):
        k, tau, s = _progress(t, runs, plans, a_max)
        way, run = runs[k]
        t1, t2 = plans[k][1][:2]
        along = np.cumsum([q for _, q in run])
        steer[i] = run[min(int(np.searchsorted(along, s)), len(run) - 1)][0]
        acc[i] = way * (1.0 if tau < t1 else 0.0 if tau < t2 else -1.0)
    return np.vstack([steer, acc])


def _guess_poses(N, start, radius, runs, plans, a_max):
    """(N, 3) poses [X, Y, theta] at the ends of N equal intervals of driving `runs` at their
    speed profiles `plans` (from `_profile`) from pose `start` on turns of `radius` [m]."""
    firsts = [np.asarray(start, float)[:3]]
    for way, run in runs:
        firsts.append(path_poses(firsts[-1], [(sign, way * q) for sign, q in run], radius,
                                 np.inf)[-1])
    tf = float(sum(profile[2] for _, profile in plans))
    poses = np.zeros((N, 3))
    for i, t in enumerate(np.arange(1, N + 1) * tf / N):
        k, _, s = _progress(t, runs, plans, a_max)
        way, run = runs[k]
        pose, left = firsts[k], s
        for sign, q in run:
            pose = _advance(pose, sign, way * min(q, max(left, 0.0)), radius)
            left -= q
        poses[i] = pose
    return poses


@dataclass(frozen=True)
class _Problem:
    """A built IPOPT solver and the maps from its variables to the connection."""
    watch: "_StallWatch"  # its iteration callback
    solver: ca.Function   # nlpsol: x = [T, vec(U)(, vec(Z))], p = [x0, goal, L, m, d_max,
    #                       a_max(, rate_max, a_lat, v_steer, Lr)(, the corridor's
    #                       offsets, centres)(, v_goal)]; g = [defects
    #                       (multiple), end, state rows (single), lateral acceleration / a_lat
    #                       and the steer rate per metre (steered)]
    rollout: ca.Function  # (T, U, p) -> states (nx, N+1) simulated from x0
    path: ca.Function     # (x, p) -> states (nx, N+1), inputs (2, N) [rad or rad/s, N]
    shooting: str
    n_end: int            # end-constraint rows: X, Y, theta (, v)
    rows: slice           # which of [X, Y, theta, v(, delta)] single shooting bounds in g
    nx: int               # 4, or 5 steered: the steer a state


# Variable bounds instead of constraints, nlpsol instead of Opti, fast_step_computation and,
# for multiple shooting, the adaptive barrier update with kkt-error globalisation: each was
# faster at the same solved count on the scenario connections and seeded problems; the
# options that were not (spral, limited-memory Hessians, mu-based bound multipliers) are left
# out. The study: docs/studies/measurements-behind-defaults-2026-11.md.
IPOPT_OPTIONS: dict[str, int | str] = {"print_level": 0, "sb": "yes", "max_iter": 100,
                                       "fast_step_computation": "yes"}
ADAPTIVE_MU: dict[str, int | str] = {"mu_strategy": "adaptive",
                                     "adaptive_mu_globalization": "kkt-error"}
# A solve whose line search cut the primal step below SHORT_STEP this many times is given up
# (status STALLED): the solves that went on to max_iter took such steps in most iterations,
# several trial points each, while no converged solve took as many (the study:
# docs/studies/plan-success-2026-11-28f.md).
SHORT_STEP = 0.1   # [1] of the full primal step
SHORT_STEPS = 40   # [1]
STALLED = "Stalled"
# The parameters before a steered problem's limits (rate_max, a_lat, v_steer, Lr), after its
# nx states x0: the goal [X, Y, theta], L, m, d_max, a_max.
LIMITS_AT = 7


# IPOPT's status where an exception not its own (CasADi's KeyboardInterruptException: these
# solves' expanded functions raise no other) ended a solve.
INTERRUPTED = "NonIpopt_Exception_Thrown"


class _StallWatch(ca.Callback):
    """IPOPT's iteration callback: stops the solve of `solver` (set after it is built) once
    SHORT_STEPS of its iterations took a primal step below SHORT_STEP (its live stats, read
    only from the SHORT_STEPS-th iteration on: `calls`, reset before each solve, counts
    them), or at once on a Ctrl-C (`interrupted`, reset before each solve)."""

    def __init__(self, name: str):
        ca.Callback.__init__(self)
        self.solver: ca.Function | None = None
        self.calls, self.interrupted = 0, False
        self.construct(name, {})

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "stop"

    def get_sparsity_in(self, i):
        return ca.Sparsity(0, 0)   # it reads the stats, not the iterate

    def eval(self, arg):
        # The one place Python runs during a solve, so where a Ctrl-C's KeyboardInterrupt is
        # raised; CasADi would swallow it and go on solving: it stops the solve, and _solve
        # raises it again.
        try:
            return self._stop()
        except KeyboardInterrupt:
            self.interrupted = True
            return [1]

    def _stop(self):
        self.calls += 1
        if self.calls < SHORT_STEPS:
            return [0]
        assert self.solver is not None
        alpha = self.solver.stats()["iterations"]["alpha_pr"]
        return [int(sum(a < SHORT_STEP for a in alpha) >= SHORT_STEPS)]


@cache
def _problem(N: int, shooting: str, method: str, bounded: bool, speed_fixed: bool,
             steered: bool = False, discs: int = 0) -> _Problem:
    """The parametrised minimum-time OCP, positions relative to the start node; `steered`:
    the steer a state, its rate the control, v^2 tan(delta) / L bounded, and below the speed
    v_steer the steer rate bounded per metre (rate_max / v_steer [rad/m]); `discs` (steered):
    the squared distance of each of that many discs of the car's body (their offsets
    parameters) at each node 1..N from a parametrised centre, whose bounds the solve sets."""
    nx = 4 + steered
    k = nx + LIMITS_AT            # parameters before (rate_max, a_lat, v_steer, Lr), the
    #                               discs' (offsets, centres (2, N * discs)) and v_goal
    n_discs = (discs + 2 * N * discs) if discs else 0
    p = ca.MX.sym("p", k + 4 * steered + n_discs + speed_fixed)
    x0, goal, L, m, d_max, a_max = p[:nx], p[nx:nx + 3], p[nx + 3], p[nx + 4], p[nx + 5], \
        p[nx + 6]
    T, U = ca.MX.sym("T"), ca.MX.sym("U", 2, N)
    inputs = ca.vertcat((p[k] if steered else d_max) * U[0, :], m * a_max * U[1, :])
    Lr = p[k + 3] if steered else 0.0
    rollout = _open_loop(N, method, steered)(x0, inputs, T / N, L, m, Lr)
    if shooting == "multiple":
        Z = ca.MX.sym("Z", nx, N)
        x, states = ca.veccat(T, U, Z), ca.horzcat(x0, Z)
        defects = Z - step_function(method, steered).map(N)(states[:, :-1], inputs, T / N, L, m,
                                                            Lr)
        g = [ca.vec(defects)]
    elif shooting == "single":
        x, states, g = ca.veccat(T, U), rollout, []
    else:
        raise ValueError(f"shooting must be 'single' or 'multiple', not {shooting!r}")
    g.append(states[:3, -1] - goal)
    if speed_fixed:
        g.append(states[3, -1] - p[-1])
    rows = slice(0 if bounded else 2, nx)
    if shooting == "single":
        g.append(ca.vec(states[rows, 1:]))
    if steered:
        # Lateral acceleration v^2 kappa, scaled by its limit to order one.
        g.append(ca.vec(states[3, 1:] ** 2 * ca.tan(states[4, 1:]) / (L * p[k + 1])))
        # |rate| <= rate_max |v| / v_steer at both ends of each interval, squared to stay
        # smooth through v = 0: U^2 - (v / v_steer)^2 <= STANDSTILL_RATE^2.
        for ends in (states[3, :-1], states[3, 1:]):
            g.append(ca.vec(U[0, :] ** 2 - (ends / p[k + 2]) ** 2))
    if discs:
        # Each disc centre lies its offset along the body, from the centre of gravity.
        c = k + 4
        offsets = p[c:c + discs]
        centres = ca.reshape(p[c + discs:c + n_discs], 2, N * discs)
        along = ca.repmat(offsets.T, 1, N)                       # disc fastest
        cx, cy, heading = (ca.reshape(ca.repmat(row, discs, 1), 1, N * discs)
                           for row in (states[0, 1:], states[1, 1:], states[2, 1:]))
        g.append(ca.vec((cx + along * ca.cos(heading) - centres[0, :]) ** 2
                        + (cy + along * ca.sin(heading) - centres[1, :]) ** 2))
    ipopt = {**IPOPT_OPTIONS, **ADAPTIVE_MU} if shooting == "multiple" else IPOPT_OPTIONS
    name = f"connect_{shooting}{N}{'_steered' * steered}"
    watch = _StallWatch(f"{name}_watch")
    solver = ca.nlpsol(name, "ipopt",
                       # casadi's stub takes SX alone; nlpsol takes MX as well
                       {"x": x, "p": p, "f": T, "g": ca.vertcat(*g)},  # type: ignore[dict-item]
                       {"expand": True, "print_time": False, "ipopt": ipopt,
                        "iteration_callback": watch})
    watch.solver = solver
    return _Problem(watch, solver, ca.Function("rollout", [T, U, p], [rollout]),
                    ca.Function("path", [x, p], [states, inputs]), shooting, 3 + speed_fixed,
                    rows, nx)


def _solve(prob, p, lo, hi, tf_range, tf_g, u_g, per_metre=False, room=None,
           z_g=None) -> _Solution:
    """One IPOPT solve from the guess (tf_g [s], scaled inputs u_g (2, N), and for multiple
    shooting the states z_g (nx, N) at nodes 1..N, default the inputs' rollout) with
    parameters p, states 1..N within lo..hi ([X, Y, theta, v]) and t_f within tf_range [s] (steered,
    `per_metre`: the steer rate bounded per metre below p's v_steer; `room`: (N * discs,)
    [m] how far each disc may lie from its centre in p): (success, status, tf, states,
    inputs)."""
    N, nx = u_g.shape[1], prob.nx
    x_g = np.r_[tf_g, u_g.ravel(order="F")]
    lbx, ubx = np.r_[tf_range[0], np.full(2 * N, -1.0)], np.r_[tf_range[1], np.ones(2 * N)]
    if prob.shooting == "multiple":
        if z_g is None:
            z_g = np.asarray(prob.rollout(tf_g, u_g, p))[:, 1:]
        x_g = np.r_[x_g, z_g.ravel(order="F")]
        lbx, ubx = np.r_[lbx, np.tile(lo, N)], np.r_[ubx, np.tile(hi, N)]
        lbg = ubg = np.zeros(nx * N + prob.n_end)
    else:
        lbg = np.r_[np.zeros(prob.n_end), np.tile(lo[prob.rows], N)]
        ubg = np.r_[np.zeros(prob.n_end), np.tile(hi[prob.rows], N)]
    if nx == 5:
        lbg = np.r_[lbg, -np.ones(N), np.full(2 * N, -np.inf)]
        ubg = np.r_[ubg, np.ones(N), np.full(2 * N, STANDSTILL_RATE ** 2 if per_metre
                                             else np.inf)]
    if room is not None:
        lbg, ubg = np.r_[lbg, np.full(len(room), -np.inf)], np.r_[ubg, np.square(room)]
    prob.watch.calls, prob.watch.interrupted = 0, False
    sol = prob.solver(x0=x_g, p=p, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
    stats = prob.solver.stats()
    # A Ctrl-C met by CasADi's own interrupt check (as it evaluates the functions) ends the
    # solve by a KeyboardInterruptException, which it does not pass on: the status says it.
    if prob.watch.interrupted or stats["return_status"] == INTERRUPTED:
        raise KeyboardInterrupt
    states, inputs = (np.asarray(a).T.copy() for a in prob.path(sol["x"], p))
    # goal (, v_goal): v_goal is the last parameter when the speed is fixed
    target = np.r_[p[nx:nx + 3], p[len(p) - (prob.n_end - 3):]]
    end = states[-1, :len(target)] - target
    success = bool(stats["success"]) and float(np.abs(end).max()) < END_TOL
    rates = None
    if nx == 5:
        rates = inputs[:, 0].copy()
        inputs[:, 0] = states[:-1, 4]
    status = STALLED if stats["return_status"] == "User_Requested_Stop" else stats["return_status"]
    return _Solution(success, str(status), float(sol["x"][0]), states[:, :4],
                     inputs, rates)


def connect(start, goal, *, L, m, bounds=None, N=50, shooting=DEFAULT_SHOOTING,
            method=DEFAULT_METHOD, goal_speed=None, v_max=25.0, delta_max=pi / 4,
            a_max=A_MAX, tf_bounds=None, v_min=0.0, paths=None, steer0=0.0,
            max_steer_rate=None, max_lateral_acceleration=None,
            steer_speed=None, Lr=0.0, corridor: Corridor | None = None) -> Connection:
    """Minimum-time connection from `start` [X, Y, theta, v] to `goal` [X, Y, theta]
    ([m, m, rad, m/s]), N piecewise-constant input intervals of dt = t_f/N.

    The car's limits: with `max_steer_rate` [rad/s] the steer is a state starting at steer0
    [rad], its rate the control (|ddelta| <= max_steer_rate), and |v^2 tan(delta) / L| <=
    max_lateral_acceleration [m/s^2] at every node (required with it), and below
    `steer_speed` [m/s] (default: no bound per metre) the steer turns at most max_steer_rate /
    steer_speed per metre (STANDSTILL_RATE of its rate at a standstill): a minimum-time car
    does not slow to a crawl to turn the wheel, which leaves a kink no car tracks at speed.
    With it the car is the kinematic bicycle as a rigid car (dynamics kinematic_cg): `start`
    and `goal` are its centre of gravity, Lr [m] ahead of the rear axle, and its body's
    heading, and its guesses drive its rear axle, which turns on circles of L / tan(delta).
    Without max_steer_rate (None, the paper's OCP) the steer is a control. With it, a
    `corridor` keeps the car off the obstacles: at each node each disc of the body lies
    within a ball free of obstacles that holds its guess's disc (`_rooms`: the widest of
    those centred at or beside the disc; a guess disc touching an obstacle gets MIN_ROOM),
    so that the solution is as free as the guess where the guess is free.

    L [m] wheelbase, m [kg] mass; bounds (Xmin, Xmax, Ymin, Ymax) [m] or None; goal_speed
    [m/s] or None (free); v_min <= v <= v_max [m/s] (v_min < 0 lets the car reverse),
    |delta| <= delta_max [rad],
    |F| <= m a_max [N]; tf_bounds (lo, hi) [s], default TF_BOUNDS. The paper leaves F
    free, which makes minimum time degenerate (t_f -> 0 with unbounded force), hence a_max.

    The guess drives a Dubins path, or with v_min < 0 a Reeds-Shepp path too (its cusps at
    rest, backwards at most -v_min), which fixes how often the heading winds: the goal
    heading is unwrapped after the path's net turn and theta is bounded THETA_MARGIN beyond
    start and goal. The fastest guess is tried first; if IPOPT fails (a map bound may cut
    that path), the fastest of each other winding and first direction of travel is tried,
    up to MAX_TRIES solves. `paths` passes those paths when the caller has them already:
    guess_paths(start, goal, radius, v_min < 0) with radius = L / tan(delta_max), start and
    goal the rear axle's poses (steered).
    Never raises for an infeasible problem: `success` is False and the arrays hold IPOPT's
    last iterate. The cached solver makes this function not thread-safe."""
    t0 = perf_counter()
    start = np.asarray(start, dtype=float)
    goal = np.asarray(goal, dtype=float)
    tf_lo, tf_hi = TF_BOUNDS if tf_bounds is None else tf_bounds
    rate_limited = max_steer_rate is not None
    prob = _problem(N, shooting, method, bounds is not None, goal_speed is not None,
                    rate_limited)
    kept = (_problem(N, shooting, method, bounds is not None, goal_speed is not None,
                     rate_limited, len(corridor.offsets))
            if corridor is not None and rate_limited else None)
    # Positions relative to the start node keep the numbers small wherever the map lies.
    origin = start[:2]
    x0 = np.array([0.0, 0.0, start[2], start[3]])
    limits = ([max_steer_rate, max_lateral_acceleration,
               1.0 if steer_speed is None else steer_speed, Lr] if rate_limited else [])
    box = (np.array([-np.inf, np.inf, -np.inf, np.inf]) if bounds is None
           else np.asarray(bounds, dtype=float) - np.repeat(origin, 2))
    v_goal = [] if goal_speed is None else [goal_speed]
    radius = L / np.tan(delta_max)
    goal_local = np.array([*(goal[:2] - origin), goal[2]])
    # The guesses drive the point that turns on circles of `radius`: the rigid car's rear axle.
    lever = Lr if rate_limited else 0.0
    rear = shifted(x0[:3], -lever)
    if paths is None:
        paths = guess_paths(rear, shifted(goal_local, -lever), radius, v_min < 0)
    # Fastest guess first; forwards only, that is the shortest Dubins path first.
    # The inputs, a Python loop per interval, are built only for the guesses tried.
    # Steered, the guess keeps to the speed at which its tightest turn meets the lateral limit.
    v_guess = min(v_max, math.sqrt(max_lateral_acceleration * radius)) if rate_limited else v_max
    guesses = sorted((_profile(segs, radius, x0, a_max, v_guess, goal_speed, -v_min)
                      for segs in paths), key=lambda guess: guess.tf)
    tried, solves = set(), 0
    for guess in guesses:
        way = guess.runs[0][0]
        theta_g = unwrap(goal[2], start[2] + guess.turn)
        winding = round((theta_g - goal[2]) / (2 * pi))
        # One try per heading winding and first direction of travel.
        key = (winding, way)
        if key in tried:
            continue
        tried.add(key)
        u_g = _guess_inputs(N, guess.runs, guess.plans, a_max)
        tf_g = min(max(guess.tf, tf_lo), tf_hi)
        lo = np.array([box[0], box[2], min(start[2], theta_g) - THETA_MARGIN, v_min])
        hi = np.array([box[1], box[3], max(start[2], theta_g) + THETA_MARGIN, v_max])
        x_start, z_g = x0, None
        poses = None
        if rate_limited:
            x_start = np.r_[x0, steer0]
            lo, hi = np.r_[lo, -delta_max], np.r_[hi, delta_max]
            if shooting == "multiple":
                # The states start on a guess the car can drive (_crawl_guess): the path at
                # its turns' steers, the wheel turned standing.
                tf_g, z_g = _crawl_guess(N, rear, x0[3], steer0,
                                         [(sign, way * q) for way, run in guess.runs
                                          for sign, q in run], radius, delta_max,
                                         max_steer_rate, a_max, v_max, -v_min,
                                         max_lateral_acceleration, goal_speed)
                tf_g = min(max(tf_g, tf_lo), tf_hi)
                u_g = np.clip(np.diff(z_g[3:], axis=1)
                              / (np.c_[[a_max, max_steer_rate]] * tf_g / N), -1.0, 1.0)[::-1]
                z_g[:3] = shifted(z_g[:3].T, lever).T
                z_g, poses = z_g[:, 1:], z_g[:3, 1:].T
            else:
                u_g[0] = _steer_ramps(u_g[0], steer0, delta_max, max_steer_rate, tf_g / N)
        p = np.r_[x_start, goal_local[:2], theta_g, L, m, delta_max, a_max, limits, v_goal]
        solved = _solve(prob, p, lo, hi, (tf_lo, tf_hi), tf_g, u_g, steer_speed is not None,
                        z_g=z_g)
        solves += 1
        if (kept is not None and corridor is not None and solved.success
                and _touches(corridor, solved, origin)):
            # The OCP ignores obstacles: solved again, each disc kept within a free ball that
            # holds its guess's disc.
            if poses is None:
                poses = shifted(_guess_poses(N, rear, radius, guess.runs, guess.plans, a_max),
                                lever)
            centres, room = _rooms(corridor, _disc_centres(corridor, poses) + origin)
            centres -= origin
            p = np.r_[p[:len(p) - len(v_goal)], corridor.offsets, centres.ravel(), v_goal]
            solved = _solve(kept, p, lo, hi, (tf_lo, tf_hi), tf_g, u_g,
                            steer_speed is not None, room.ravel(), z_g)
            solves += 1
        if solved.success or solves >= MAX_TRIES:
            break
    solved.states[:, :2] += origin
    return Connection(success=solved.success, status=solved.status, tf=solved.tf,
                      t=np.linspace(0, solved.tf, N + 1), states=solved.states,
                      inputs=solved.inputs, solve_s=perf_counter() - t0,
                      shooting=shooting, steer_rates=solved.steer_rates)


def _disc_centres(corridor: Corridor, poses) -> np.ndarray:
    """(n, J, 2) [m] the centres of the corridor's discs of the car at poses (n, 3+) [X, Y,
    psi]."""
    poses = np.asarray(poses, float)
    return poses[:, None, :2] + np.asarray(corridor.offsets)[None, :, None] \
        * np.stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])], axis=-1)[:, None, :]


def _rooms(corridor: Corridor, centres) -> tuple[np.ndarray, np.ndarray]:
    """(centres (..., 2) [m], rooms (...) [m]) of the balls the corridor keeps the discs at
    `centres` (..., 2) [m] within: each the widest of the balls free of obstacles (its room
    the clearance of its centre less the disc radius, at least MIN_ROOM) that still hold its
    disc's centre, centred at the disc or up to ROOM_SHIFTS away from it in ROOM_DIRECTIONS
    directions: a disc beside a wall may then move away from it as far as the space allows,
    where a ball about the disc itself would hold it as near the wall as it is."""
    centres = np.asarray(centres, float)
    angles = np.arange(ROOM_DIRECTIONS) * 2 * pi / ROOM_DIRECTIONS
    shifts = np.r_[0.0, np.outer(ROOM_SHIFTS, np.ones(ROOM_DIRECTIONS)).ravel()]
    ways = np.r_[[[0.0, 0.0]], np.tile(np.column_stack([np.cos(angles), np.sin(angles)]),
                                       (len(ROOM_SHIFTS), 1))]
    moved = centres[..., None, :] + shifts[:, None] * ways        # (..., K, 2)
    room = corridor.clearance(moved) - corridor.radius
    room[..., 0] = np.maximum(room[..., 0], MIN_ROOM)
    room = np.where(room >= shifts, room, -np.inf)                  # the disc stays inside
    best = np.argmax(room, axis=-1)
    pick = np.take_along_axis(moved, best[..., None, None], axis=-2)[..., 0, :]
    return pick, np.take_along_axis(room, best[..., None], axis=-1)[..., 0]


def _touches(corridor: Corridor, solved: _Solution, origin) -> bool:
    """Whether a disc of the car touches an obstacle at a node 1..N of the (steered) solution,
    positions relative to `origin` [m]."""
    centres = _disc_centres(corridor, solved.states[1:])
    return bool((corridor.clearance(centres + origin) <= corridor.radius).any())


def resimulate(conn: Connection, *, L, m, Lr=0.0, refine=10) -> np.ndarray:
    """States (N*refine+1, 4) re-integrated with the zoo's rk4 driver on a `refine`-times
    finer step under the connection's piecewise-constant inputs (steer rates, the steer a
    state, on the rigid car with Lr [m], if it has them): checks the discretisation."""
    rk4, p = zoo_method("rk4"), {"L": float(L), "m": float(m), "Lr": float(Lr)}
    h = conn.tf / len(conn.inputs) / refine
    rhs, x, inputs = kinematic_bicycle, jnp.asarray(conn.states[0]), conn.inputs
    if conn.steer_rates is not None:
        rhs, x = steered(rigid_bicycle), jnp.asarray(np.r_[conn.states[0], conn.inputs[0, 0]])
        inputs = np.column_stack([conn.steer_rates, conn.inputs[:, 1]])
    rows = [conn.states[:1]]
    for u in inputs:
        traj = integrate(rk4, rhs, x, jnp.asarray(u), p, h, refine)
        rows.append(np.asarray(traj.x[1:, :4]))
        x = traj.x[-1]
    return np.concatenate(rows)


def _crawl_guess(N, start, v0, steer0, segs, radius, delta_max, rate_max, a_max, v_fwd, v_back,
                 a_lat, v_goal, dt=CRAWL_DT) -> tuple[float, np.ndarray]:
    """(t_f [s], states (5, N+1) [X, Y, theta, v, delta] at N+1 equal times) of a guess the
    rate-limited car can drive: the path `segs` (turn sign, signed length [m]) of turning
    radius `radius` [m] from pose `start` [X, Y, theta], each segment at its steer (sign *
    delta_max [rad]), the wheel turned at rate_max [rad/s] standing where the path's steer
    or its direction changes (the car brakes to rest there at a_max [m/s^2]), at most
    v_fwd (v_back backwards) [m/s] and sqrt(a_lat radius) on turns. From speed v0 [m/s] and
    steer steer0 [rad] it brakes along the path until its steer is the first segment's. A
    path that ends turning ends at rest, the wheel then turned straight standing (the body
    on the path's end heading); one that ends straight ends at v_goal [m/s] if given. Only
    where it sets off moving at another steer does its state leave the kinematic bicycle's
    motion (a guess at the path's poses with the steer ramped as fast as it may lags the
    path's turns and ends metres off the goal)."""
    segs = [(sign, q) for sign, q in segs if q != 0] or [(0, 0.0)]
    ends = np.cumsum([abs(q) for _, q in segs]).tolist()   # floats: the loop is scalar Python
    steer_of = [sign * delta_max for sign, _ in segs]
    way_of = [1 if q >= 0 else -1 for _, q in segs]
    cap = [min(v_fwd if way > 0 else v_back, math.sqrt(a_lat * radius) if sign else np.inf)
           for (sign, _), way in zip(segs, way_of)]
    last = len(segs) - 1
    stops = [steer_of[i + 1] != steer_of[i] or way_of[i + 1] != way_of[i]
             for i in range(last)] + [steer_of[last] != 0 or v_goal is not None]
    end_speed = [0.0] * last + [0.0 if steer_of[last] != 0 or v_goal is None else abs(v_goal)]
    s, u, delta, i = 0.0, max(v0 * way_of[0], 0.0), float(steer0), 0
    rows, step = [(0.0, s, u * way_of[0], delta)], rate_max * dt
    while len(rows) < CRAWL_MAX_STEPS:
        arrived = i == last and s >= ends[last]
        target = 0.0 if arrived else steer_of[i]
        delta += min(max(target - delta, -step), step)
        if arrived:
            if delta == 0.0 or u > 0.0:
                rows.append((rows[-1][0] + dt, s, u * way_of[i], delta))
                break
        elif abs(delta - steer_of[i]) > 1e-12:
            u = max(u - a_max * dt, 0.0)    # braking until the wheel is turned
        else:
            room = max(ends[i] - s, 0.0)
            limit = math.sqrt(end_speed[i] ** 2 + 2 * a_max * room) if stops[i] else cap[i]
            u = min(u + a_max * dt, cap[i], limit)
        if not arrived:
            s += u * dt
            if s >= ends[i] - CRAWL_SNAP_M:
                if stops[i] and u <= end_speed[i] + math.sqrt(2 * a_max * CRAWL_SNAP_M) \
                        + a_max * dt:
                    s, u = ends[i], end_speed[i]
                if s >= ends[i] and i < last:
                    i += 1
        rows.append((rows[-1][0] + dt, s, u * way_of[i], delta))
    table = np.array(rows)
    poses = path_poses(start, segs, radius, CRAWL_SPACING_M)
    along = np.r_[0.0, np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))]
    along *= ends[-1] / along[-1] if along[-1] > 0 else 1.0
    times = np.linspace(0.0, table[-1, 0], N + 1)
    at = np.interp(times, table[:, 0], table[:, 1])
    return float(table[-1, 0]), np.vstack([
        np.interp(at, along, poses[:, 0]), np.interp(at, along, poses[:, 1]),
        np.interp(at, along, poses[:, 2]), np.interp(times, table[:, 0], table[:, 2]),
        np.interp(times, table[:, 0], table[:, 3])])
