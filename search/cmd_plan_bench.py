"""`stepzoo plan-bench QUERIES --runs N --out DIR`: plan every query of a file N times (seeds
SEED..SEED+N-1) with each integrator (--integrator METHOD:H, or a tuned TOML's choice and
runners-up), one warmed-up planner per (map, integrator), into a tidy table (runs.parquet and
runs.csv, one row per run), a summary per integrator (summary.parquet and summary.csv) and
OMPL benchmark logs (ompl/<query>.log, a planner per integrator), which OMPL's
`ompl_benchmark_statistics ompl/*.log -d bench.db` turns into a Planner Arena database. Each
finished run is saved as it finishes; --resume continues a cut-off bench; --scheduler plans
on a Dask cluster."""
import argparse
import json
import platform
import socket
import sys
import threading
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib.metadata import version
from pathlib import Path
from time import perf_counter

from stepzoo.errors import UsageError
from stepzoo.output import atomic_write, text_table

PLANNER = "stepzoo_PathFinder"
SUMMARY_COLUMNS = ["runs", "exact", "exact_rate", "median_time_s", "median_first_solution_s",
                   "median_length_m"]
# The summary per integrator: who it is, then SUMMARY_COLUMNS, then the replay's verdict.
INTEGRATOR_COLUMNS = ["integrator", "method", "h", "role", *SUMMARY_COLUMNS,
                      "median_replay_deviation_m", "max_replay_deviation_m",
                      "replay_collisions"]
# plan.json's replay block (stepzoo.search.replay) as columns, spelled as there; its
# clearance_min_m is replay_clearance_min_m beside the planned path's own.
REPLAY_COLUMNS = ("max_deviation_m", "final_deviation_m", "max_heading_deviation_rad",
                  "collides", "goal_distance_m")
DEFAULT_MAX_HOURS = 24.0
# On a Dask worker: each thread's warmed-up planners, by finder_key (a planner is not safe to
# share between threads, and a worker may run several).
_worker = threading.local()


def add_arguments(p):
    from stepzoo.search.cmd_plan import REVERSE_HELP, settings_help
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = settings_help()
    p.add_argument("queries", metavar="QUERIES", help="JSON list of queries {map (relative to "
                   "the file), cell_size [m/cell], start, goal [x, y, yaw], id}")
    p.add_argument("--runs", type=int, default=1, help="runs per query, seeds SEED.. (default 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first run (default 0)")
    p.add_argument("--speed", type=float, default=5.0, metavar="VX",
                   help="constant speed of the tree [m/s] (default 5)")
    p.add_argument("--config", metavar="FILE", help="planner config TOML (default: the "
                   "shipped search/tuned_default.toml); its [planner] table sets the budget")
    p.add_argument("--integrator", action="append", metavar="METHOD:H",
                   help="plan with this method at this step [s] (repeatable), e.g. rk4:0.05; "
                   "default: the planner config's own")
    p.add_argument("--integrators-from", metavar="TUNED.toml", help="plan with the choice of "
                   "a TOML written by `stepzoo tune` and its runners-up")
    p.add_argument("--runners-up", type=int, metavar="N", help="with --integrators-from: "
                   "only its first N runners-up (default: all)")
    p.add_argument("--reverse", action="store_true", help=REVERSE_HELP)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--resume", action="store_true", help="continue the plan-bench DIR holds "
                   "(the same command): finished runs are kept, not planned again")
    p.add_argument("--overwrite", action="store_true",
                   help="discard the plan-bench DIR holds first")
    p.add_argument("--max-hours", type=float, default=DEFAULT_MAX_HOURS, metavar="H",
                   help="refuse a bench whose planning could take longer: runs x the "
                   f"budget max_seconds [h] (default {DEFAULT_MAX_HOURS:g})")
    p.add_argument("--scheduler", metavar="ADDRESS", help="plan the (integrator, query, run) "
                   "tasks on a Dask cluster: tcp://HOST:8786, or local:N worker processes "
                   "here (needs stepzoo[distributed])")
    p.add_argument("--format", choices=["text", "json"], default="text",
                   help="what is printed: a summary table, or JSON")


@dataclass(frozen=True)
class Task:
    """One run of the bench: query `query` planned with integrator `integrator` (indices into
    the bench's lists) and seed `seed`, with planner `config` at speed `vx` [m/s]."""
    integrator: int
    query: int
    run: int
    seed: int
    config: object             # PlannerConfig of this integrator
    role: str
    q: object                  # the Query
    vx: float

    @property
    def name(self) -> str:
        """The file name of its finished row (indices only: nothing the user typed)."""
        return f"{self.integrator:03d}-{self.query:05d}-{self.run:04d}"


