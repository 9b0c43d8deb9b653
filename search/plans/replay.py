"""Plan fidelity: the inputs that produce a plan's path, segment by segment (plan.json's
`controls`), and their replay open loop from the start pose through the same models with a
tight adaptive reference (SciPy's DOP853), measured against the planned path and the map
(plan.json's `replay`): how far the planned path is from what the car would drive."""
from __future__ import annotations

import math
from functools import cache

import numpy as np

from stepzoo import dynamics
from stepzoo.dynamics.models import steered as steered_rhs
from stepzoo.search.planner.connection_ocp import DEFAULT_METHOD as CONNECT_METHOD
from stepzoo.search.world.footprint import (Footprint, first_collision, rectangle_clearance,
                                            rectangle_decides)
from stepzoo.search.world.maps import OccupancyMap
from stepzoo.search.plans.path_metrics import distance_to_obstacles
from stepzoo.search.planner.pathfinder import PlanResult

METHOD, RTOL, ATOL = "DOP853", 1e-10, 1e-12
FILL_METHOD = CONNECT_METHOD  # one step of it from a node gives the path rows between nodes
# Batches of the rows filled in between nodes: up to FILL_SMALL rows on the driver's small
# batch path, larger ones padded to FILL_LEAST rows at least (one program for most segments).
FILL_SMALL, FILL_LEAST = 16, 512
CHECK_SPACING_M = 0.05  # [m] at most between the replayed poses checked for collision
# [s] a planned node is the path row this close in time to its step: plan.json rounds times
# to 1e-6 s, and the rows filled in between nodes are far more than this apart.
NODE_TIME_TOL_S = 1e-5
VEHICLE_PARAMS = ("m", "Iz", "Lf", "Lr", "Caf", "Car")
KINEMATIC = ("kinematic", "kinematic_cg")  # the paper's kinematic bicycle, the rigid car's
METRICS = ("max_deviation_m", "final_deviation_m", "max_heading_deviation_rad", "collides",
           "goal_distance_m", "clearance_min_m")


def controls(result: PlanResult, method: str | None = None) -> list[dict]:
    """The inputs that produce the plan's path, a dict per segment, times [s] from the start:
    a tree edge on the dynamic bicycle (eq. 4) at constant speed and steer,
    {"model": "dynamic5", "t0", "duration", "vx" [m/s], "inputs": {"delta" [rad]}}, and a
    kinematic tree move (reverse gear or a tight move) or the connection on the kinematic
    bicycle with inputs piecewise constant over steps of dt,
    {"model": "kinematic", "t0", "dt", "v0" [m/s, signed, at the segment's start],
    "inputs": {"delta" [rad] (n,), "F" [N] (n,)}}; each also says which `move` it is, its
    `steps`, and the integrator (`method`, step `h` [s]) that planned it. `method`: the tree's
    integrator, recorded when given.

    Rate-limited steering (the steer a state, dynamics.models.steered): `inputs` also hold
    "delta_rate" [rad/s], the steer's constant rate over the segment (a tree edge) or over each
    step (the connection, (n,)), and "delta" is the steer at its (each step's) start; the
    kinematic segments drive the kinematic bicycle as a rigid car, {"model": "kinematic_cg"}
    (its (X, Y) the centre of gravity, psi the body, v the centre of gravity's speed)."""
    out, t0 = [], 0.0
    tree = {"method": method} if method else {}
    rates = result.path_steer_rates or [None] * len(result.path_edges)
    previous = np.zeros(5)  # the state a segment starts from unless it says otherwise
    for edge, steer, tight, way, rate in zip(result.path_edges, result.path_steers,
                                             result.path_tight, result.path_directions, rates):
        n = len(edge) - 1
        start = float(steer) if rate is None else float(steer - rate * n * result.h)
        ramp: dict[str, float | list] = {} if rate is None else {"delta_rate": float(rate)}
        if tight or way < 0:
            ramp = {k: [v] * n for k, v in ramp.items()}
            delta = ([start] * n if rate is None
                     else (start + rate * result.h * np.arange(n)).tolist())
            speed = result.tight_vx if tight or way < 0 else result.vx
            out.append({"model": "kinematic" if rate is None else "kinematic_cg", "t0": t0,
                        "dt": result.h, "v0": way * speed,
                        "inputs": {"delta": delta, "F": [0.0] * n, **ramp},
                        "move": "tight" if tight else "reverse", "steps": n, **tree,
                        "h": result.h})
        else:
            # Rate-limited, an edge after a standstill or a kinematic one sets off at the
            # lateral steady state of its steer: its (vy, r) at the start.
            settled = ({"lateral0": [float(v) for v in edge[0, 3:5]]}
                       if rate is not None and np.any(edge[0, 3:5] != previous[3:5]) else {})
            out.append({"model": "dynamic5", "t0": t0, "duration": n * result.h,
                        "vx": result.vx, "inputs": {"delta": start, **ramp}, "move": "tree",
                        "steps": n, **tree, "h": result.h, **settled})
        previous = edge[-1]
        # As path_rows times the path: the same sums, so a node's time matches its row's.
        t0 = t0 + result.h * n
    conn = result.connection
    if conn is not None:
        n = len(conn.inputs)
        ramp = ({} if conn.steer_rates is None
                else {"delta_rate": conn.steer_rates.tolist()})
        out.append({"model": "kinematic" if conn.steer_rates is None else "kinematic_cg",
                    "t0": t0, "dt": conn.tf / n,
                    "v0": float(conn.states[0, 3]),
                    "inputs": {"delta": conn.inputs[:, 0].tolist(),
                               "F": conn.inputs[:, 1].tolist(), **ramp},
                    "move": "connection", "steps": n, "method": CONNECT_METHOD,
                    "h": conn.tf / n})
    return out


