"""Plan-bench's engine: plan a list of queries with several integrators (the same seeds, one
warmed-up planner per (map, integrator)), here or on a Dask cluster, each run replayed through
the true models, and summarise per integrator. `stepzoo plan-bench` writes what it returns
into a results folder; `tune --for-plans` chooses from it."""
from __future__ import annotations

import json
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple
from time import perf_counter

from stepzoo.errors import UsageError
from stepzoo.search.plans import schema as plan_schema
from stepzoo.search.plans.schema import DRIVABILITY_COLUMNS, REPLAY_COLUMNS, RUN_COLUMNS, ordered

if TYPE_CHECKING:
    import numpy as np
    from stepzoo.search.planner.config import PlannerConfig, PlannerParams
    from stepzoo.search.planner.pathfinder import PathFinder
    from stepzoo.search.world.queries import Query

# The tables' columns in their order (documented in plan_schema).
SUMMARY_COLUMNS = list(plan_schema.SUMMARY_COLUMNS)
INTEGRATOR_COLUMNS = list(plan_schema.INTEGRATOR_COLUMNS)
# On a Dask worker: each thread's warmed-up planners, by finder_key (a planner is not safe to
# share between threads, and a worker may run several).
_worker = threading.local()


@dataclass(frozen=True)
class Task:
    """One run of the bench: query `query` planned with integrator `integrator` (indices into
    the bench's lists) and seed `seed`, with planner `config` at speed `vx` [m/s]."""
    integrator: int
    query: int
    run: int
    seed: int
    config: PlannerConfig      # of this integrator
    role: str
    q: Query
    vx: float

    @property
    def name(self) -> str:
        """The file name of its finished row (indices only: nothing the user typed)."""
        return f"{self.integrator:03d}-{self.query:05d}-{self.run:04d}"


class FinderKey(NamedTuple):
    """What a warmed-up planner is for: a map (file, cell size [m]), an integrator (method,
    h [s]), the planner parameters and the speed vx [m/s]."""
    map_file: str
    cell_size: float | None   # None: the map file gives it
    method: str
    h: float
    params: PlannerParams
    vx: float


def finder_key(task: Task) -> FinderKey:
    c = task.config
    return FinderKey(str(task.q.map_path.resolve()), task.q.cell_size, c.method, c.h,
                     c.params, task.vx)


def plan_run(task: Task, finders: dict) -> dict:
    """The table's row of one run, planned with the warmed-up planner of its (map,
    integrator) from `finders` (made there if missing), replayed through the true models
    (REPLAY_COLUMNS, None without a path; replay_s [s], its time, is not in time_s) and
    tracked (tracking_*, tracking_s likewise, search/plans/tracking.py); its
    `progress` a JSON list of the (time [s], length [m]) of each shorter path."""
    from stepzoo.search.plan_bench.ompl_log import STATUS_OF_CAUSE
    from stepzoo.search.plans.path_metrics import PATH_METRICS, path_metrics
    from stepzoo.search.planner.pathfinder import PathFinder
    from stepzoo.search.plans.files import path_rows, plan_drivability
    from stepzoo.search.plans.replay import replay
    from stepzoo.search.world.scenarios import open_map
    from stepzoo.search.plans.tracking import tracking
    q, config = task.q, task.config
    key = finder_key(task)
    if key not in finders:
        finders[key] = PathFinder(open_map(q.map_path, q.cell_size), config, None, task.vx)
        finders[key].warm_up()
    finder = finders[key]
    result = finder.plan(q.start, q.goal, None, task.seed)
    t0 = perf_counter()
    fidelity = replay(result, finder.omap, vehicle=finder.vehicle,
                      margin=finder.config.params.margin)
    replay_s = perf_counter() - t0
    t0 = perf_counter()
    tracked = tracking(result, finder.omap, vehicle=finder.vehicle,
                       margin=finder.config.params.margin)
    tracking_s = perf_counter() - t0
    exact = result.status == "exact"
    rows: np.ndarray | list = path_rows(result, finder.vehicle) if exact else []
    metrics = path_metrics(rows, finder.omap, finder.vehicle_footprint) \
        if exact else dict.fromkeys(PATH_METRICS)
    drivable = plan_drivability(rows, finder.vehicle, config.params)
    return ordered({
        "query": q.id, "map": q.map, "cell_size": q.cell_size, "run": task.run,
        "seed": task.seed, "status": result.status.value, "cause": result.cause.value,
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
        **{k: drivable[k] for k in DRIVABILITY_COLUMNS if k != "cusps"},
        **{f"tracking_{k}": v for k, v in tracked.items()},
        "tracking_s": tracking_s if fidelity["segments"] else None,
        "progress": json.dumps(result.progress)}, RUN_COLUMNS, "plan-bench row")


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
        finders: dict[FinderKey, PathFinder] = {}
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


def check_endpoints(queries, config, vx):
    """UsageError for the first query whose start or goal is off its map or in collision, as
    `stepzoo plan` refuses one: the poses are the user's input, not a result to record."""
    from stepzoo.search.planner.pathfinder import PathFinder
    from stepzoo.search.world.scenarios import open_map
    finders = {}
    for q in queries:
        key = (str(q.map_path.resolve()), q.cell_size)
        if key not in finders:
            finders[key] = PathFinder(open_map(q.map_path, q.cell_size), config, None, vx)
        cause, reason = finders[key].bad_endpoint(q.start, q.goal)
        if cause:
            raise UsageError(f"query {q.id}: {reason}; choose a pose in free space on the map")


def load(path, config, vx: float) -> list:
    """The queries of the file `path`, refused as plan-bench refuses them (UsageError): a
    missing map, a start or goal off its map or in collision for `config` at `vx` [m/s]."""
    from stepzoo.search.world.queries import load_queries
    queries = load_queries(path)
    for q in queries:
        if not q.map_path.is_file():
            raise UsageError(f"query {q.id}: map file {q.map_path} not found; map paths are "
                             "relative to the queries file")
    check_endpoints(queries, config, vx)
    return queries


def plan_all(queries, integrators, config, *, runs: int = 1, seed: int = 0, vx: float = 5.0,
             scheduler=None, on_row=None) -> tuple[list[dict], list[dict]]:
    """(rows, summary per integrator) of planning every query `runs` times (seeds seed..)
    with each of `integrators` (bench_integrators.Integrator) and `config`'s planner
    parameters at `vx` [m/s]; `on_row(done, total, row)` is called as each run finishes.
    The runs are interleaved, query by query and seed by seed, every integrator in turn, so
    that a load that changes while the bench runs weighs on every integrator alike."""
    from stepzoo.search.plan_bench.integrators import configured
    configs = [configured(config, item) for item in integrators]
    tasks = [Task(i, k, r, seed + r, configs[i], item.role, q, vx)
             for k, q in enumerate(queries) for r in range(runs)
             for i, item in enumerate(integrators)]
    done = {}
    for name, row in run_tasks(tasks, scheduler):
        done[name] = row
        if on_row is not None:
            on_row(len(done), len(tasks), row)
    rows = [done[t.name] for t in sorted(tasks, key=lambda t: t.name)]
    return rows, integrator_summary(rows, integrators)
