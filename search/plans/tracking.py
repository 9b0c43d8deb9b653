"""The closed-loop tracking replay (plan.json's `tracking`): a Stanley path-tracking
controller drives a richer car than the planner's (dynamics/blended.py: Fiala tyres with their
friction limit, the steering-rate limit, the speed a state) along the planned path, integrated
with the zoo's rk4 in one compiled scan; how far the car's centre of gravity strays from the
path, and whether its footprint collides along the way."""
from __future__ import annotations

import math
from functools import cache

import numpy as np

from stepzoo import dynamics
from stepzoo.dynamics.blended import blend_weight, blended_single_track, kinematic_lateral
from stepzoo.dynamics.kinematic import shifted
from stepzoo.search.planner.connection_ocp import A_MAX
from stepzoo.search.plans.path_metrics import STILL_M, steps
from stepzoo.dynamics.vehicles import G, axle_loads, default_vehicle, st_params, tyre_params

CONTROLLER = "stanley"
MODEL = "single_track_fiala"
METRICS = ("max_deviation_m", "final_deviation_m", "final_heading_deviation_rad", "collides",
           "clearance_min_m")
KEYS = ("controller", "model") + METRICS

METHOD = "rk4"
H_S = 0.01            # [s] integration step and control period (zero-order hold)
# Stanley (Thrun et al., 'Stanley: the robot that won the DARPA Grand Challenge', J. Field
# Robotics 23, 2006, eq. 2; Hoffmann et al., ACC 2007): steer = heading error + atan(k e /
# (k_soft + v)); on the kinematic car the front axle's cross-track error then decays at rate k.
GAIN_K = 2.0          # [1/s] cross-track gain k
K_SOFT = 1.0          # [m/s] softening: the cross-track term stays bounded as the car stops
# Backwards, rear-wheel feedback (Samson, IEEE TAC 40, 1995; Paden et al., 'A survey of motion
# planning and control techniques for self-driving urban vehicles', IEEE T-IV 1, 2016,
# sec. V-B2): the rear axle, which the steer does not move sideways, turns at its path's
# curvature (fed forward) less e / l^2 + 2 sin(theta) / l, e its offset to the left of the
# path and theta its travel direction's error; the kinematic car's rear axle turns at
# -tan(delta) / L per metre backwards, so along the path e'' + 2 e' / l + e / l^2 = 0
# (critically damped), and on a curve it keeps to the path. Pure pursuit, its predecessor
# here, cut curves short of a cusp by up to 0.4 m (no curvature fed forward, its lookahead
# past the end of a piece a few tenths of a metre long).
BACK_L_M = 1.0        # [m] the length l: an error settles within a few metres (reversing
                      # pieces between cusps are often shorter than a wheelbase)
STEER_SHARE = 0.5     # the share of the steer rate the path may ask for per metre at speed
A_CAP = 2.0           # [m/s^2] braking towards a speed the steer rate or the grip caps
GRIP_SHARE = 0.6      # the share of the tyres' friction mu g the path's turns may ask for
                      # (the planner's lateral limit may ask more: 0.8 of 11.5 m/s^2)
V_CAP_MIN = 0.2       # [m/s] the least speed that cap sets
STEER_LAG_RAD = 0.2   # [rad] steer lagging its command by this much halts the car ...
SLOWEST = 0.1         # ... down to this fraction of the planned speed
START_LAG_RAD = 0.05  # [rad] standing, the car moves off once its steer is this near its command
HALT_S = 0.1          # [s] a plan standing still this long mid-way stops the car there too
STEER_SERVO_S = 0.05  # [s] time constant of the steering servo (the plant limits its rate)
SPEED_GAIN = 5.0      # [1/s] speed loop
A_TRACK = 2 * A_MAX   # [m/s^2] the tracker's largest braking and acceleration: above the
                      # connection's, so that it can follow the plan's speed
A_BRAKE = 1.0         # [m/s^2] the braking it plans to stop at a cusp or the path's end
STOPPED_MPS = 0.05    # [m/s] below this the speed loop alone stops the car
END_TOL_M = 0.02      # [m] a piece is done when its end is this close along the path
V_BLEND = (1.0, 2.0)  # [m/s] the plant blends from kinematic to dynamic between these speeds
SPACING_M = 0.05      # [m] between the reference's points along the path
SMOOTH_M = 1.0        # [m] the path's heading is averaged over this length
FF_SMOOTH_M = 0.25   # [m] and its curvature, which sets the steer fed forward, over this
WINDOW = 16           # path segments searched ahead of the last nearest one per step
CHECK_SPACING_M = 0.05  # [m] at most between the tracked poses checked for collision
# The closed loop is compiled for at least this many control periods and reference rows:
# plans of the built-in scenarios' sizes then share one program, whose compiling costs far
# more than running the extra periods (cut off: the time allowed stays the plan's own).
LEAST_STEPS, LEAST_ROWS = 16384, 4096


