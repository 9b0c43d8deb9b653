"""`stepzoo plan-bench QUERIES --runs N --out DIR`: plan every query of a file N times (seeds
SEED..SEED+N-1) in one process, one warmed-up planner per map, into a tidy table (runs.parquet
and runs.csv, one row per run) and OMPL benchmark logs (ompl/<query>.log), which OMPL's
`ompl_benchmark_statistics ompl/*.log -d bench.db` turns into a Planner Arena database."""
import argparse
import json
import platform
import socket
import sys
from datetime import datetime, timezone
from importlib.metadata import version
from pathlib import Path

from stepzoo.errors import UsageError
from stepzoo.output import atomic_write, text_table

PLANNER = "stepzoo_PathFinder"
SUMMARY_COLUMNS = ["runs", "exact", "exact_rate", "median_time_s", "median_first_solution_s",
                   "median_length_m"]


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
    p.add_argument("--reverse", action="store_true", help=REVERSE_HELP)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--format", choices=["text", "json"], default="text",
                   help="what is printed: a summary table, or JSON")


def bench_rows(queries, config, runs, seed, speed):
    """One dict per run of every query: the table's row, its `progress` a JSON list of the
    (time [s], length [m]) of each shorter path."""
    from stepzoo.search.path_metrics import path_metrics
    from stepzoo.search.pathfinder import PathFinder
    from stepzoo.search.plan_output import path_rows
    from stepzoo.search.ompl_log import STATUS_OF_CAUSE
    from stepzoo.search.scenarios import open_map
    finders, rows = {}, []
    for q in queries:
        key = (str(q.map_path.resolve()), q.cell_size)
        if key not in finders:
            finders[key] = PathFinder(open_map(q.map_path, q.cell_size), config, None, speed)
            finders[key].warm_up()
        finder = finders[key]
        for run in range(runs):
            result = finder.plan(q.start, q.goal, None, seed + run)
            metrics = path_metrics(path_rows(result), finder.omap, finder.vehicle_footprint) \
                if result.status == "exact" else path_metrics([], None, None)
            rows.append({
                "query": q.id, "map": q.map, "cell_size": q.cell_size, "run": run,
                "seed": seed + run, "status": result.status, "cause": result.cause,
                "solved": result.status == "exact",
                "approximate": result.status == "approximate",
                "ompl_status": STATUS_OF_CAUSE[result.cause],
                "time_s": result.search_s + result.connect_s,
                "first_solution_s": result.first_solution_s,
                "solution_s": result.solution_s, **metrics,
                "expansions": result.expansions, "nodes": result.nodes,
                "budget_bound": result.budget_bound, "lower_bound_m": result.lower_bound_m,
                "widened": result.widened, "tight_edges": sum(result.path_tight),
                "connect_attempts": result.connect_attempts,
                "method": config.method, "h": config.h,
                "progress": json.dumps(result.progress)})
    return rows


def _cpuinfo() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def write_logs(out, queries, rows, config, seed, total_s):
    """One OMPL benchmark log per query into out/ompl/."""
    from stepzoo.search.ompl_log import benchmark_log
    date = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S")
    settings = {"method": config.method, "h": config.h, **config.params}
    for q in queries:
        runs = [dict(r, progress=json.loads(r["progress"])) for r in rows if r["query"] == q.id]
        setup = json.dumps({"map": q.map, "cell_size": q.cell_size, "start": list(q.start),
                            "goal": list(q.goal), "config": config.source or "built-in"})
        text = benchmark_log(
            experiment=q.id, version=f"stepzoo {version('stepzoo')}",
            host=socket.gethostname(), date=date, setup=setup, cpuinfo=_cpuinfo(), seed=seed,
            time_limit_s=float(config.params["max_seconds"]), total_s=total_s,
            planner=PLANNER, settings=settings, runs=runs,
            experiment_properties={"map": (q.map, "TEXT"),
                                   "cell_size": (q.cell_size, "REAL")})
        atomic_write(out / "ompl" / f"{q.id}.log", text)


def summary(rows) -> dict:
    import numpy as np
    exact = [r for r in rows if r["solved"]]

    def median(key, among):
        values = [r[key] for r in among if r[key] is not None]
        return float(np.median(values)) if values else None
    return {"runs": len(rows), "exact": len(exact), "exact_rate": len(exact) / len(rows),
            "median_time_s": median("time_s", rows),
            "median_first_solution_s": median("first_solution_s", exact),
            "median_length_m": median("length_m", exact)}


def main(args) -> int:
    import io
    from time import perf_counter

    import pandas as pd

    from stepzoo.search.planner_config import load_config, with_params
    from stepzoo.search.queries import load_queries
    from stepzoo.search.scenarios import speed
    if args.runs < 1 or args.seed < 0:
        raise UsageError(f"--runs must be >= 1 and --seed >= 0, got {args.runs} and {args.seed}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} exists and is not a folder; give a folder")
    vx = speed(args.speed, "--speed")
    config = load_config(args.config)
    if args.reverse:
        config = with_params(config, reverse=1)
    queries = load_queries(args.queries)
    for q in queries:
        if not q.map_path.is_file():
            raise UsageError(f"query {q.id}: map file {q.map_path} not found; map paths are "
                             "relative to the queries file")
    t0 = perf_counter()
    rows = bench_rows(queries, config, args.runs, args.seed, vx)
    total_s = perf_counter() - t0
    table = pd.DataFrame(rows)
    buf = io.BytesIO()
    table.to_parquet(buf, index=False)
    atomic_write(out / "runs.parquet", buf.getvalue())
    atomic_write(out / "runs.csv", table.to_csv(index=False))
    write_logs(out, queries, rows, config, args.seed, total_s)
    total = summary(rows)
    if args.format == "json":
        sys.stdout.write(json.dumps(total) + "\n")
    else:
        sys.stdout.write(text_table([total], SUMMARY_COLUMNS) + f"\nwritten to {out} (runs.parquet,"
                         f" runs.csv, ompl/*.log for ompl_benchmark_statistics)\n")
    return 0
