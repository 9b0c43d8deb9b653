"""`stepzoo plan`: plan a built-in scenario, a scenario file, or a query on a map file with the
tree planner into plan.json, plan.png and map.npy; `--all` or a batch of scenarios (on a Dask
cluster with --scheduler) adds a summary table. Outputs are written after planning, atomically."""
import argparse
import csv
import io
import json
import os
import sys
import textwrap
import time
from dataclasses import replace
from pathlib import Path

from stepzoo import environment
from stepzoo.errors import UsageError
from stepzoo.output import atomic_write, text_table, to_json
from stepzoo.search.plan_request import ENV, SERVER_WAIT_S
from stepzoo.validate import check

SUMMARY_COLUMNS = ["scenario", "status", "expansions", "nodes", "search_s", "connect_s",
                   "path_length_m", "connect_tf_s", "max_deviation_m"]


REVERSE_HELP = ("reverse gear: the tree and the connection may drive backwards, each change "
                "of direction costing cusp_cost (default: forward only, as the paper; also "
                "`reverse = 1` in [planner])")


def settings_help() -> str:
    """The planner settings as `--help` lists them: a config's [planner] table sets them."""
    from stepzoo.config_schema import describe
    from stepzoo.search.planner_config import PlannerParams
    lines = ["planner settings (a config TOML's [planner] table; name = default, range, doc):"]
    for name, info in PlannerParams.model_fields.items():
        lines += textwrap.wrap(f"{name} = {info.default:g}: {describe(info)}", 84,
                               initial_indent="  ", subsequent_indent="      ")
        lines += [f"      {line}" for line in textwrap.wrap(info.description, 80)]
    return "\n".join(lines)


def add_arguments(p):
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    shown = p.format_help

    def format_help():
        # The settings come from their schema (pydantic), imported only when help is shown:
        # `plan --server` builds this parser and must not pay for it.
        p.epilog = settings_help()
        return shown()
    p.format_help = format_help
    p.add_argument("scenario", nargs="*", metavar="SCENARIO",
                   help="a built-in scenario name or a scenario .toml file; several are a "
                   "batch, written like --all")
    p.add_argument("--all", action="store_true", help="plan every built-in scenario")
    p.add_argument("--map", metavar="FILE", help="map file (.yaml ROS, .map MovingAI, .png/.pgm, "
                   ".npy) to plan on instead of a scenario")
    p.add_argument("--cell-size", type=float, metavar="M",
                   help="[m/cell] for map files that do not store it")
    p.add_argument("--start", metavar="X,Y,PSI", help="start pose [m, m, rad] (with --map; "
                   "write --start=-1,2,0 when X is negative)")
    p.add_argument("--goal", metavar="X,Y,PSI[,V]",
                   help="goal pose [m, m, rad], optionally the goal speed [m/s] (with --map)")
    p.add_argument("--speed", type=float, metavar="VX", help="constant speed of the tree [m/s]")
    p.add_argument("--config", metavar="FILE", help="planner config TOML from `stepzoo tune` "
                   "(default: the shipped search/tuned_default.toml)")
    p.add_argument("--reverse", action="store_true", help=REVERSE_HELP)
    p.add_argument("--seed", type=int, default=0, help="seed of the random points (default 0)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--format", choices=["text", "json"], default="text",
                   help="what is printed: a line/table, or JSON")
    p.add_argument("--scheduler", metavar="ADDRESS", help="plan on a Dask cluster, one task "
                   "per scenario: tcp://HOST:8786, or local:N worker processes here")
    p.add_argument("--server", metavar="SOCKET", default=os.environ.get(ENV) or None,
                   help="plan in the `stepzoo serve` process listening at the Unix socket "
                   "SOCKET, which has JAX, the compiled programs and the solvers warm: the same "
                   f"files, output and exit status, without the start-up (default: ${ENV}; "
                   "unset or empty: plan in this process)")
    p.add_argument("--server-timeout", type=float, default=SERVER_WAIT_S, metavar="S",
                   help="with --server: how long to wait for the server to take the plan "
                   "(it plans one request at a time) before giving up [s] (default "
                   f"{SERVER_WAIT_S:g}); the plan itself is bounded by its own budget")


def _numbers(text, flag):
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise UsageError(f"{flag} must be comma-separated numbers like 5,20,0, got {text!r}") \
            from None


def _scenarios(args):
    """The scenarios the arguments ask for; every inconsistency is a UsageError."""
    from stepzoo.search.scenarios import builtin_names, custom_scenario, load_scenario, pose
    query = [f for f, v in (("--start", args.start), ("--goal", args.goal),
                            ("--cell-size", args.cell_size)) if v is not None]
    chosen = [f for f, v in (("SCENARIO", args.scenario or None), ("--all", args.all or None),
                             ("--map", args.map)) if v is not None]
    if len(chosen) != 1:
        raise UsageError("give exactly one of SCENARIO, --all or --map FILE "
                         f"(got {', '.join(chosen) or 'none'})")
    if args.map is None and query:
        raise UsageError(f"{', '.join(query)} only go with --map FILE; a scenario has its own")
    if args.map is not None:
        if args.start is None or args.goal is None:
            raise UsageError("--map needs --start X,Y,PSI and --goal X,Y,PSI[,V]")
        start = pose(_numbers(args.start, "--start"), "--start")
        goal = pose(_numbers(args.goal, "--goal"), "--goal", allow_speed=True)
        return [custom_scenario(args.map, args.cell_size, start, goal, args.speed)]
    names = builtin_names() if args.all else args.scenario
    scenarios = [load_scenario(n) for n in names]
    if len({s.name for s in scenarios}) < len(scenarios):
        raise UsageError("two scenarios of the batch have the same name (each is written to "
                         "a folder of its name); rename one file")
    if args.speed is not None:
        from stepzoo.search.scenarios import speed
        vx = speed(args.speed, "--speed")
        scenarios = [replace(s, speed=vx) for s in scenarios]
    return scenarios