def plant_params(vehicle: dict) -> dict:
    """The tracked car's parameters: the set's m, Iz, Lf, Lr, Caf, Car and max_steer_rate
    [rad/s] (as plan.json's `vehicle` records them), its Fiala friction coefficient and
    CommonRoad steer angle and acceleration limits (the default set's where a set publishes
    none)."""
    name = vehicle.get("name")
    p = {k: float(vehicle[k]) for k in ("m", "Iz", "Lf", "Lr", "Caf", "Car")}
    tables = dynamics.vehicle(name) if name in dynamics.vehicle_names() else {}
    limits = st_params(name if "st" in tables else default_vehicle())
    mu = tyre_params(name if "fiala" in tables else default_vehicle(), "fiala")["mu"]
    Fzf, Fzr = axle_loads(p)
    keep = ("delta_min", "delta_max", "v_min", "v_max", "v_switch", "a_max")
    rate = float(vehicle["max_steer_rate"])
    return {**p, **{k: limits[k] for k in keep}, "ddelta_min": -rate, "ddelta_max": rate,
            "mu": float(mu), "Fzf": Fzf, "Fzr": Fzr,
            "v_blend_low": V_BLEND[0], "v_blend_high": V_BLEND[1]}


def pieces(rows, halts=()) -> list[tuple[int, int, int]]:
    """(first row, last row, direction +1 | -1) of each stretch of path rows (K, 4) [t, X,
    Y, psi] driven one way (forwards: along psi), cut also at the rows `halts` (where the plan
    stands still: see `halted`); rows that do not move are dropped first."""
    way = np.where(steps(rows)[1] >= 0, 1, -1)
    cuts = np.flatnonzero(way[1:] != way[:-1]) + 1
    inside = [h for h in halts if 0 < h < len(way)]
    bounds = np.unique(np.r_[0, cuts, np.array(inside, int), len(way)])
    return [(int(a), int(b), int(way[a])) for a, b in zip(bounds[:-1], bounds[1:])]


def halted(rows, keep) -> np.ndarray:
    """Indices among the rows `keep` (K,) bool of path rows (K, 4) [t, X, Y, psi] (the first
    and each one a move reaches: `reference`'s) after which the plan stands still for HALT_S
    or longer before it moves on: there it turns the wheel standing (the connection, from
    lock to lock), and the car stops there too, as at a cusp, rather than crawl on through a
    turn its wheel has not reached."""
    still = ~keep[1:]
    stood = np.r_[0.0, np.cumsum(np.where(still, np.diff(rows[:, 0]), 0.0))]
    kept = np.flatnonzero(keep)
    # Between kept rows i and j, steps i .. j-2 stand still and step j-1 moves.
    after = stood[kept[1:] - 1] - stood[kept[:-1]]
    return np.flatnonzero(after >= HALT_S)