def vehicle_params(vehicle: dict) -> dict:
    """The model parameters of a vehicle set (dynamics.vehicle) as plan.json records them:
    m [kg], Iz [kg m^2], Lf, Lr [m], Caf, Car [N/rad] (linear tyres), wheelbase [m]."""
    return {**{k: float(vehicle[k]) for k in VEHICLE_PARAMS},
            "wheelbase": float(vehicle["Lf"] + vehicle["Lr"]), "tyre": "linear"}


def replay(plan, omap: OccupancyMap, footprint: Footprint | None = None,
           vehicle: dict | None = None, margin: float | None = None) -> dict:
    """replay(plan, omap, footprint=None, vehicle=None, margin=None) -> dict, plan.json's
    `replay` block.

    `plan`: the plan.json record (a dict with controls, vehicle, start, goal, path and
    params) or a PlanResult (then `vehicle`, the planner's vehicle set, PathFinder.vehicle,
    is needed, and `margin` [m], the planner's collision margin, sizes the disc cover as the
    planner's does; a record brings its own in params). The controls are driven open loop from
    the start pose, segment after segment, by DOP853 at rtol 1e-10: the dynamic bicycle's
    state carried across tree edges; a kinematic segment starting from the pose reached at its
    v0; a tree edge after a kinematic one from that pose with vy = r = 0, as the planner
    starts it; a tree edge that records `lateral0` (rate-limited, after a standstill or a
    kinematic edge) from its (vy, r), the steady state of its steer.

    Against the planned path at its nodes (the planner's integration steps and the
    connection's intervals): max_deviation_m, final_deviation_m [m] (position) and
    max_heading_deviation_rad; collides: the `footprint` (default: the car's own, no margin,
    covered by discs as the planner covers it) along the replayed path, facing its psi
    (`drive`), poses at most CHECK_SPACING_M apart and the straight moves between
    them checked (first_collision),
    against `omap`; clearance_min_m [m]: the least distance of that disc cover (where the
    check decides by the rectangle, of the rectangle: `safety`) to an obstacle along the
    replay (<= 0 touches); goal_distance_m [m]: replayed end to the goal position.
    A plan without a path gets these as None; `segments`, `nodes`, `samples` count what was
    compared, `end` is the replayed end pose [X, Y, psi]."""
    if isinstance(plan, PlanResult):
        if vehicle is None:
            raise TypeError("replay of a PlanResult needs vehicle=PathFinder.vehicle")
        segs, start, goal = controls(plan), plan.start, plan.goal
    else:
        segs, start, goal = plan["controls"], plan["start"], plan["goal"]
        vehicle = {**plan["vehicle"], **(vehicle or {})}
        margin = plan.get("params", {}).get("margin", margin)
    block = {"method": METHOD, "rtol": RTOL, "atol": ATOL, "segments": len(segs),
             **dict.fromkeys(METRICS), "nodes": 0, "rows": 0, "samples": 0, "end": None}
    if not segs:
        return block
    if isinstance(plan, PlanResult):
        from stepzoo.search.plans.files import path_rows
        planned = path_rows(plan, vehicle)
    else:
        planned = np.asarray(plan["path"], float)
    if footprint is None:
        footprint = car_footprint(vehicle, margin)
    replayed, samples = drive(segs, start, vehicle, planned[:, 0])
    gap = np.hypot(*(replayed[:, :2] - planned[:, 1:3]).T)
    turn = np.abs(np.remainder(replayed[:, 2] - planned[:, 3] + math.pi, 2 * math.pi)
                  - math.pi)
    collides, clearance = safety(omap, footprint, samples)
    block.update({
        "max_deviation_m": float(gap.max()),
        "final_deviation_m": float(gap[-1]),
        "max_heading_deviation_rad": float(turn.max()),
        "collides": collides,
        "goal_distance_m": float(np.hypot(*(samples[-1, :2] - np.asarray(goal, float)[:2]))),
        "clearance_min_m": clearance,
        "nodes": 1 + sum(int(seg["steps"]) for seg in segs), "rows": len(planned),
        "samples": len(samples),
        "end": [float(v) for v in samples[-1]]})
    return block


