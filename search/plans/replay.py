"""Plan fidelity: the inputs that produce a plan's path, segment by segment (plan.json's
`controls`), and their replay open loop from the start pose through the same models with a
tight adaptive reference (SciPy's DOP853), measured against the planned path and the map
(plan.json's `replay`): how far the planned path is from what the car would drive."""
from __future__ import annotations

import math
from functools import cache

import numpy as np

from stepzoo import dynamics
from stepzoo.search.planner.connection_ocp import DEFAULT_METHOD as CONNECT_METHOD
from stepzoo.search.world.footprint import Footprint, first_collision
from stepzoo.search.world.maps import OccupancyMap
from stepzoo.search.plans.path_metrics import distance_to_obstacles
from stepzoo.search.planner.pathfinder import PlanResult

METHOD, RTOL, ATOL = "DOP853", 1e-10, 1e-12
CHECK_SPACING_M = 0.05  # [m] at most between the replayed poses checked for collision
# [s] a planned node is the path row this close in time to its step: plan.json rounds times
# to 1e-6 s, and the rows filled in between nodes are far more than this apart.
NODE_TIME_TOL_S = 1e-5
VEHICLE_PARAMS = ("m", "Iz", "Lf", "Lr", "Caf", "Car")
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
    integrator, recorded when given."""
    out, t0 = [], 0.0
    tree = {"method": method} if method else {}
    for edge, steer, tight, way in zip(result.path_edges, result.path_steers,
                                       result.path_tight, result.path_directions):
        n = len(edge) - 1
        if tight or way < 0:
            out.append({"model": "kinematic", "t0": t0, "dt": result.h, "v0": way * result.vx,
                        "inputs": {"delta": [float(steer)] * n, "F": [0.0] * n},
                        "move": "tight" if tight else "reverse", "steps": n, **tree,
                        "h": result.h})
        else:
            out.append({"model": "dynamic5", "t0": t0, "duration": n * result.h,
                        "vx": result.vx, "inputs": {"delta": float(steer)}, "move": "tree",
                        "steps": n, **tree, "h": result.h})
        # As path_rows times the path: the same sums, so a node's time matches its row's.
        t0 = t0 + result.h * n
    conn = result.connection
    if conn is not None:
        n = len(conn.inputs)
        out.append({"model": "kinematic", "t0": t0, "dt": conn.tf / n,
                    "v0": float(conn.states[0, 3]),
                    "inputs": {"delta": conn.inputs[:, 0].tolist(),
                               "F": conn.inputs[:, 1].tolist()},
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
    starts it.

    Against the planned path at its nodes (the planner's integration steps and the
    connection's intervals): max_deviation_m, final_deviation_m [m] (position) and
    max_heading_deviation_rad; collides: the `footprint` (default: the car's own, no margin,
    covered by discs as the planner covers it) along the replayed path, poses at most
    CHECK_SPACING_M apart and the straight moves between them checked (first_collision),
    against `omap`; clearance_min_m [m]: the least distance of that disc cover to an obstacle
    along the replay (<= 0 touches); goal_distance_m [m]: replayed end to the goal position.
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
             **dict.fromkeys(METRICS), "nodes": 0, "samples": 0, "end": None}
    if not segs:
        return block
    planned = (path_nodes(plan) if isinstance(plan, PlanResult)
               else _path_nodes(np.asarray(plan["path"], float), segs))
    if footprint is None:
        footprint = car_footprint(vehicle, margin)
    nodes, samples = drive(segs, start, vehicle)
    gap = np.hypot(*(nodes[:, :2] - planned[:, 1:3]).T)
    turn = np.abs(np.remainder(nodes[:, 2] - planned[:, 3] + math.pi, 2 * math.pi) - math.pi)
    centres = footprint.disc_centres(samples).reshape(-1, 2)
    block.update({
        "max_deviation_m": float(gap.max()),
        "final_deviation_m": float(gap[-1]),
        "max_heading_deviation_rad": float(turn.max()),
        "collides": bool(first_collision(omap, footprint, samples[None])[0] >= 0),
        "goal_distance_m": float(np.hypot(*(samples[-1, :2] - np.asarray(goal, float)[:2]))),
        "clearance_min_m": float(distance_to_obstacles(omap, centres).min()
                                 - footprint.radius),
        "nodes": len(nodes), "samples": len(samples),
        "end": [float(v) for v in samples[-1]]})
    return block


def car_footprint(vehicle: dict, margin: float | None = None) -> Footprint:
    """The car's own length x width footprint (no margin), with as many discs as the planner
    gives its footprint grown by `margin` [m] on every side (PathFinder)."""
    grow = 2 * (margin or 0.0)
    length, width = vehicle["length"], vehicle["width"]
    return Footprint.from_vehicle(length, width,
                                  2 * math.ceil((length + grow) / (width + grow)))


def drive(segs: list[dict], start, vehicle: dict) -> tuple[np.ndarray, np.ndarray]:
    """The controls `segs` driven open loop from the pose `start` [X, Y, psi]: (replayed
    poses (K, 3) at the segments' steps, the planned nodes' times, in order, each joint
    once; replayed poses (M, 3) at most CHECK_SPACING_M apart, the ends included)."""
    nodes, samples = [np.asarray(start, float)[None, :3]], [np.asarray(start, float)[None, :3]]
    state = np.r_[np.asarray(start, float)[:3], 0.0, 0.0]  # [X, Y, psi, vy, r]
    for seg in segs:
        if seg["model"] == "dynamic5":
            n = int(seg["steps"])
            p = dict(_params("dynamic5", vehicle), vx=float(seg["vx"]))
            x, seg_nodes, seg_samples = _solve(
                "dynamic5", state, [float(seg["inputs"]["delta"])], p, float(seg["duration"]),
                n, abs(float(seg["vx"])))
            state = x
        elif seg["model"] == "kinematic":
            p = _params("kinematic", vehicle)
            x = np.r_[state[:3], float(seg["v0"])]
            u = np.column_stack([seg["inputs"]["delta"], seg["inputs"]["F"]]).astype(float)
            dt = float(seg["dt"])
            seg_nodes, seg_samples = [], []
            # Runs of equal inputs are one smooth problem: solved in one call.
            breaks = np.r_[0, 1 + np.flatnonzero((np.diff(u, axis=0) != 0).any(axis=1)), len(u)]
            for a, b in zip(breaks[:-1], breaks[1:]):
                speed = abs(x[3]) + abs(u[a, 1]) / p["m"] * dt * (b - a)
                x, run_nodes, run_samples = _solve("kinematic", x, u[a], p, dt * (b - a),
                                                   b - a, speed)
                seg_nodes.append(run_nodes)
                seg_samples.append(run_samples)
            seg_nodes, seg_samples = np.vstack(seg_nodes), np.vstack(seg_samples)
            # The kinematic bicycle has no lateral motion: a tree edge after it starts at rest
            # laterally, as the planner starts it.
            state = np.r_[x[:3], 0.0, 0.0]
        else:
            raise ValueError(f"unknown control model {seg['model']!r}: dynamic5 or kinematic")
        nodes.append(seg_nodes)
        samples.append(seg_samples)
    return np.vstack(nodes), np.vstack(samples)


def _solve(model: str, x0, u, p, duration, steps, speed):
    """One smooth piece: `model` from x0 under constant inputs u for `duration` [s]; (end
    state, poses (steps, 3) at duration * k / steps for k = 1..steps, poses (m, 3) at most
    CHECK_SPACING_M apart for a speed up to `speed` [m/s], the start excluded)."""
    import jax
    import jax.numpy as jnp
    from scipy.integrate import solve_ivp
    fun = _rhs(model)
    # The replay is the float64 truth whatever precision the caller computes in: float64 in
    # this block only, no global setting changed.
    with jax.enable_x64(True):
        # JAX arrays once here: converting Python numbers at every call would double its cost.
        u, pv = jnp.asarray(u, float), {k: jnp.asarray(v, float) for k, v in p.items()}
        sol = solve_ivp(lambda t, x: np.asarray(fun(t, x, u, pv)), (0.0, duration),
                        np.asarray(x0, float), method=METHOD, rtol=RTOL, atol=ATOL,
                        dense_output=True)
    if not sol.success:
        raise RuntimeError(f"replay of a {model} segment failed: {sol.message}")
    at = duration * np.arange(1, steps + 1) / steps
    # 10% above the largest speed: a dynamic bicycle's lateral speed adds a little to vx.
    m = max(1, math.ceil(1.1 * speed * duration / CHECK_SPACING_M))
    fine = duration * np.arange(1, m + 1) / m
    return sol.y[:, -1], sol.sol(at).T[:, :3], sol.sol(fine).T[:, :3]


@cache
def _rhs(model: str):
    """The model's right-hand side, compiled once (per precision: _solve calls it in float64)."""
    import jax
    return jax.jit(dynamics.model(model).rhs)


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


def _path_nodes(path: np.ndarray, segs: list[dict]) -> np.ndarray:
    """(K, 4) the rows of plan.json's path (K', 4) [t s, X, Y, psi] at the segments' steps
    (the rows filled in between them are linear interpolation, not the planner's)."""
    pieces = [np.zeros(1)]
    for seg in segs:
        n = int(seg["steps"])
        span = float(seg["duration"] if seg["model"] == "dynamic5" else seg["dt"] * n)
        pieces.append(float(seg["t0"]) + span * np.arange(1, n + 1) / n)
    times = np.concatenate(pieces)
    k = np.clip(np.searchsorted(path[:, 0], times), 1, len(path) - 1)
    k = np.where(np.abs(path[k - 1, 0] - times) < np.abs(path[k, 0] - times), k - 1, k)
    off = np.abs(path[k, 0] - times).max()
    if off > NODE_TIME_TOL_S:
        raise ValueError(f"the plan's path has no row within {NODE_TIME_TOL_S:g} s of a "
                         f"control step ({off:.3g} s off): controls and path disagree")
    return path[k]