def finder_key(task: Task) -> tuple:
    c = task.config
    return (str(task.q.map_path.resolve()), task.q.cell_size, c.method, c.h,
            tuple(sorted(c.params.items())), task.vx)


def plan_run(task: Task, finders: dict) -> dict:
    """The table's row of one run, planned with the warmed-up planner of its (map,
    integrator) from `finders` (made there if missing) and replayed through the true models
    (REPLAY_COLUMNS, None without a path; replay_s [s], its time, is not in time_s); its
    `progress` a JSON list of the (time [s], length [m]) of each shorter path."""
    from stepzoo.search.ompl_log import STATUS_OF_CAUSE
    from stepzoo.search.path_metrics import path_metrics
    from stepzoo.search.pathfinder import PathFinder
    from stepzoo.search.plan_output import path_rows
    from stepzoo.search.replay import replay
    from stepzoo.search.scenarios import open_map
    q, config = task.q, task.config
    key = finder_key(task)
    if key not in finders:
        finders[key] = PathFinder(open_map(q.map_path, q.cell_size), config, None, task.vx)
        finders[key].warm_up()
    finder = finders[key]
    result = finder.plan(q.start, q.goal, None, task.seed)
    t0 = perf_counter()
    fidelity = replay(result, finder.omap, vehicle=finder.vehicle,
                      margin=finder.config.params["margin"])
    replay_s = perf_counter() - t0
    exact = result.status == "exact"
    metrics = path_metrics(path_rows(result), finder.omap, finder.vehicle_footprint) \
        if exact else path_metrics([], None, None)
    return {
        "query": q.id, "map": q.map, "cell_size": q.cell_size, "run": task.run,
        "seed": task.seed, "status": result.status, "cause": result.cause,
        "solved": exact, "approximate": result.status == "approximate",
        "ompl_status": STATUS_OF_CAUSE[result.cause],
        "time_s": result.search_s + result.connect_s,
        "first_solution_s": result.first_solution_s,
        "solution_s": result.solution_s, **metrics,
        "expansions": result.expansions, "nodes": result.nodes,
        "budget_bound": result.budget_bound, "lower_bound_m": result.lower_bound_m,
        "widened": result.widened, "tight_edges": sum(result.path_tight),
        "connect_attempts": result.connect_attempts,
        "method": config.method, "h": config.h,
        "integrator": f"{config.method}:{config.h:.6g}", "role": task.role,
        **{k: fidelity[k] for k in REPLAY_COLUMNS},
        "replay_clearance_min_m": fidelity["clearance_min_m"],
        "replay_s": replay_s if fidelity["segments"] else None,   # a path to replay
        "progress": json.dumps(result.progress)}


def _plan_on_worker(task: Task) -> tuple[str, dict]:
    """(task name, row) in a Dask worker process, which plans in float64 as the `stepzoo`
    command does (a worker starts with JAX's default float32); the worker keeps its planners
    for the bench's later tasks."""
    import jax
    jax.config.update("jax_enable_x64", True)
    if not hasattr(_worker, "finders"):
        _worker.finders = {}
    return task.name, _jsonable(plan_run(task, _worker.finders))


def _jsonable(row: dict) -> dict:
    """`row` as the JSON file of a finished run reads back, so a resumed bench's table is the
    one an uninterrupted bench writes."""
    return json.loads(json.dumps(row, default=_plain))


def _plain(v):
    import numpy as np
    if isinstance(v, np.generic):
        return v.item()
    raise TypeError(f"{type(v).__name__} in a plan-bench row")


def run_tasks(todo: list[Task], scheduler=None):
    """(task name, row) of each task as it finishes: here, or on the Dask cluster at
    `scheduler`, one task per (integrator, query, run) as `sweep --scheduler` sends chunks."""
    if scheduler is None:
        finders = {}
        for task in todo:
            yield task.name, _jsonable(plan_run(task, finders))
        return
    from dask.distributed import as_completed

    from stepzoo.distributed import RETRIES, connect
    with connect(scheduler) as client:
        submitted = as_completed(client.submit(_plan_on_worker, task, retries=RETRIES,
                                               pure=False, key=f"stepzoo-plan-bench-{task.name}")
                                 for task in todo)
        for future in submitted:
            yield future.result()
            future.release()           # the row is on disk: the cluster can drop it