def safety(omap: OccupancyMap, footprint: Footprint, poses) -> tuple[bool, float]:
    """(whether the footprint collides at the poses (M, 3+) [X, Y, psi] or on the straight
    moves between them (first_collision), the least distance [m] of its disc cover to an
    obstacle at the poses (<= 0 touches), or where the check decides by the rectangle, of
    the rectangle (rectangle_clearance, a lower bound))."""
    poses = np.asarray(poses, float)
    centres = footprint.disc_centres(poses)
    discs = distance_to_obstacles(omap, centres.reshape(-1, 2)).reshape(
        centres.shape[:-1]).min(axis=-1) - footprint.radius
    clearance = (rectangle_clearance(omap, footprint, poses, discs)
                 if rectangle_decides(omap, footprint) else float(discs.min()))
    return bool(first_collision(omap, footprint, poses[None])[0] >= 0), clearance


def car_footprint(vehicle: dict, margin: float | None = None) -> Footprint:
    """The car's own length x width footprint (no margin), with as many discs as the planner
    gives its footprint grown by `margin` [m] on every side (PathFinder)."""
    grow = 2 * (margin or 0.0)
    length, width = vehicle["length"], vehicle["width"]
    return Footprint.from_vehicle(length, width,
                                  2 * math.ceil((length + grow) / (width + grow)))


def drive(segs: list[dict], start, vehicle: dict,
          times=None) -> tuple[np.ndarray, np.ndarray]:
    """The controls `segs` driven open loop from the pose `start` [X, Y, psi]: (replayed
    poses (K, 3) at `times` [s] (ascending, from the start; default: the segments' steps,
    each joint once), replayed poses (M, 3) at most CHECK_SPACING_M apart, the ends
    included). A time on a joint is the earlier segment's end; times past the last segment
    are its end."""
    if times is None:
        times = np.r_[0.0, np.concatenate([
            float(seg["t0"]) + _span(seg) * np.arange(1, int(seg["steps"]) + 1) / int(seg["steps"])
            for seg in segs])] if segs else np.zeros(1)
    times = np.asarray(times, float)
    poses = np.tile(np.asarray(start, float)[:3], (len(times), 1))
    samples = [np.asarray(start, float)[None, :3]]
    todo = times > 0.0
    state = np.r_[np.asarray(start, float)[:3], 0.0, 0.0]  # [X, Y, psi, vy, r]

    def solve(model, x0, u, p, t0, duration, speed, steered, last):
        """One smooth piece from t0 [s]: poses at the times it covers written, its end
        state returned."""
        inside = todo & ((times <= t0 + duration) | last)
        x, at, fine = _solve(model, x0, u, p, duration, np.clip(times[inside] - t0, 0.0,
                                                                 duration), speed, steered)
        poses[inside] = at[:, :3]
        todo[inside] = False
        samples.append(fine[:, :3])
        return x

    for i, seg in enumerate(segs):
        inputs = seg["inputs"]
        steered = "delta_rate" in inputs  # the steer a state, driven by its rate
        last = i == len(segs) - 1
        if seg["model"] == "dynamic5":
            p = dict(_params("dynamic5", vehicle), vx=float(seg["vx"]))
            if "lateral0" in seg:
                state = np.r_[state[:3], seg["lateral0"]]  # set off at its recorded (vy, r)
            x0, u = state, [float(inputs["delta"])]
            if steered:
                x0, u = np.r_[state, u], [float(inputs["delta_rate"])]
            x = solve("dynamic5", x0, u, p, float(seg["t0"]), float(seg["duration"]),
                      abs(float(seg["vx"])), steered, last)
            state = x[:5]
        elif seg["model"] in KINEMATIC:
            model = seg["model"]
            p = _params(model, vehicle)
            x = np.r_[state[:3], float(seg["v0"])]
            uk = np.column_stack([inputs["delta_rate" if steered else "delta"],
                                  inputs["F"]]).astype(float)
            if steered:
                x = np.r_[x, float(inputs["delta"][0])]
            dt = float(seg["dt"])
            # Runs of equal inputs are one smooth problem: solved in one call.
            breaks = np.r_[0, 1 + np.flatnonzero((np.diff(uk, axis=0) != 0).any(axis=1)), len(uk)]
            for a, b in zip(breaks[:-1], breaks[1:]):
                speed = abs(x[3]) + abs(uk[a, 1]) / p["m"] * dt * (b - a)
                x = solve(model, x, uk[a], p, float(seg["t0"]) + a * dt, dt * (b - a),
                          speed, steered, last and b == len(uk))
            # The kinematic bicycle has no lateral motion: a tree edge after it starts at rest
            # laterally, as the planner starts it.
            state = np.r_[x[:3], 0.0, 0.0]
        else:
            raise ValueError(f"unknown control model {seg['model']!r}: dynamic5, "
                             f"{' or '.join(KINEMATIC)}")
    return poses, np.vstack(samples)


