"""Planning scenarios as the commands run it: each scenario planned (in turn, or as one batch
sharing the compiled planner), its files written, the summary table printed."""
import csv
import io
import json
import sys
import textwrap
import time
from pathlib import Path

from stepzoo import environment
from stepzoo.errors import UsageError
from stepzoo.output import atomic_write, text_table, to_json
from stepzoo.validate import check


SUMMARY_COLUMNS = ["scenario", "status", "expansions", "nodes", "search_s", "connect_s",
                   "path_length_m", "connect_tf_s", "max_deviation_m", "drivable"]
STATS_SHOWN = SUMMARY_COLUMNS[2:8]


REVERSE_HELP = ("reverse gear: the tree and the connection may drive backwards, each change "
                "of direction costing cusp_cost (default: forward only, as the paper; also "
                "`reverse = 1` in [planner])")


def settings_help() -> str:
    """The planner settings as `--help` lists them: a config's [planner] table sets them."""
    from stepzoo.config_schema import describe
    from stepzoo.search.planner.config import PlannerParams
    lines = ["planner settings (a config TOML's [planner] table; name = default, range, doc):"]
    for name, info in PlannerParams.model_fields.items():
        default = info.default if isinstance(info.default, str) else f"{info.default:g}"
        lines += textwrap.wrap(f"{name} = {default}: {describe(info)}", 84,
                               initial_indent="  ", subsequent_indent="      ")
        lines += [f"      {line}" for line in textwrap.wrap(info.description or "", 80)]
    return "\n".join(lines)


def plan_scenario(scenario, config, seed):
    """(record, finder): plan one scenario after a warm-up, so times measure planning."""
    from stepzoo.search.planner.pathfinder import PathFinder
    from stepzoo.search.plans.files import plan_record
    finder = PathFinder(scenario.omap, config, scenario.vehicle, scenario.speed)
    result = finder.refuse(scenario.start, scenario.goal)  # a bad pose, before compiling
    warmup_s = 0.0
    if result is None:
        warmup_s = finder.warm_up(scenario.goal_speed is not None)
        result = finder.plan(scenario.start, scenario.goal, scenario.goal_speed, seed)
    return plan_record(result, scenario, config, finder.vehicle, seed, warmup_s)


def _plan_on_worker(scenario, config, seed):
    """plan_scenario in a Dask worker process, which plans in float64 as the `stepzoo`
    command does (a worker starts with JAX's default float32)."""
    import jax
    jax.config.update("jax_enable_x64", True)
    return plan_scenario(scenario, config, seed)


def _summary_row(record):
    stats = record["stats"]
    return {"scenario": record["scenario"], "status": record["status"],
            **{k: stats[k] for k in STATS_SHOWN},
            "max_deviation_m": record["replay"]["max_deviation_m"],
            "drivable": record["drivability"]["drivable"]}


def plan(scenarios, out, config=None, seed: int = 0, *, reverse: bool = False,
         scheduler=None, batch: bool | None = None, progress: bool = False,
         beside=None) -> list[dict]:
    """Plan each scenario with the planner config file `config` (default: the shipped one;
    `reverse` allows reverse gear) and planner seed `seed`, and write the plans and a
    manifest into the folder `out`; returns their records. On the Dask cluster at
    `scheduler` if given; else here, sharing the scenarios with `beside` if given (see
    `plan_all`); `progress`: a line per plan of a batch on stderr. A batch (default:
    more than one scenario) writes a folder per scenario and summary.csv/json; a single plan
    goes into `out` itself. `stepzoo plan` and `stepzoo run` call it, e.g.
    `plan([load_scenario("street")], "plans")`."""
    from stepzoo.search.planner.pathfinder import BAD_ENDPOINT
    from stepzoo.results_folder import check_kind, claim
    from stepzoo.search.planner.config import load_config, with_params
    check("seed", "--seed", seed)
    started = environment.now()
    out = check_kind(out, "plan")
    config = load_config(config)
    if reverse:
        config = with_params(config, reverse=1)
    batch = len(scenarios) > 1 if batch is None else batch
    for s in scenarios:
        if tuple(s.start) == tuple(s.goal):
            raise UsageError(f"{s.name}: the start is the goal ({', '.join(map(str, s.start))}); "
                             "nothing to plan, give a goal elsewhere")
    if scheduler is None:
        # A line per plan of a batch; one plan's own result line follows at once.
        planned = plan_all(scenarios, config, seed, progress and len(scenarios) > 1, beside)
        records, pngs = [r for r, _ in planned], [png for _, png in planned]
    else:
        from stepzoo.distributed import connect, gather_in_order
        with connect(scheduler) as client:
            records = gather_in_order(client, _plan_on_worker, scenarios, config, seed)
        pngs = [None] * len(records)
    for record in records:
        if record["cause"] in BAD_ENDPOINT:
            # The poses are the user's input: no plan is written for a pose that cannot be.
            raise UsageError(f"{record['reason']}; choose a pose in free space on the map")
    with claim(out, "plan"):
        _write(out, records, scenarios, batch, pngs)
        environment.write_manifest(out, "plan", started, {
            "scenarios": [r["scenario"] for r in records], "seed": seed,
            "config": config.source, "method": config.method, "h": config.h,
            "statuses": {r["scenario"]: r["status"] for r in records}})
    return records


