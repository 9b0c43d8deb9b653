"""OMPL's benchmark log format (the text ompl::tools::Benchmark writes and OMPL's script
`ompl_benchmark_statistics` turns into a Planner Arena SQLite database): one experiment (a
query) per log, a planner per integrator, a row of properties per run, and the anytime
progress."""
from __future__ import annotations

# ompl::base::PlannerStatus, in the order of its enum (the `status` column stores the index).
OMPL_STATUS = ("Unknown status", "Invalid start", "Invalid goal", "Unrecognized goal type",
               "Timeout", "Approximate solution", "Exact solution", "Crash", "Abort",
               "Infeasible")
# Our causes (plan_result.Cause) as OMPL statuses.
STATUS_OF_CAUSE = {"start_off_map": 1, "start_in_collision": 1, "goal_off_map": 2,
                   "goal_in_collision": 2, "walled_off": 9, "start_boxed_in": 9,
                   "goal_boxed_in": 9, "exhausted": 9, "budget": 5,
                   "connections_failed": 5, "connected": 6}
# (column of the runs table, OMPL property name, SQL type). OMPL's own names where it has one.
RUN_PROPERTIES = (
    ("time_s", "time", "REAL"),
    ("solved", "solved", "BOOLEAN"),
    ("approximate", "approximate solution", "BOOLEAN"),
    ("ompl_status", "status", "ENUM"),
    ("first_solution_s", "first solution time", "REAL"),
    ("length_m", "solution length", "REAL"),
    ("clearance_min_m", "solution clearance", "REAL"),
    ("clearance_mean_m", "solution clearance mean", "REAL"),
    ("smoothness", "solution smoothness", "REAL"),
    ("curvature_max", "solution curvature max", "REAL"),
    ("curvature_mean", "solution curvature mean", "REAL"),
    ("cusps", "solution cusps", "INTEGER"),
    ("expansions", "iterations", "INTEGER"),
    ("nodes", "graph states", "INTEGER"),
    ("connect_attempts", "connection attempts", "INTEGER"),
    ("seed", "seed", "INTEGER"),
    ("max_deviation_m", "replay max deviation", "REAL"),
    ("final_deviation_m", "replay final deviation", "REAL"),
    ("collides", "replay collides", "BOOLEAN"),
)


def _value(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return str(int(v))
    return repr(float(v)) if isinstance(v, float) else str(v)


def benchmark_log(*, experiment: str, version: str, host: str, date: str, setup: str,
                  cpuinfo: str, seed: int, time_limit_s: float, total_s: float,
                  planners: list[tuple[str, dict, list[dict]]],
                  experiment_properties: dict | None = None) -> str:
    """The log text of one experiment; `planners` are (name, common settings, runs), the runs
    dicts with the RUN_PROPERTIES columns and `progress`, a list of (time [s], best length
    [m]) pairs; every planner has the same number of runs."""
    props = experiment_properties or {}
    lines = [f"{version.split()[0]} version {version.split()[-1]}",
             f"Experiment {experiment}",
             f"{len(props)} experiment properties",
             *(f"{name} {sqltype} = {value}" for name, (value, sqltype) in props.items()),
             f"Running on {host}", f"Starting at {date}",
             "<<<|", setup.rstrip("\n"), "|>>>", "<<<|", cpuinfo.rstrip("\n"), "|>>>",
             f"{seed} is the random seed", f"{time_limit_s!r} seconds per run",
             "0 MB per run", f"{len(planners[0][2])} runs per planner",
             f"{total_s!r} seconds spent to collect the data",
             "1 enum types", "|".join(("status", *OMPL_STATUS)),
             f"{len(planners)} planners"]
    for planner, settings, runs in planners:
        lines += [planner, f"{len(settings)} common properties",
                  *(f"{k} = {v}" for k, v in settings.items()),
                  f"{len(RUN_PROPERTIES)} properties for each run",
                  *(f"{name} {sqltype}" for _, name, sqltype in RUN_PROPERTIES),
                  f"{len(runs)} runs"]
        lines += ["; ".join(_value(run[col]) for col, _, _ in RUN_PROPERTIES) + "; "
                  for run in runs]
        lines += ["2 progress properties for each run", "time REAL", "best cost REAL",
                  f"{len(runs)} runs"]
        lines += ["".join(f"{t!r},{c!r},;" for t, c in run["progress"]) for run in runs]
        lines.append(".")
    return "\n".join(lines) + "\n"