def reference(rows, p: dict, kinematic=None) -> dict:
    """The path as the controller reads it, piece after piece (cut at the cusps and where the
    plan stands still, `halted`; a cut's row is in both):
    the centre of gravity's path P (n, 2), the controlled axle's path C (n, 2) (front axle
    forwards, rear axle backwards), the travel direction's heading along C `course` (n,),
    the body heading `psi_body` (n,), the steer that holds the path's curvature `steer_ff`
    (n,), the plan's speed `speed` (n,) [m/s], the distance left to the piece's end `left`
    (n,) [m]; per piece `first`, `last` row and `way` (+1 | -1).

    The body heading is the plan's psi (the dynamic bicycle's and the rigid car's rows: the
    centre of gravity and the body); where it drove the paper's kinematic bicycle
    (`kinematic`, a bool per row; default: nowhere), whose (X, Y) moves along psi, it is the
    path's heading less the rolling car's slip angle at the centre of gravity, asin(Lr
    kappa), averaged over SMOOTH_M. It sets the axles of a car whose centre of gravity is on
    the path. The steer fed forward is that of the rear axle's path (Lr behind the centre of
    gravity along the body), which turns at tan(delta) / L."""
    rows = np.asarray(rows, float)
    # Standing still, rows rounded to 1e-6 m (plan.json's) step about at random: read as
    # moves, such steps would cut the path into pieces of alternating direction.
    keep = np.r_[True, np.hypot(*np.diff(rows[:, 1:3], axis=0).T) > STILL_M]
    kinematic = (np.zeros(len(rows), bool) if kinematic is None
                 else np.asarray(kinematic, bool))[keep]
    halts = halted(rows, keep)
    rows = rows[keep]
    L, Lr, Lf = p["Lf"] + p["Lr"], p["Lr"], p["Lf"]
    # The kinematic car's slip angle at full lock bounds the one the path asks for.
    sin_beta_max = math.sin(math.atan(Lr * math.tan(p["delta_max"]) / L))
    out: dict[str, list] = {k: [] for k in ("P", "C", "course", "psi_body", "steer_ff", "kappa",
                                            "speed", "accel", "left")}
    first, last, ways = [], [], []
    for a, b, way in pieces(rows, halts):
        # Resampled evenly along the path: rows closer than their rounding would make the
        # differences below noise.
        d = np.hypot(*np.diff(rows[a:b + 1, 1:3], axis=0).T)
        along = np.r_[0.0, np.cumsum(d)]
        s = np.linspace(0.0, along[-1], max(2, math.ceil(along[-1] / SPACING_M) + 1))
        seg = np.column_stack([np.interp(s, along, rows[a:b + 1, k]) for k in range(3)])
        t, xy = seg[:, 0], seg[:, 1:3]
        d = np.diff(s)
        travel = np.unwrap(np.arctan2(*_slope(xy, s).T[::-1]))
        # Averaged over FF_SMOOTH_M: a second difference of rows SPACING_M apart turns their
        # rounding (1e-6 m) into curvature noise of 1e-3 1/m, a steer fed forward that jitters.
        kappa = _smooth(way * _slope(travel, s) if len(s) > 2 else np.zeros(len(s)),
                        FF_SMOOTH_M)
        beta = np.arcsin(np.clip(Lr * kappa, -sin_beta_max, sin_beta_max))
        rolling = np.interp(s, along, kinematic[a:b + 1].astype(float)) > 0.5
        facing = travel + (np.pi if way < 0 else 0.0)
        planned = np.interp(s, along, np.unwrap(rows[a:b + 1, 3]))
        planned += 2 * np.pi * np.round((facing[0] - planned[0]) / (2 * np.pi))
        # Forwards averaged over SMOOTH_M: a kink where the plan hands a slipping car's
        # heading to the kinematic bicycle becomes a turn a car can drive. Backwards the
        # rear-wheel feedback reads the rear axle's path segment by segment, which must be the
        # path the car drove: the plan's body heading as it is (averaged, it moved that path
        # by tenths of a radian on a piece shorter than SMOOTH_M), the kinematic bicycle's
        # averaged along its trend.
        body = np.where(rolling, facing - beta, planned)
        psi_body = (_smooth(body) if way > 0
                    else np.where(rolling, _smooth(body, trend=True), body))
        # The steer fed forward: on the paper's kinematic bicycle, the steer of its path's
        # turn; elsewhere the rear axle's (Lr behind the centre of gravity, along the body),
        # which turns at tan(delta) / L whatever the steer does, where the centre of gravity's
        # path curves beyond that while the steer turns (its slip changes with it).
        rear = shifted(np.column_stack([xy, body]), -Lr)[:, :2]
        pace = np.gradient(rear, s, axis=0) if len(s) > 2 else np.ones((len(s), 2))
        turning = (np.gradient(np.unwrap(np.arctan2(pace[:, 1], pace[:, 0])), s)
                   / np.maximum(np.hypot(pace[:, 0], pace[:, 1]), 1e-9))
        steer_ff = np.where(rolling, np.arctan(L * np.tan(beta) / Lr),
                            np.arctan(L * _smooth(way * turning, FF_SMOOTH_M)))
        offset = Lf if way > 0 else -Lr
        axle = xy + offset * np.column_stack([np.cos(psi_body), np.sin(psi_body)])
        course = _smooth(np.unwrap(np.arctan2(*np.gradient(axle, s, axis=0).T[::-1])))
        dt = np.diff(t)
        v = np.where(dt > 0, d / np.where(dt > 0, dt, 1.0), 0.0)
        speed = steering_speed(np.r_[v, v[-1:]], s, _smooth(steer_ff), p["ddelta_max"],
                               _smooth(kappa), GRIP_SHARE * p["mu"] * G)
        first.append(sum(len(c) for c in out["P"]))
        last.append(first[-1] + len(seg) - 1)
        ways.append(way)
        for k, val in (("P", xy), ("C", axle), ("course", course), ("psi_body", psi_body),
                       ("steer_ff", steer_ff), ("kappa", _smooth(kappa)),
                       ("speed", speed), ("accel", speed * np.gradient(speed, s)),
                       ("left", s[-1] - s)):
            out[k].append(val)
    ref = {k: np.concatenate(v) for k, v in out.items()}
    return dict(ref, first=np.array(first), last=np.array(last), way=np.array(ways))