def finished(out, config, seed: int, scenarios) -> list[dict] | None:
    """The records of the batch `plan` finished in the folder `out` for these scenarios with
    this planner (the loaded config's method, h and parameters) and seed, read back from
    its plan.json files (how `stepzoo run` keeps its plans when run again); None where
    anything differs, or a file is missing or damaged."""
    import numpy as np
    out = Path(out)
    try:
        manifest = json.loads((out / "manifest.json").read_text())
        if (manifest.get("written_by") != "plan" or manifest.get("seed") != seed
                or manifest.get("scenarios") != [s.name for s in scenarios]
                or not {"summary.csv", "summary.json"} <= {p.name for p in out.iterdir()}):
            return None
        params = json.loads(to_json(config.params.model_dump()))
        records = []
        for s in scenarios:
            record = json.loads((out / s.name / "plan.json").read_text())
            same = (record["params"] == params and record["stats"]["seed"] == seed
                    and (record["config"]["method"], record["config"]["h"]) ==
                    (config.method, config.h)
                    and record["start"] == [float(v) for v in s.start]
                    and record["goal"] == [float(v) for v in s.goal]
                    and (record["speed"], record["goal_speed"]) == (s.speed, s.goal_speed)
                    and (out / s.name / "plan.png").is_file()
                    and np.array_equal(np.load(out / s.name / "map.npy"), s.omap.occupied))
            if not same:
                return None
            records.append(record)
        return records
    except (OSError, ValueError, KeyError, TypeError):
        return None


def timed_plan(scenario, config, seed) -> tuple[dict, float, bytes | None]:
    """(plan_scenario's record, its wall time [s], its plan.png, None for a pose that cannot
    be planned): drawn by the process that planned it."""
    from stepzoo.search.planner.pathfinder import BAD_ENDPOINT
    from stepzoo.search.plans.files import render_png
    t0 = time.perf_counter()
    record = plan_scenario(scenario, config, seed)
    seconds = time.perf_counter() - t0
    return (record, seconds,
            None if record["cause"] in BAD_ENDPOINT else render_png(record, scenario))


def plan_all(scenarios, config, seed, progress: bool,
             beside=None) -> list[tuple[dict, bytes | None]]:
    """(plan_scenario's record, its plan.png) of each scenario (timed_plan's), in their
    order, each followed by a line on stderr if `progress`. Without `beside` they are planned
    here in turn. With it (another process: `beside.start(scenario, config, seed)` has it
    plan a scenario, False where it cannot; `beside.ready()` says whether its answer has
    come; `beside.answer()` waits for it: timed_plan's answer, or None where that failed)
    this process plans the scenarios from the first on and hands that one the last not yet
    taken, one at a time, looking for its answer between its own plans (no thread: a Ctrl-C
    meets this process in its own work or its wait): two cores plan at once. A plan depends
    only on its scenario, config and seed (and, through a clock budget, on the processor
    time it gets), not on the process that makes it; one that `beside` could not make is
    made here, and from then on all are."""
    todo = list(range(len(scenarios)))
    done: dict[int, tuple[dict, bytes | None]] = {}
    away = None         # the scenario `beside` plans

    def finish(i, record, seconds, png):
        done[i] = record, png
        if progress:
            _say_planned(f"[{i + 1}/{len(scenarios)}]", scenarios[i].name, record, seconds)

    def hand():
        nonlocal away, beside
        if beside is not None and away is None and todo:
            away = todo.pop()
            if not beside.start(scenarios[away], config, seed):
                todo.append(away)
                away, beside = None, None

    def collect(wait: bool):
        nonlocal away, beside
        if away is None or not (wait or beside.ready()):
            return
        i, answer, away = away, beside.answer(), None
        if answer is None:              # that process failed: this one plans the rest
            todo.insert(0, i)
            beside = None
        else:
            finish(i, *answer)

    hand()
    while todo or away is not None:
        if not todo:                    # this process is done: wait for the other's plan
            collect(wait=True)          # (one it failed comes back to `todo`)
            continue
        i = todo.pop(0)
        finish(i, *timed_plan(scenarios[i], config, seed))
        collect(wait=False)
        hand()
    return [done[i] for i in range(len(scenarios))]


