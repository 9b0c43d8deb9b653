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
from datetime import datetime, timezone
from importlib.metadata import version
from pathlib import Path

from stepzoo.errors import UsageError
from stepzoo.output import atomic_write, text_table
from stepzoo.search.bench_plans import (INTEGRATOR_COLUMNS, SUMMARY_COLUMNS, Task,
                                        integrator_summary, load, run_tasks, summary)

PLANNER = "stepzoo_PathFinder"
DEFAULT_MAX_HOURS = 24.0


def add_arguments(p):
    from stepzoo.cli.plan import REVERSE_HELP, settings_help
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
            planners.append((name, {"method": config.method, "h": config.h,
                                    **config.params.model_dump()}, runs))
        setup = json.dumps({"map": q.map, "cell_size": q.cell_size, "start": list(q.start),
                            "goal": list(q.goal), "config": configs[0].source or "built-in"})
        text = benchmark_log(
            experiment=q.id, version=f"stepzoo {version('stepzoo')}",
            host=socket.gethostname(), date=date, setup=setup, cpuinfo=_cpuinfo(), seed=seed,
            time_limit_s=float(configs[0].params.max_seconds),
            total_s=sum(r["time_s"] for _, _, runs in planners for r in runs),
            planners=planners, experiment_properties={"map": (q.map, "TEXT"),
                                                      "cell_size": (q.cell_size, "REAL")})
        target = logs / f"{q.id}.log"
        if target.parent != logs:       # load_queries refuses such ids; never write outside
            raise UsageError(f"query id {q.id!r} cannot name a file in {logs}")
        atomic_write(target, text)


def estimate(n_queries: int, n_integrators: int, runs: int, config, max_hours) -> str:
    """The bench's size and its longest planning time, as a line; UsageError past
    `max_hours`. Each plan stops at the budget max_seconds, so that bounds its time."""
    plans = n_queries * n_integrators * runs
    hours = plans * config.params.max_seconds / 3600
    line = (f"{plans} plans ({n_queries} queries x {n_integrators} integrators x {runs} "
            f"runs) of at most {config.params.max_seconds:g} s each: at most {hours:.3g} h "
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
    queries = load(args.queries, config, vx)
    line = estimate(len(queries), len(integrators), args.runs, config, args.max_hours)
    tasks = [Task(i, k, r, args.seed + r, c, item.role, q, vx)
             for i, (item, c) in enumerate(zip(integrators, configs))
             for k, q in enumerate(queries) for r in range(args.runs)]
    settings = {"queries": [[q.id, q.map, q.cell_size, list(q.start), list(q.goal)]
                            for q in queries],
                "integrators": [[i.method, i.h, i.role] for i in integrators],
                "runs": args.runs, "seed": args.seed, "speed": vx,
                "params": config.params.model_dump(),
                # A map file replaced by another under the same name is another bench.
                "map_sha256": {q.map: bench_folder.sha256(q.map_path) for q in queries}}
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
            sys.stderr.write(f"stepzoo plan-bench: {line}; {len(done)} already done\n")
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