def _cpuinfo() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def write_logs(out, queries, rows, configs, seed):
    """One OMPL benchmark log per query into out/ompl/, a planner per integrator (named
    PLANNER when there is one, as before integrators could be compared)."""
    from stepzoo.search.ompl_log import benchmark_log
    date = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S")
    logs = Path(out, "ompl").resolve()
    for q in queries:
        planners = []
        for config in configs:
            label = f"{config.method}:{config.h:.6g}"
            runs = [dict(r, progress=json.loads(r["progress"])) for r in rows
                    if r["query"] == q.id and r["integrator"] == label]
            name = PLANNER if len(configs) == 1 else f"{PLANNER}[{label}]"
            planners.append((name, {"method": config.method, "h": config.h, **config.params},
                             runs))
        setup = json.dumps({"map": q.map, "cell_size": q.cell_size, "start": list(q.start),
                            "goal": list(q.goal), "config": configs[0].source or "built-in"})
        text = benchmark_log(
            experiment=q.id, version=f"stepzoo {version('stepzoo')}",
            host=socket.gethostname(), date=date, setup=setup, cpuinfo=_cpuinfo(), seed=seed,
            time_limit_s=float(configs[0].params["max_seconds"]),
            total_s=sum(r["time_s"] for _, _, runs in planners for r in runs),
            planners=planners, experiment_properties={"map": (q.map, "TEXT"),
                                                      "cell_size": (q.cell_size, "REAL")})
        target = logs / f"{q.id}.log"
        if target.parent != logs:       # load_queries refuses such ids; never write outside
            raise UsageError(f"query id {q.id!r} cannot name a file in {logs}")
        atomic_write(target, text)


def summary(rows) -> dict:
    """SUMMARY_COLUMNS over `rows`, and the replay's verdict on their exact plans: median
    and largest max_deviation_m [m], and how many replayed paths collide."""
    import numpy as np
    exact = [r for r in rows if r["solved"]]

    def median(key, among):
        values = [r[key] for r in among if r.get(key) is not None]
        return float(np.median(values)) if values else None
    deviations = [r["max_deviation_m"] for r in exact if r.get("max_deviation_m") is not None]
    return {"runs": len(rows), "exact": len(exact), "exact_rate": len(exact) / len(rows),
            "median_time_s": median("time_s", rows),
            "median_first_solution_s": median("first_solution_s", exact),
            "median_length_m": median("length_m", exact),
            "median_replay_deviation_m": median("max_deviation_m", exact),
            "max_replay_deviation_m": float(max(deviations)) if deviations else None,
            "replay_collisions": sum(bool(r.get("collides")) for r in exact)}


def integrator_summary(rows, integrators) -> list[dict]:
    """A summary row per integrator, in the bench's order."""
    out = []
    for item in integrators:
        own = [r for r in rows if r["integrator"] == item.label]
        out.append({"integrator": item.label, "method": item.method, "h": item.h,
                    "role": item.role, **summary(own)})
    return out


def _check_endpoints(queries, config, vx):
    """UsageError for the first query whose start or goal is off its map or in collision, as
    `stepzoo plan` refuses one: the poses are the user's input, not a result to record."""
    from stepzoo.search.pathfinder import PathFinder
    from stepzoo.search.scenarios import open_map
    finders = {}
    for q in queries:
        key = (str(q.map_path.resolve()), q.cell_size)
        if key not in finders:
            finders[key] = PathFinder(open_map(q.map_path, q.cell_size), config, None, vx)
        cause, reason = finders[key].bad_endpoint(q.start, q.goal)
        if cause:
            raise UsageError(f"query {q.id}: {reason}; choose a pose in free space on the map")


def _estimate(n_queries, integrators, runs, config, max_hours) -> str:
    """The bench's size and its longest planning time, as a line; UsageError past
    `max_hours`. Each plan stops at the budget max_seconds, so that bounds its time."""
    plans = n_queries * len(integrators) * runs
    hours = plans * config.params["max_seconds"] / 3600
    line = (f"{plans} plans ({n_queries} queries x {len(integrators)} integrators x {runs} "
            f"runs) of at most {config.params['max_seconds']:g} s each: at most {hours:.3g} h "
            "of planning")
    if hours > max_hours:
        raise UsageError(f"{line}, past --max-hours {max_hours:g}; give fewer queries, "
                         "integrators or runs, a smaller max_seconds in the config's [planner] "
                         "table, or raise --max-hours")
    return line