def steering_speed(speed, s, steer, rate: float, kappa=None, lateral: float = math.inf):
    """(n,) [m/s] the plan's `speed` (n,) at the points `s` (n,) [m] along a piece, capped
    where the steer the path asks for, `steer` (n,) [rad], changes faster per metre than
    STEER_SHARE of the car's steer `rate` [rad/s] follows at that speed, and braking towards
    each such cap at A_CAP (a backward pass), at least V_CAP_MIN: the car slows to turn the
    wheel where the path turns it within a short distance, rather than running wide. With
    the path's curvature `kappa` (n,) [1/m], also capped where v^2 |kappa| would exceed
    `lateral` [m/s^2]: near full lock the tyres cannot carry a turn near their friction
    limit, and the car slows for it as a driver does. (A plan that crawls there is not
    followed exactly in time: the tracker slows where it must.)"""
    per_m = np.abs(np.gradient(steer, s)) if len(s) > 2 else np.zeros(len(s))
    cap = STEER_SHARE * rate / np.maximum(per_m, 1e-9)
    if kappa is not None:
        cap = np.minimum(cap, np.sqrt(lateral / np.maximum(np.abs(kappa), 1e-9)))
    cap = np.maximum(cap, V_CAP_MIN)
    ds = np.diff(s)
    for i in range(len(s) - 2, -1, -1):
        cap[i] = min(cap[i], math.sqrt(cap[i + 1] ** 2 + 2 * A_CAP * ds[i]))
    return np.minimum(speed, cap)


def _slope(a, s) -> np.ndarray:
    """d a / d s of samples `a` (n, ...) at the points `s` (n,) [m], to second order at the
    ends too: first order there, a piece's first point read half a curve's turn."""
    return np.gradient(a, s, axis=0, edge_order=2 if len(s) > 2 else 1)


def _smooth(a, length=SMOOTH_M, trend=False):
    """Moving average of samples SPACING_M apart over `length` [m], the ends held, or with
    `trend` extended along the line that fits the samples within `length` of each (a heading
    along a curve: held, its last half length bent straight)."""
    half = int(length / SPACING_M / 2)
    if len(a) < 3 or half < 1:
        return a
    if trend:
        near, k = min(len(a), 2 * half + 1), np.arange(1, half + 1)
        head, tail = (np.polyfit(np.arange(near), end, 1) for end in (a[:near], a[::-1][:near]))
        padded = np.r_[np.polyval(head, -k[::-1]), a, np.polyval(tail, -k)]
    else:
        padded = np.r_[np.repeat(a[0], half), a, np.repeat(a[-1], half)]
    return np.convolve(padded, np.full(2 * half + 1, 1 / (2 * half + 1)), mode="valid")


def _bucket(n: int, least: int) -> int:
    """n rounded up to a power of two (at least `least`): plans of similar size share one
    compilation."""
    return max(least, 1 << max(0, math.ceil(math.log2(max(n, 1)))))


def kinematic_rows(rows, segs: list[dict]) -> np.ndarray:
    """(K,) bool: which path rows (K, 4) [t, ...] the plan drove on the kinematic bicycle,
    by the time spans of its controls (search/plans/replay.py's `controls`)."""
    t = np.asarray(rows, float)[:, 0]
    out = np.zeros(len(t), bool)
    for seg in segs:
        span = seg["duration"] if seg["model"] == "dynamic5" else seg["dt"] * seg["steps"]
        inside = (t >= seg["t0"] - 1e-9) & (t <= seg["t0"] + span + 1e-9)
        out[inside] = seg["model"] == "kinematic"
    return out


