"""A plan as files: plan.json (status, path, the controls that produce it and their replay,
the tracking replay, tree, stats, params), plan.png in the paper's colours (black obstacles,
blue tree, red path) and map.npy, each written atomically."""
from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from stepzoo.output import atomic_write
from stepzoo.dynamics.vehicles import limits
from stepzoo.search.plans.path_metrics import cusps, drivability
from stepzoo.search.planner.pathfinder import PlanResult
from stepzoo.search.plans.schema import (DRIVABILITY_KEYS, PLAN_KEYS, STATS_KEYS, TRACKING_KEYS,
                                         ordered)
from stepzoo.search.plans.replay import controls, model_rows, replay, vehicle_params
from stepzoo.search.world.scenarios import Scenario
from stepzoo.search.plans.tracking import tracking

MAX_GAP_M = 0.1       # no two consecutive path rows farther apart [m] (the report's contract)
ROW_SPACING_M = MAX_GAP_M / 2  # spacing the path is filled to: half, for rounding room
TREE_POINTS = 6       # points kept per tree edge: the picture needs shape, not every step


def path_rows(result: PlanResult, vehicle: dict) -> np.ndarray:
    """(K, 4) [t s, X m, Y m, psi rad] along the tree edges and the connection, rows at most
    ROW_SPACING_M apart: the planner's nodes and, between them, the model's own states under
    the plan's inputs (replay.model_rows), not chords. `vehicle`: PathFinder.vehicle."""
    return model_rows(result, vehicle, ROW_SPACING_M)


def tree_polylines(result: PlanResult) -> list:
    """Every tree edge as a few [X, Y] points [m] (TREE_POINTS spread evenly over its
    states, ends included), rounded to centimetres; edges of one length in one array."""
    out: list = [None] * len(result.tree)
    by_length: dict[int, list[int]] = {}
    for i, edge in enumerate(result.tree):
        by_length.setdefault(len(edge), []).append(i)
    for n, edges in by_length.items():
        keep = np.unique(np.linspace(0, n - 1, TREE_POINTS).round().astype(int))
        points = np.round(np.stack([result.tree[i][keep, :2] for i in edges]), 2).tolist()
        for i, line in zip(edges, points):
            out[i] = line
    return out


def plan_record(result: PlanResult, scenario: Scenario, config, vehicle: dict, seed: int,
                warmup_s: float) -> dict:
    """The plan.json content, its `replay` block measured on the scenario's map."""
    rows = path_rows(result, vehicle)
    conn = result.connection
    assert result.cause is not None      # a finished plan says why it ended
    record = {
        "scenario": scenario.name,
        "description": scenario.description,
        "status": result.status.value,
        "reason": result.reason,
        "cause": result.cause.value,
        "start": [float(v) for v in scenario.start],
        "goal": [float(v) for v in scenario.goal],
        "goal_speed": scenario.goal_speed,
        "speed": scenario.speed,
        # Micrometres and microradians: far below any map cell, and a third of the file size.
        "path": np.round(rows, 6).tolist(),
        "vehicle": {"name": vehicle["name"], "length": vehicle["length"],
                    "width": vehicle["width"], "wheelbase": vehicle["Lf"] + vehicle["Lr"],
                    **vehicle_params(vehicle), **limits(vehicle["name"])},
        # The inputs, segment by segment, that drive the car along the path
        # (search/plans/replay.py).
        "controls": controls(result, config.method),
        "stats": ordered({
            "expansions": result.expansions,
            "nodes": result.nodes,
            "search_s": result.search_s,
            "connect_s": result.connect_s,
            "connect_attempts": result.connect_attempts,
            "warmup_s": warmup_s,
            "path_length_m": result.path_length() if len(rows) else None,
            "connect_tf_s": conn.tf if conn is not None else None,
            # Anytime: when the first exact path and the one returned (the shortest) were found,
            # [s] from the search's start, and the length of each shorter path on the way.
            "first_solution_s": result.first_solution_s,
            "solution_s": result.solution_s,
            "progress": [{"t_s": t, "length_m": length} for t, length in result.progress],
            # Which budget cut the search short (null: none, so the plan is reproducible).
            "budget_bound": result.budget_bound,
            "lower_bound_m": result.lower_bound_m,
            # Whether the tree exhausted its own moves and was widened by tight moves (the
            # kinematic bicycle at parking speed), and how many of the path's edges are such.
            "widened": result.widened,
            "tight_edges": sum(result.path_tight),
            "cusps": cusps(rows),
            "seed": seed,
            "method": config.method,
            "h": config.h,
            "n_steps": config.n_steps,
        }, STATS_KEYS, "plan.json stats"),
        "params": config.params.model_dump(),
        "config": {"method": config.method, "h": config.h, "provenance": config.provenance,
                   "file": config.source},
        "tree": tree_polylines(result),
        "map": {"file": "map.npy", "resolution": scenario.omap.resolution,
                "origin": list(scenario.omap.origin), "source": scenario.map_source},
    }
    # Those controls driven through the true models: how far the car strays from the path.
    record["replay"] = replay(record, scenario.omap)
    record["drivability"] = plan_drivability(rows, vehicle, config.params)
    # A tracking controller driving a richer car along the path: how far a real car strays.
    record["tracking"] = ordered(tracking(record, scenario.omap), TRACKING_KEYS,
                                 "plan.json tracking")
    return ordered(record, PLAN_KEYS, "plan.json")