def main(args) -> int:
    from stepzoo import environment
    from stepzoo.results_folder import claim
    from stepzoo.search import bench_folder
    from stepzoo.search.bench_integrators import choose, configured
    from stepzoo.search.planner_config import load_config, with_params
    from stepzoo.search.queries import load_queries
    from stepzoo.search.scenarios import speed
    started = environment.now()
    if args.runs < 1 or args.seed < 0:
        raise UsageError(f"--runs must be >= 1 and --seed >= 0, got {args.runs} and {args.seed}")
    if args.runners_up is not None and (args.runners_up < 0 or not args.integrators_from):
        raise UsageError("--runners-up N needs --integrators-from and N >= 0")
    if not args.max_hours > 0:
        raise UsageError(f"--max-hours must be a number > 0, got {args.max_hours!r}")
    if args.resume and args.overwrite:
        raise UsageError("--resume and --overwrite contradict each other (continue the "
                         "bench, or discard it); give one")
    bench_folder.check_out(args.out, args.overwrite)
    vx = speed(args.speed, "--speed")
    config = load_config(args.config)
    if args.reverse:
        config = with_params(config, reverse=1)
    integrators = choose(args.integrator, args.integrators_from, args.runners_up, config)
    configs = [configured(config, item) for item in integrators]
    queries = load_queries(args.queries)
    for q in queries:
        if not q.map_path.is_file():
            raise UsageError(f"query {q.id}: map file {q.map_path} not found; map paths are "
                             "relative to the queries file")
    _check_endpoints(queries, config, vx)
    estimate = _estimate(len(queries), integrators, args.runs, config, args.max_hours)
    tasks = [Task(i, k, r, args.seed + r, c, item.role, q, vx)
             for i, (item, c) in enumerate(zip(integrators, configs))
             for k, q in enumerate(queries) for r in range(args.runs)]
    settings = {"queries": [[q.id, q.map, q.cell_size, list(q.start), list(q.goal)]
                            for q in queries],
                "integrators": [[i.method, i.h, i.role] for i in integrators],
                "runs": args.runs, "seed": args.seed, "speed": vx, "params": config.params}
    with claim(args.out, "plan-bench", overwrite=args.overwrite) as out:
        done = bench_folder.start(out, settings, args.resume, args.overwrite)
        if not done:
            environment.write_manifest(out, "plan-bench", started,
                                       {"settings": settings, "complete": False})
        # Interleaved, each query planned with every integrator in turn: a machine's load
        # drifting over a long bench then slows every integrator alike, not the last ones.
        todo = sorted((t for t in tasks if t.name not in done),
                      key=lambda t: (t.query, t.run, t.integrator))
        if args.progress:
            sys.stderr.write(f"stepzoo plan-bench: {estimate}; {len(done)} already done\n")
        for count, (name, row) in enumerate(run_tasks(todo, args.scheduler), 1):
            bench_folder.save(out, name, row)
            if args.progress:
                sys.stderr.write(f"stepzoo plan-bench: [{count}/{len(todo)}] {row['integrator']} "
                                 f"{row['query']} run {row['run']}: {row['status']} in "
                                 f"{row['time_s']:.2f} s\n")
        done = bench_folder.finished(out)
        rows = [done[t.name] for t in tasks]
        _write_tables(out, rows, integrators)
        write_logs(out, queries, rows, configs, args.seed)
        environment.write_manifest(out, "plan-bench", started, {
            "settings": settings, "complete": True,
            "files": ["runs.parquet", "runs.csv", "summary.parquet", "summary.csv",
                      *(f"ompl/{q.id}.log" for q in queries)]})
    total = summary(rows)
    per = integrator_summary(rows, integrators)
    if args.format == "json":
        sys.stdout.write(json.dumps({**total, "integrators": per}) + "\n")
    else:
        shown = SUMMARY_COLUMNS if len(per) == 1 else INTEGRATOR_COLUMNS
        sys.stdout.write(text_table(per if len(per) > 1 else [total], shown)
                         + f"\nwritten to {out} (runs.parquet, runs.csv, summary.parquet, "
                         "summary.csv, ompl/*.log for ompl_benchmark_statistics)\n")
    return 0


def _write_tables(out, rows, integrators):
    import io

    import pandas as pd
    for name, table in (("runs", pd.DataFrame(rows)),
                        ("summary", pd.DataFrame(integrator_summary(rows, integrators),
                                                 columns=INTEGRATOR_COLUMNS))):
        buf = io.BytesIO()
        table.to_parquet(buf, index=False)
        atomic_write(out / f"{name}.parquet", buf.getvalue())
        atomic_write(out / f"{name}.csv", table.to_csv(index=False))