def track(rows, start, vehicle: dict, kinematic=None) -> dict:
    """Drive the car of `vehicle` along path rows (K, 4) [t s, X m, Y m, psi rad] from the
    pose `start` [X, Y, psi] with Stanley's controller: {"poses": (N, 3) [X, Y, psi] every
    H_S until the car stopped at the path's end (or the time allowed ran out),
    "deviation": (N,) [m] the centre of gravity's distance to the path, "done": whether it
    reached the end, "end": its last pose}; `kinematic`: the rows the plan drove on the
    kinematic bicycle (`reference`). Float64 whatever the caller's precision."""
    import jax
    p = plant_params(vehicle)
    ref = reference(rows, p, kinematic)
    n_rows, n_pieces = len(ref["P"]), len(ref["first"])
    size, n_p = _bucket(n_rows + WINDOW + 1, LEAST_ROWS), _bucket(n_pieces, 4)
    pad = lambda a: np.concatenate([a, np.repeat(a[-1:], size - len(a), axis=0)])
    arrays = {k: pad(v) for k, v in ref.items() if k not in ("first", "last", "way")}
    for k in ("first", "last", "way"):
        arrays[k] = np.r_[ref[k], np.repeat(ref[k][-1:], n_p - n_pieces)]
    # Time allowed: the plan's (or the reference's, slower), plus a stop and a start at A_TRACK
    # per piece, plus slack.
    v_max = float(ref["speed"].max())
    driven = float(np.sum(SPACING_M / np.maximum(ref["speed"], V_CAP_MIN)))  # at its speeds
    allowed = max(float(rows[-1, 0] - rows[0, 0]), driven) + n_pieces * (
        2 * v_max / A_BRAKE + 2.0) + 5.0
    n_steps = _bucket(math.ceil(allowed / H_S), 1024)   # the control periods allowed
    # At the start pose at the plan's first speed, the wheel turned (before moving off, as
    # the planner's driver turns it) to the controller's first command for a car on its path,
    # the lateral motion the rolling car's at that steer.
    start = np.asarray(start, float)[:3]
    way, v0 = ref["way"][0], ref["way"][0] * ref["speed"][0]
    delta0 = float(np.clip(
        np.remainder(ref["course"][0] - start[2] + np.pi, 2 * np.pi) - np.pi if way > 0
        else ref["steer_ff"][0], p["delta_min"], p["delta_max"]))
    x0 = np.r_[start, v0, *kinematic_lateral(v0, delta0, p), delta0]
    with jax.enable_x64(True):
        out = _scan(max(n_steps, LEAST_STEPS))(x0, arrays, n_pieces, p)
        poses, dev, done = (np.asarray(a)[:n_steps] for a in out[:3])
    poses = poses[:, :3]
    # Up to the step it finished (and one more: the stopped pose).
    n = int(np.argmax(done)) + 1 if done.any() else len(done)
    return {"poses": poses[:n], "deviation": dev[:n], "done": bool(done.any()),
            "end": poses[n - 1]}


