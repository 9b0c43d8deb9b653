"""A plan's files, declared once: plan.json's keys (and those of its `stats`), and the columns
of plan-bench's tables (runs, summary), each with a doc line and its unit. plan_output and
bench_plans write by it (search/plans/files.py, search/plan_bench/engine.py); a key named here is
a contract."""
from __future__ import annotations

# Measures of an exact plan's path (search/plans/path_metrics.py), as planner benchmarks report
# them.
PATH_METRICS = {
    "length_m": "[m] along the path",
    "cusps": "changes of the direction of travel",
    "clearance_min_m": "[m] least distance of the car's disc cover to an obstacle or the "
                       "map's edge (<= 0 touches)",
    "clearance_mean_m": "[m] its mean over the path's rows",
    "curvature_max": "[1/m] largest |curvature|",
    "curvature_mean": "[1/m] length-weighted mean |curvature|",
    "smoothness": "[1/m] integral of curvature^2 over length",
}

# plan.json's `drivability`, from the path rows alone (path_metrics.drivability); the first
# six are also plan-bench columns.
DRIVABILITY_COLUMNS = {
    "max_curvature_1pm": "[1/m] largest |curvature|: heading change per metre over windows of "
                         "window_s",
    "max_steer_rate_radps": "[rad/s] largest rate of the implied steer atan(wheelbase kappa)",
    "max_lateral_acceleration_mps2": "[m/s^2] largest v^2 |kappa|",
    "reverse_length_m": "[m] driven backwards",
    "cusps": "changes of the direction of travel",
    "drivable": "whether each measure is within its tolerance times the car's limit",
}
DRIVABILITY_KEYS = {
    **DRIVABILITY_COLUMNS,
    "heading": "what the curvature is read from (path_metrics.drivability): rear_axle, the "
               "course of the rear axle's centre (the rows' (X, Y) Lr back along psi), which a "
               "rigid car drives along its body on curvature tan(delta) / wheelbase",
    "window_s": "[s] the time over which the heading's change per metre gives the curvature",
    "limits": "the car's limits: curvature_1pm [1/m] (tan(delta_max) / wheelbase), "
              "steer_rate_radps [rad/s], lateral_acceleration_mps2 [m/s^2]",
    "tolerance": "the factor over each limit that the rows' finite differences are allowed",
}

# plan.json, in the order it is written.
PLAN_KEYS = {
    "scenario": "the scenario's name (a query's: its map's)",
    "description": "one line on the scenario",
    "status": "exact | approximate | no_path (plan_result.PlannerStatus)",
    "reason": "why, in words: how the plan ended and what was tried",
    "cause": "why, as a word for programs (plan_result.Cause)",
    "start": "[X m, Y m, psi rad] the start pose",
    "goal": "[X m, Y m, psi rad] the goal pose",
    "goal_speed": "[m/s] the speed the connection ends at, null: free",
    "speed": "[m/s] the tree's constant speed",
    "path": "rows [t s, X m, Y m, psi rad] at most 0.1 m apart, tree edges then connection",
    "vehicle": "the car: name, length [m], width [m], wheelbase [m], its parameters and its "
               "limits max_steer_rate [rad/s], max_lateral_acceleration [m/s^2]",
    "controls": "the inputs, segment by segment, that drive the car along the path",
    "stats": "the search's measures (STATS_KEYS)",
    "params": "the planner parameters (planner_config.PlannerParams), every one",
    "config": "the integrator: method, h [s], provenance, file",
    "tree": "every tree edge as a few [X, Y] points [m]",
    "map": "the grid: file (map.npy), resolution [m/cell], origin [m], source",
    "replay": "the controls driven through the true models: deviation, collision, clearance",
    "drivability": "the path rows against the car's limits (DRIVABILITY_KEYS)",
    "tracking": "a path-tracking controller driving a richer car model along the path: "
                "deviation, collision, clearance (TRACKING_KEYS)",
}

# plan.json's `tracking`, in the order they are written (search/plans/tracking.py).
TRACKING_KEYS = {
    "controller": "the path-tracking controller: stanley",
    "model": "the car it drives: single_track_fiala (dynamics/blended.py)",
    "max_deviation_m": "[m] largest distance of the car's centre of gravity from the path",
    "final_deviation_m": "[m] where the car stopped, to the path's last row",
    "final_heading_deviation_rad": "[rad] the car's body heading where it stopped, less the "
                                   "path's last row's (the goal's), wrapped to (-pi, pi]",
    "collides": "whether the car's footprint collides along the tracked trajectory",
    "clearance_min_m": ("[m] least distance of its disc cover to an obstacle (<= 0 touches); "
                        "where the check decides by the car's rectangle, of the rectangle (a "
                        "lower bound: footprint.rectangle_clearance)"),
}

# plan.json's `stats`, in the order they are written.
STATS_KEYS = {
    "expansions": "nodes expanded",
    "nodes": "nodes in the tree, the start included",
    "search_s": "[s] wall time of the search, connections excluded",
    "connect_s": "[s] wall time of the connection OCP solves",
    "connect_attempts": "connection attempts that called the OCP",
    "warmup_s": "[s] compiling the integrator and building the OCP, before the plan",
    "path_length_m": "[m] along the path, null without one",
    "connect_tf_s": "[s] duration of the connection, null without one",
    "first_solution_s": "[s] from the search's start to the first exact path, null: none",
    "solution_s": "[s] from the search's start to the path returned (the shortest found)",
    "progress": "each shorter path: t_s [s] when found, length_m [m]",
    "budget_bound": "max_seconds | max_expansions: the budget that cut the search short; "
                    "null: it ended by itself (the same plan on any machine)",
    "lower_bound_m": "[m] no path from start to goal is shorter",
    "widened": "whether the exhausted tree was widened by tight moves",
    "tight_edges": "path edges that are tight moves (kinematic bicycle)",
    "cusps": "changes of the direction of travel along the path",
    "seed": "the seed of the random points",
    "method": "the integrator of the tree shootings",
    "h": "[s] its step",
    "n_steps": "integration steps per shooting",
}

