"""Plan-bench as the command runs it: the tasks (integrator, query, run) planned here or on a
cluster, each saved as it finishes, then the tables, the OMPL logs and the manifest."""
import json
import platform
import socket
import sys
from datetime import datetime, timezone
from importlib.metadata import version
from pathlib import Path

from stepzoo.errors import UsageError
from stepzoo.output import atomic_write
from stepzoo.search.plan_bench.engine import (INTEGRATOR_COLUMNS, Task,
                                        integrator_summary, load, run_tasks)


PLANNER = "stepzoo_PathFinder"
DEFAULT_MAX_HOURS = 24.0


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
    from stepzoo.search.plan_bench.ompl_log import benchmark_log
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


def plan_bench(query_file, out_dir, *, runs: int = 1, seed: int = 0, speed_mps: float = 5.0,
               config_file=None, integrator=None, integrators_from=None, runners_up=None,
               reverse: bool = False, resume: bool = False, overwrite: bool = False,
               max_hours: float = DEFAULT_MAX_HOURS, scheduler=None, progress: bool = True):
    """Plan every query of `query_file` `runs` times (seeds `seed`..) at `speed_mps` [m/s]
    with each integrator into `out_dir`: each run saved as it finishes, then the tables and
    OMPL logs; returns (folder, rows, integrators). `stepzoo plan-bench` calls it."""
    from stepzoo import environment
    from stepzoo.results_folder import claim
    from stepzoo.search.plan_bench import folder as bench_folder
    from stepzoo.search.plan_bench.integrators import choose, configured
    from stepzoo.search.planner.config import load_config, with_params
    from stepzoo.search.world.scenarios import speed
    started = environment.now()
    bench_folder.check_out(out_dir, overwrite)
    vx = speed(speed_mps, "--speed")
    config = load_config(config_file)
    if reverse:
        config = with_params(config, reverse=1)
    integrators = choose(integrator, integrators_from, runners_up, config)
    configs = [configured(config, item) for item in integrators]
    queries = load(query_file, config, vx)
    line = estimate(len(queries), len(integrators), runs, config, max_hours)
    tasks = [Task(i, k, r, seed + r, c, item.role, q, vx)
             for i, (item, c) in enumerate(zip(integrators, configs))
             for k, q in enumerate(queries) for r in range(runs)]
    settings = {"queries": [[q.id, q.map, q.cell_size, list(q.start), list(q.goal)]
                            for q in queries],
                "integrators": [[i.method, i.h, i.role] for i in integrators],
                "runs": runs, "seed": seed, "speed": vx,
                "params": config.params.model_dump(),
                # A map file replaced by another under the same name is another bench.
                "map_sha256": {q.map: bench_folder.sha256(q.map_path) for q in queries}}
    with claim(out_dir, "plan-bench", overwrite=overwrite) as out:
        done = bench_folder.start(out, settings, resume, overwrite)
        if not done:
            environment.write_manifest(out, "plan-bench", started,
                                       {"settings": settings, "complete": False})
        # Interleaved, each query planned with every integrator in turn: a machine's load
        # drifting over a long bench then slows every integrator alike, not the last ones.
        todo = sorted((t for t in tasks if t.name not in done),
                      key=lambda t: (t.query, t.run, t.integrator))
        if progress:
            sys.stderr.write(f"stepzoo plan-bench: {line}; {len(done)} already done\n")
        for count, (name, row) in enumerate(run_tasks(todo, scheduler), 1):
            bench_folder.save(out, name, row)
            if progress:
                sys.stderr.write(f"stepzoo plan-bench: [{count}/{len(todo)}] {row['integrator']} "
                                 f"{row['query']} run {row['run']}: {row['status']} in "
                                 f"{row['time_s']:.2f} s\n")
        done = bench_folder.finished(out)
        rows = [done[t.name] for t in tasks]
        _write_tables(out, rows, integrators)
        write_logs(out, queries, rows, configs, seed)
        environment.write_manifest(out, "plan-bench", started, {
            "settings": settings, "complete": True,
            "files": ["runs.parquet", "runs.csv", "summary.parquet", "summary.csv",
                      *(f"ompl/{q.id}.log" for q in queries)]})
    return out, rows, integrators