@cache
def _scan(n_steps: int):
    """The compiled closed loop of n_steps control periods (one per plan size bucket)."""
    import jax
    import jax.numpy as jnp
    from jax import lax

    from stepzoo.integrators import integrate

    def wrap(a):
        return jnp.remainder(a + jnp.pi, 2 * jnp.pi) - jnp.pi

    def nearest(points, i, lo, hi, q, reach=WINDOW):
        """Nearest point to q on the segments i..i+reach-1 (reach <= WINDOW) of `points`
        within rows lo..hi: (segment, fraction along it, distance, signed offset to its
        left)."""
        j = jnp.clip(i + jnp.arange(WINDOW), lo, jnp.maximum(hi - 1, lo))
        a, b = points[j], points[j + 1]
        ab = b - a
        frac = jnp.clip(jnp.sum((q - a) * ab, axis=1) / jnp.maximum(jnp.sum(ab * ab, 1), 1e-18),
                        0.0, 1.0)
        gap = q - (a + frac[:, None] * ab)
        dist = jnp.where(jnp.arange(WINDOW) < reach, jnp.hypot(gap[:, 0], gap[:, 1]), jnp.inf)
        k = jnp.argmin(dist)
        side = (ab[k, 0] * gap[k, 1] - ab[k, 1] * gap[k, 0]) / jnp.maximum(
            jnp.hypot(ab[k, 0], ab[k, 1]), 1e-18)
        return j[k], frac[k], dist[k], side

    def run(x0, ref, n_pieces, p):
        at = lambda name, j, f: ref[name][j] + f * (ref[name][j + 1] - ref[name][j])

        L = p["Lf"] + p["Lr"]

        def front_slip(v, kappa):
            """[rad] the front tyre's slip angle (Fiala, inverted in closed form: |F| =
            grip (1 - (1 - y)^3), y = Ca |tan alpha| / (3 grip)) that carries its share of
            the steady turn m v^2 kappa, as far as the car's speed blends in its tyres:
            the steer the car needs beyond the front axle's course."""
            grip = p["mu"] * p["Fzf"]
            share = jnp.minimum(p["m"] * p["Lr"] / L * v * v * jnp.abs(kappa) / grip, 0.999)
            y = 1 - jnp.cbrt(1 - share)
            return blend_weight(v, p) * jnp.sign(kappa) * jnp.arctan(3 * grip * y / p["Caf"])

        def control(x, i, k):
            way = ref["way"][k]
            lo, hi = ref["first"][k], ref["last"][k]
            psi, v = x[2], x[3]
            heading = jnp.stack([jnp.cos(psi), jnp.sin(psi)])
            axle = x[:2] + jnp.where(way > 0, p["Lf"], -p["Lr"]) * heading
            # No farther along than twice the step's travel: a car far off the path (one
            # it cannot drive) is not drawn along it by a nearest point racing ahead.
            reach = 2 + jnp.ceil(2 * jnp.abs(v) * H_S / SPACING_M).astype(int)
            j, f, _, side = nearest(ref["C"], i, lo, hi, axle, reach)
            # The offset to the left of the body's forward direction along the path.
            e = side * way
            soft = K_SOFT + jnp.abs(v)
            # Heading term: where the car rolls (below the plant's blend), the steer that holds
            # the path's curvature fed forward plus the body's heading error; above it, the
            # controlled axle's course. The course is averaged over SMOOTH_M: where a crawling
            # plan ramps its steer within a few tens of centimetres, the average spreads the
            # ramp over a metre, and a car steered by it turned its wheel late, then
            # over-steered to catch up.
            rolls = 1 - blend_weight(v, p)
            aim = (rolls * (at("steer_ff", j, f) + wrap(at("psi_body", j, f) - psi))
                   + (1 - rolls) * wrap(at("course", j, f) - psi))
            forward = (aim - jnp.arctan(GAIN_K * e / soft)
                       + front_slip(v, at("kappa", j, f)))
            # Backwards: the rear axle's path curvature fed forward, plus its offset and the
            # error of its travel direction along the path (the segment it is nearest).
            seg = ref["C"][j + 1] - ref["C"][j]
            theta = wrap(psi + jnp.pi - jnp.arctan2(seg[1], seg[0]))
            backward = jnp.arctan(jnp.tan(at("steer_ff", j, f))
                                  + L * (side / BACK_L_M ** 2 + 2 * jnp.sin(theta) / BACK_L_M))
            steer = jnp.clip(jnp.where(way > 0, forward, backward), p["delta_min"],
                             p["delta_max"])
            # The plan's speed, or less where braking at A_BRAKE must start to stop at the
            # piece's end; the plan's acceleration, or that braking, fed forward so that the
            # speed loop does not lag it.
            left = at("left", j, f)
            brake = jnp.sqrt(2 * A_BRAKE * left)
            braking = brake < at("speed", j, f)
            target = jnp.where(braking, brake, at("speed", j, f))
            end = (left < END_TOL_M) | ((j >= hi - 1) & (f >= 1.0))
            ahead = jnp.where(braking, -A_BRAKE, at("accel", j, f)) * way
            return steer, target * way, ahead, j, end

        def body(carry, _):
            x, i, k, done = carry
            steer, target, ahead, j, end = control(x, i, k)
            # Slower while the steer lags its command (its rate is limited): the path, not
            # the plan's timing, is what the car must keep to.
            lag = jnp.clip(1 - jnp.abs(steer - x[6]) / STEER_LAG_RAD, SLOWEST, 1.0)
            # Standing (at a cusp, or where the plan stood), it turns the wheel before it
            # moves off, as a driver does where the plan's steer jumps.
            lag = jnp.where((jnp.abs(x[3]) < STOPPED_MPS)
                            & (jnp.abs(steer - x[6]) > START_LAG_RAD), 0.0, lag)
            target, ahead = target * lag, jnp.where(lag < 1, 0.0, ahead)
            last = k >= n_pieces - 1
            finished = done | (end & last)
            # At the end, on braking at A_BRAKE until nearly stopped, then held.
            stopping = -A_BRAKE * jnp.sign(x[3]) * (jnp.abs(x[3]) > STOPPED_MPS)
            target, ahead = (jnp.where(finished, 0.0, target),
                             jnp.where(finished, stopping, ahead))
            accel = jnp.clip(SPEED_GAIN * (target - x[3]) + ahead, -A_TRACK, A_TRACK)
            u = jnp.stack([(steer - x[6]) / STEER_SERVO_S, accel])
            x = integrate(METHOD, blended_single_track, x, u, p, H_S, 1).x[-1]
            switch = end & ~last
            k = jnp.where(switch, k + 1, k)
            i = jnp.where(switch, ref["first"][k], j)
            # The centre of gravity's distance to its path, near the controlled axle's row.
            lo = ref["first"][k]
            _, _, dev, _ = nearest(ref["P"], jnp.maximum(i - WINDOW // 2, lo), lo,
                                   ref["last"][k], x[:2])
            stopped = finished & (jnp.abs(x[3]) < 1e-3)
            return (x, i, k, done | finished), (x, dev, stopped, j, steer, target)

        init = (x0, ref["first"][0], jnp.zeros((), int), jnp.zeros((), bool))
        _, out = lax.scan(body, init, None, length=n_steps)
        return out

    return jax.jit(run)


def tracking(plan, omap, footprint=None, vehicle: dict | None = None,
             margin: float | None = None) -> dict:
    """tracking(plan, omap, footprint=None, vehicle=None, margin=None) -> dict, plan.json's
    `tracking` block: `controller`, `model`, and along the tracked trajectory (`track`)
    max_deviation_m [m] (the centre of gravity's largest distance to the planned path),
    final_deviation_m [m] (where the car stopped, to the path's last row),
    final_heading_deviation_rad [rad] (its body's heading there, less the last row's),
    collides (the car's footprint, as `replay` checks it, at poses at most CHECK_SPACING_M
    apart and the moves between them) and clearance_min_m [m] (least distance of its disc
    cover, or rectangle, to an obstacle, as `replay` measures it, <= 0 touches). `plan`: the
    plan.json record or a PlanResult (with the planner's vehicle set and margin, as `replay`
    takes them). No path: the measures are None."""
    from stepzoo.search.planner.pathfinder import PlanResult
    from stepzoo.search.plans.replay import car_footprint, safety
    if isinstance(plan, PlanResult):
        if vehicle is None:
            raise ValueError("tracking a PlanResult needs the planner's vehicle set")
        from stepzoo.search.plans.files import path_rows
        from stepzoo.search.plans.replay import controls
        rows, start, segs = path_rows(plan, vehicle), plan.start, controls(plan)
    else:
        rows, start, segs = np.asarray(plan["path"], float), plan["start"], plan["controls"]
        vehicle = {**plan["vehicle"], **(vehicle or {})}
        margin = plan.get("params", {}).get("margin", margin)
    block = {"controller": CONTROLLER, "model": MODEL, **dict.fromkeys(METRICS)}
    if len(rows) < 2:
        return block
    if footprint is None:
        footprint = car_footprint(vehicle, margin)
    run = track(rows, start, vehicle, kinematic_rows(rows, segs))
    poses = run["poses"]
    step = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    # Every pose whose travel since the last kept one reaches CHECK_SPACING_M, and the last.
    kept = np.r_[0, 1 + np.flatnonzero(np.diff(np.floor(np.r_[0.0, np.cumsum(step)]
                                                           / CHECK_SPACING_M)) > 0)]
    kept = np.unique(np.r_[kept, len(poses) - 1])
    collides, clearance = safety(omap, footprint, poses[kept])
    block.update({
        "max_deviation_m": float(run["deviation"].max()),
        "final_deviation_m": float(np.hypot(*(run["end"][:2] - rows[-1, 1:3]))),
        "final_heading_deviation_rad": float(np.angle(np.exp(1j * (run["end"][2]
                                                                   - rows[-1, 3])))),
        "collides": collides, "clearance_min_m": clearance})
    return block