# The replay's measures as plan-bench columns, spelled as in plan.json's `replay`.
REPLAY_COLUMNS = {
    "max_deviation_m": "[m] largest distance of the replayed path from the planned one",
    "final_deviation_m": "[m] the same at the path's end",
    "max_heading_deviation_rad": "[rad] largest heading difference",
    "collides": "whether the replayed path collides",
    "goal_distance_m": "[m] from the replayed end to the goal",
}

# plan-bench's runs table: one row per (query, integrator, run), in this order.
RUN_COLUMNS = {
    "query": "the query's id",
    "map": "its map file, relative to the queries file",
    "cell_size": "[m/cell] the map's cell size",
    "run": "which repetition (0..runs-1)",
    "seed": "the planner's seed for this run",
    "status": "exact | approximate | no_path",
    "cause": "why (plan_result.Cause)",
    "solved": "whether the plan is exact",
    "approximate": "whether the plan is approximate",
    "ompl_status": "the cause as the index of OMPL's PlannerStatus",
    "time_s": "[s] search and connections, warm-up excluded",
    "first_solution_s": "[s] to the first exact path",
    "solution_s": "[s] to the path returned",
    **PATH_METRICS,                  # null without an exact path
    "expansions": "nodes expanded",
    "nodes": "nodes in the tree",
    "budget_bound": "the budget that cut the search short, null: none",
    "lower_bound_m": "[m] no path is shorter",
    "widened": "whether tight moves widened the tree",
    "tight_edges": "path edges that are tight moves",
    "connect_attempts": "connection attempts that called the OCP",
    "method": "the integrator's method",
    "h": "[s] its step",
    "integrator": "method:h, the integrator's label",
    "role": "why the integrator is in the bench (tuned, runner-up, given)",
    **REPLAY_COLUMNS,
    "replay_clearance_min_m": "[m] the replayed path's least clearance",
    "replay_s": "[s] the replay's wall time (not in time_s), null without a path",
    # The path rows against the car's limits (plan.json's drivability; cusps above).
    **{k: v for k, v in DRIVABILITY_COLUMNS.items() if k != "cusps"},
    **{f"tracking_{k}": v for k, v in TRACKING_KEYS.items()},
    "tracking_s": "[s] the tracking replay's wall time (not in time_s), null without a path",
    "progress": "JSON list of (time [s], length [m]) of each shorter path",
}

# plan-bench's summary over runs.
SUMMARY_COLUMNS = {
    "runs": "runs summarised",
    "exact": "runs with an exact plan",
    "exact_rate": "exact / runs",
    "median_time_s": "[s] median time_s over all runs",
    "median_first_solution_s": "[s] median time to the first exact path, exact runs",
    "median_length_m": "[m] median path length, exact runs",
}

# plan-bench's summary.parquet: a row per integrator, then the replay's verdict.
INTEGRATOR_COLUMNS = {
    "integrator": "method:h",
    "method": "the integrator's method",
    "h": "[s] its step",
    "role": "why it is in the bench",
    **SUMMARY_COLUMNS,
    "median_replay_deviation_m": "[m] median max_deviation_m of the exact plans",
    "max_replay_deviation_m": "[m] largest max_deviation_m of the exact plans",
    "replay_collisions": "exact plans whose replay collides",
}

# The runs table's columns that are not numbers (each number may be null: no path, no
# solution): strings (budget_bound null when no budget cut the search) and true/false.
RUN_TEXT = ("query", "map", "status", "cause", "budget_bound", "method", "integrator", "role",
            "progress", "tracking_controller", "tracking_model")
RUN_FLAGS = ("solved", "approximate", "widened", "collides", "drivable", "tracking_collides")


def run_row_problem(row) -> str | None:
    """What makes `row` no row of the runs table (None: it is one): another set of columns,
    or a value of another kind than its column's (RUN_TEXT, RUN_FLAGS, else a number)."""
    if not isinstance(row, dict):
        return "not a JSON object"
    if set(row) != set(RUN_COLUMNS):
        lacking = [k for k in RUN_COLUMNS if k not in row]
        return (f"it lacks {', '.join(lacking[:3])}{' and more' if len(lacking) > 3 else ''}"
                if lacking else f"it has {sorted(set(row) - set(RUN_COLUMNS))[0]!r}, no column")
    for key, value in row.items():
        kind = str if key in RUN_TEXT else bool if key in RUN_FLAGS else (int, float)
        if value is not None and (not isinstance(value, kind) or
                                  (kind is not bool and isinstance(value, bool))):
            words = "a string" if kind is str else "true or false" if kind is bool else "a number"
            return f"its {key} must be {words}, got {value!r}"
    return None


def ordered(row: dict, keys: dict, what: str) -> dict:
    """`row` with its entries in the order of `keys` (one of the declarations above);
    ValueError if it holds other keys than those: a writer out of step with its schema."""
    if set(row) != set(keys):
        raise ValueError(f"{what} out of step with search/plans/schema.py: "
                         f"missing {sorted(set(keys) - set(row))}, "
                         f"undeclared {sorted(set(row) - set(keys))}")
    return {k: row[k] for k in keys}