def _span(seg: dict) -> float:
    """[s] how long a control segment lasts."""
    return float(seg["duration"] if seg["model"] == "dynamic5" else seg["dt"] * seg["steps"])


def _solve(model: str, x0, u, p, duration, at, speed, steered=False):
    """One smooth piece: `model` (`steered`: its steer a state, driven by the first input)
    from x0 under constant inputs u for `duration` [s]; (end state, poses (len(at), 3) at
    the times `at` [s] from its start, poses (m, 3) at most CHECK_SPACING_M apart for a
    speed up to `speed` [m/s], the start excluded; both with every state column)."""
    from scipy.integrate import solve_ivp
    keys = tuple(sorted(p))
    fun = _rhs(model, steered, len(x0), len(u), keys)
    u, pv = [float(v) for v in u], [float(p[k]) for k in keys]
    sol = solve_ivp(lambda t, x: fun(t, x, u, pv), (0.0, duration), np.asarray(x0, float),
                    method=METHOD, rtol=RTOL, atol=ATOL, dense_output=True)
    if not sol.success:
        raise RuntimeError(f"replay of a {model} segment failed: {sol.message}")
    # 10% above the largest speed: a dynamic bicycle's lateral speed adds a little to vx.
    m = max(1, math.ceil(1.1 * speed * duration / CHECK_SPACING_M))
    fine = duration * np.arange(1, m + 1) / m
    poses = sol.sol(np.asarray(at)).T if len(at) else np.zeros((0, len(sol.y)))
    return sol.y[:, -1], poses, sol.sol(fine).T


@cache
def _rhs(model: str, steered: bool, n: int, k: int, keys: tuple):
    """The model's float64 right-hand side (`steered`: with the steer a state) as plain Python
    float code, g(t, x, u, pv) with x of n and u of k floats and pv the parameters' values in
    the order of `keys`; built once."""
    from stepzoo.search.plans.scalar_code import scalar_function
    rhs = dynamics.model(model).rhs
    return scalar_function(steered_rhs(rhs) if steered else rhs, n, k, keys)


def _params(model: str, vehicle: dict) -> dict:
    p = {k: float(vehicle[k]) for k in VEHICLE_PARAMS}
    return dict(p, Fxf=0.0) if model == "dynamic5" else dict(p, L=p["Lf"] + p["Lr"])