def _say_planned(count: str, name: str, record: dict, seconds: float) -> None:
    """A line on stderr saying how a plan went (none for a pose that cannot be planned: that
    is the user's mistake, told in one line after the batch)."""
    from stepzoo.search.planner.pathfinder import BAD_ENDPOINT
    if record["cause"] in BAD_ENDPOINT:
        return
    st = record["stats"]
    sys.stderr.write(f"stepzoo plan: {count} {name}: {record['status']} in {seconds:.1f} s "
                     f"(warm-up {st['warmup_s']:.2f} s, tree search time {st['search_s']:.3f} "
                     f"s, connection solve time {st['connect_s']:.3f} s)\n")
    sys.stderr.flush()


def _write(out, records, scenarios, batch: bool, pngs) -> None:
    """Write the plans: one into `out`, or a batch (a folder each and the summary); `pngs`
    their plan.png where drawn already (else None)."""
    from stepzoo.search.plans.files import write_plan
    if not batch:
        write_plan(out, records[0], scenarios[0], pngs[0])
        return
    for record, scenario, png in zip(records, scenarios, pngs):
        write_plan(out / scenario.name, record, scenario, png)
    rows = [_summary_row(r) for r in records]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, SUMMARY_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write(out / "summary.csv", buf.getvalue())
    atomic_write(out / "summary.json", to_json(rows) + "\n")


def show(records: list[dict], out, batch: bool, fmt: str = "text") -> None:
    """Print the plans written into `out`: a line (one plan) or the summary table of a
    batch; or JSON."""
    out = Path(out)
    if not batch:
        if fmt == "json":
            sys.stdout.write(json.dumps(_summary_row(records[0])) + "\n")
        else:
            r = records[0]
            deviation = r["replay"]["max_deviation_m"]
            replayed = "" if deviation is None else f", replay deviation {deviation:.3g} m"
            sys.stdout.write(f"{r['scenario']}: {r['status']} ({r['reason']}); "
                             f"{r['stats']['expansions']} expansions, search "
                             f"{r['stats']['search_s']:.3f} s, connection "
                             f"{r['stats']['connect_s']:.3f} s{replayed}"
                             f"{drivable_words(r['drivability'])} -> {out / 'plan.json'}\n")
        return
    rows = [_summary_row(r) for r in records]
    if fmt == "json":
        sys.stdout.write(json.dumps(rows) + "\n")
    else:
        sys.stdout.write(text_table(rows, SUMMARY_COLUMNS) + f"\nwritten to {out}\n")


def status(records) -> int:
    """Exit status 1 when a plan is not exact: the planner ran, but reached no goal."""
    return 0 if all(r["status"] == "exact" for r in records) else 1



def drivable_words(block: dict) -> str:
    """', drivable' or ', not drivable (what exceeds its limit)' for a plan's drivability
    block; '' without a path."""
    if block["drivable"] is None:
        return ""
    words = {"curvature_1pm": ("curvature", "1/m"), "steer_rate_radps": ("steer rate", "rad/s"),
             "lateral_acceleration_mps2": ("lateral acceleration", "m/s^2")}
    over = [f"{words[name][0]} {block['max_' + name]:.3g} > {block['tolerance'][name]:g} x "
            f"{limit:.3g} {words[name][1]}"
            for name, limit in block["limits"].items()
            if block["max_" + name] > block["tolerance"][name] * limit]
    return ", drivable" if block["drivable"] else f", not drivable ({'; '.join(over)})"
