"""Plan-bench's engine as one library call: plan a list of queries with several integrators
(the same seeds, one warmed-up planner per (map, integrator)) and return the rows and the
summary per integrator that `stepzoo plan-bench` writes, without a results folder."""
from __future__ import annotations

from stepzoo.errors import UsageError
from stepzoo.search import cmd_plan_bench as engine


def load(path, config, vx: float) -> list:
    """The queries of the file `path`, refused as plan-bench refuses them (UsageError): a
    missing map, a start or goal off its map or in collision for `config` at `vx` [m/s]."""
    from stepzoo.search.queries import load_queries
    queries = load_queries(path)
    for q in queries:
        if not q.map_path.is_file():
            raise UsageError(f"query {q.id}: map file {q.map_path} not found; map paths are "
                             "relative to the queries file")
    engine._check_endpoints(queries, config, vx)
    return queries


def plan_all(queries, integrators, config, *, runs: int = 1, seed: int = 0, vx: float = 5.0,
             scheduler=None, on_row=None) -> tuple[list[dict], list[dict]]:
    """(rows, summary per integrator) of planning every query `runs` times (seeds seed..)
    with each of `integrators` (bench_integrators.Integrator) and `config`'s planner
    parameters at `vx` [m/s]; `on_row(done, total, row)` is called as each run finishes.
    The runs are interleaved, query by query and seed by seed, every integrator in turn, so
    that a load that changes while the bench runs weighs on every integrator alike."""
    from stepzoo.search.bench_integrators import configured
    configs = [configured(config, item) for item in integrators]
    tasks = [engine.Task(i, k, r, seed + r, configs[i], item.role, q, vx)
             for k, q in enumerate(queries) for r in range(runs)
             for i, item in enumerate(integrators)]
    done = {}
    for name, row in engine.run_tasks(tasks, scheduler):
        done[name] = row
        if on_row is not None:
            on_row(len(done), len(tasks), row)
    rows = [done[t.name] for t in sorted(tasks, key=lambda t: t.name)]
    return rows, engine.integrator_summary(rows, integrators)