def plan_scenario(scenario, config, seed):
    """(record, finder): plan one scenario after a warm-up, so times measure planning."""
    from stepzoo.search.pathfinder import PathFinder
    from stepzoo.search.plan_output import plan_record
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
            **{k: stats[k] for k in SUMMARY_COLUMNS[2:-1]},
            "max_deviation_m": record["replay"]["max_deviation_m"]}


def plan(scenarios, out, config=None, seed: int = 0, *, reverse: bool = False,
         scheduler=None, batch: bool | None = None, progress: bool = False) -> list[dict]:
    """Plan each scenario with the planner config file `config` (default: the shipped one;
    `reverse` allows reverse gear) and planner seed `seed`, and write the plans and a
    manifest into the folder `out`; returns their records. On the Dask cluster at
    `scheduler` if given; `progress`: a line per plan of a batch on stderr. A batch (default:
    more than one scenario) writes a folder per scenario and summary.csv/json; a single plan
    goes into `out` itself. `stepzoo plan` and `stepzoo run` call it, e.g.
    `plan([load_scenario("street")], "plans")`."""
    from stepzoo.search.pathfinder import BAD_ENDPOINT
    from stepzoo.results_folder import check_kind, claim
    from stepzoo.search.planner_config import load_config, with_params
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
        records = [_plan_one(s, config, seed, f"[{i}/{len(scenarios)}]",
                             progress and len(scenarios) > 1)
                   for i, s in enumerate(scenarios, 1)]
    else:
        from stepzoo.distributed import connect, gather_in_order
        with connect(scheduler) as client:
            records = gather_in_order(client, _plan_on_worker, scenarios, config, seed)
    for record in records:
        if record["cause"] in BAD_ENDPOINT:
            # The poses are the user's input: no plan is written for a pose that cannot be.
            raise UsageError(f"{record['reason']}; choose a pose in free space on the map")
    with claim(out, "plan"):
        _write(out, records, scenarios, batch)
        environment.write_manifest(out, "plan", started, {
            "scenarios": [r["scenario"] for r in records], "seed": seed,
            "config": config.source, "method": config.method, "h": config.h,
            "statuses": {r["scenario"]: r["status"] for r in records}})
    return records


def main(args) -> int:
    scenarios = _scenarios(args)
    batch = args.all or len(scenarios) > 1
    records = plan(scenarios, args.out, args.config, args.seed, reverse=args.reverse,
                   scheduler=args.scheduler, batch=batch, progress=args.progress)
    show(records, args.out, batch, args.format)
    return status(records)


def _plan_one(scenario, config, seed, count: str, progress: bool) -> dict:
    """plan_scenario, then a line on stderr saying how it went (none for a pose that cannot
    be planned: that is the user's mistake, told in one line after the batch)."""
    from stepzoo.search.pathfinder import BAD_ENDPOINT
    t0 = time.perf_counter()
    record = plan_scenario(scenario, config, seed)
    if progress and record["cause"] not in BAD_ENDPOINT:
        st = record["stats"]
        sys.stderr.write(f"stepzoo plan: {count} {scenario.name}: {record['status']} in "
                         f"{time.perf_counter() - t0:.1f} s (warm-up {st['warmup_s']:.2f} s, "
                         f"tree search time {st['search_s']:.3f} s, connection solve time "
                         f"{st['connect_s']:.3f} s)\n")
        sys.stderr.flush()
    return record


def _write(out, records, scenarios, batch: bool) -> None:
    """Write the plans: one into `out`, or a batch (a folder each and the summary)."""
    from stepzoo.search.plan_output import write_plan
    if not batch:
        write_plan(out, records[0], scenarios[0])
        return
    for record, scenario in zip(records, scenarios):
        write_plan(out / scenario.name, record, scenario)
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
                             f"{r['stats']['connect_s']:.3f} s{replayed} -> "
                             f"{out / 'plan.json'}\n")
        return
    rows = [_summary_row(r) for r in records]
    if fmt == "json":
        sys.stdout.write(json.dumps(rows) + "\n")
    else:
        sys.stdout.write(text_table(rows, SUMMARY_COLUMNS) + f"\nwritten to {out}\n")


def status(records) -> int:
    """Exit status 1 when a plan is not exact: the planner ran, but reached no goal."""
    return 0 if all(r["status"] == "exact" for r in records) else 1