def plan_drivability(rows, vehicle: dict, params) -> dict:
    """plan.json's `drivability` block (path_metrics.drivability) of path rows (K, 4) for the
    vehicle set `vehicle` and the planner parameters `params` (its steer limit delta_max),
    read from the course of the rear axle (the rows' centre of gravity, Lr back along psi)."""
    return ordered(drivability(rows, vehicle["Lf"] + vehicle["Lr"], params.delta_max,
                               **limits(vehicle["name"]), heading="rear_axle",
                               lr=vehicle["Lr"]), DRIVABILITY_KEYS, "plan.json drivability")


def render_png(record: dict, scenario: Scenario) -> bytes:
    """The plan drawn as the paper drew its results."""
    # Imported here: matplotlib takes a second or more to import, which `stepzoo plan` would
    # otherwise spend before its search starts.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure
    omap = scenario.omap
    xmin, xmax, ymin, ymax = omap.bounds()
    aspect = (ymax - ymin) / (xmax - xmin)
    fig = Figure(figsize=(8.0, min(max(8.0 * aspect, 3.0), 12.0)))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.imshow(omap.occupied, cmap="gray_r", vmin=0, vmax=1, origin="lower",
              extent=(xmin, xmax, ymin, ymax), interpolation="nearest")
    ax.add_collection(LineCollection(record["tree"], colors="blue", linewidths=0.5))
    if record["path"]:
        path = np.asarray(record["path"])
        ax.plot(path[:, 1], path[:, 2], color="red", linewidth=1.8)
    for pose, name in ((record["start"], "start"), (record["goal"], "goal")):
        ax.annotate(name, xy=pose[:2], xytext=(pose[0] - 3 * np.cos(pose[2]),
                                               pose[1] - 3 * np.sin(pose[2])),
                    arrowprops={"arrowstyle": "->", "color": "green"}, color="green")
    ax.set(xlim=(xmin, xmax), ylim=(ymin, ymax), xlabel="X [m]", ylabel="Y [m]",
           title=f"{record['scenario']}: {record['status']}")
    ax.set_aspect("equal")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    return buf.getvalue()


def write_plan(out_dir, record: dict, scenario: Scenario, png: bytes | None = None) -> Path:
    """Write plan.json, plan.png (`png`, or drawn here) and map.npy into out_dir; returns the
    plan.json path."""
    out_dir = Path(out_dir)
    png = render_png(record, scenario) if png is None else png
    buf = io.BytesIO()
    np.save(buf, np.asarray(scenario.omap.occupied, dtype=bool))
    atomic_write(out_dir / "map.npy", buf.getvalue())
    atomic_write(out_dir / "plan.png", png)
    # Compact: the path and the tree are thousands of numbers that indentation would triple.
    text = json.dumps(record, allow_nan=False, separators=(",", ":"))
    return atomic_write(out_dir / "plan.json", text + "\n")