def path_nodes(result: PlanResult) -> np.ndarray:
    """(K, 4) [t s, X m, Y m, psi rad] the planned path at its nodes (the integrator's steps
    along the tree edges, the connection's intervals), each joint once; (0, 4) for none."""
    pieces, t0 = [], 0.0
    for edge in result.path_edges:
        t = t0 + result.h * np.arange(len(edge))
        pieces.append(np.column_stack([t, edge[:, :3]]))
        t0 = t[-1]
    if result.connection is not None:
        conn = result.connection
        pieces.append(np.column_stack([t0 + conn.t, conn.states[:, :3]]))
    if not pieces:
        return np.zeros((0, 4))
    # Each piece starts where the previous ended: drop the repeated joint row.
    return np.vstack([pieces[0]] + [p[1:] for p in pieces[1:]])


def model_rows(result: PlanResult, vehicle: dict, spacing: float) -> np.ndarray:
    """(K, 4) [t s, X m, Y m, psi rad]: the planned path at its nodes (path_nodes) and, between
    two nodes farther apart than `spacing` [m], rows that split the gap evenly: the model's
    own states, each one step of FILL_METHOD from the earlier node under its inputs (the
    segment's model, steer state included, as `controls` records it), so that the path is
    what the model drives between the nodes, not a chord. `vehicle`: PathFinder.vehicle."""
    import jax
    nodes = path_nodes(result)
    if not len(nodes):
        return nodes
    filled = [nodes]
    with jax.enable_x64(True):
        for seg, states in zip(controls(result), _segment_states(result)):
            filled.append(_fill(seg, states, vehicle, spacing))
    rows = np.vstack(filled)
    return rows[np.argsort(rows[:, 0], kind="stable")]


def _segment_states(result: PlanResult):
    """Each control segment's states at its steps (steps + 1, d), in `controls`' order: a
    tree edge's [X, Y, psi, vy, r] (a kinematic move's [X, Y, psi] with v appended by
    _fill), the connection's [X, Y, theta, v]."""
    yield from result.path_edges
    if result.connection is not None:
        yield result.connection.states


def _fill(seg: dict, states: np.ndarray, vehicle: dict, spacing: float) -> np.ndarray:
    """The rows (M, 4) of one segment strictly between its steps (see model_rows)."""
    from stepzoo.integrators import integrate_batch
    n, h, inputs = int(seg["steps"]), _span(seg) / int(seg["steps"]), seg["inputs"]
    steered = "delta_rate" in inputs
    gap = np.hypot(*np.diff(states[:, :2], axis=0).T)
    parts = np.maximum(np.ceil(gap / spacing), 1).astype(int)
    owner = np.repeat(np.arange(n), parts - 1)
    if not owner.size:
        return np.zeros((0, 4))
    frac = (np.arange(owner.size) - np.repeat(np.cumsum(parts - 1) - (parts - 1), parts - 1)
            + 1) / parts[owner]
    if seg["model"] == "dynamic5":
        model, p = "dynamic5", dict(_params("dynamic5", vehicle), vx=float(seg["vx"]))
        x = states[:n, :5]
        steer = float(inputs["delta"]) + float(inputs.get("delta_rate", 0.0)) * h * np.arange(n)
        u = np.full((n, 1), float(inputs["delta_rate"] if steered else inputs["delta"]))
    else:
        model, p = seg["model"], _params(seg["model"], vehicle)
        x = states[:n, :4] if states.shape[1] == 4 and seg["move"] == "connection" else \
            np.column_stack([states[:n, :3], np.full(n, float(seg["v0"]))])
        steer = np.asarray(inputs["delta"], float)[:n]
        u = np.column_stack([inputs["delta_rate" if steered else "delta"], inputs["F"]])[:n]
    if steered:
        x = np.column_stack([x, steer])
    rhs = steered_rhs(dynamics.model(model).rhs) if steered else dynamics.model(model).rhs
    # Padded to a power of two, and above FILL_SMALL to FILL_LEAST at least: the driver
    # compiles once per batch size, and most segments then share one program.
    size = 1 << max(4, math.ceil(math.log2(owner.size)))
    if size > FILL_SMALL:
        size = max(size, FILL_LEAST)
    pad = np.r_[owner, np.full(size - owner.size, owner[0])]
    step = np.r_[frac, np.ones(size - owner.size)] * h
    # Sliced in NumPy: a JAX slice compiles a program per segment's size.
    x1 = np.asarray(integrate_batch(FILL_METHOD, rhs, x[pad].astype(float),
                                    u[pad].astype(float), p, step, 1).x)[:owner.size, 1]
    t = float(seg["t0"]) + (owner + frac) * h
    return np.column_stack([t, x1[:, :3]])
