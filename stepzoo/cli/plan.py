"""`stepzoo plan`: plan a built-in scenario, a scenario file, or a query on a map file with the
tree planner into plan.json, plan.png and map.npy; `--all` or a batch of scenarios (on a Dask
cluster with --scheduler) adds a summary table. Outputs are written after planning, atomically."""
import argparse
import os
from dataclasses import replace

from stepzoo.errors import UsageError
from stepzoo.search.plans.request import ENV, SERVER_WAIT_S
from stepzoo.workflows.plan import REVERSE_HELP, plan, settings_help, show, status



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
                   "(default: the shipped search/planner/tuned_default.toml)")
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
    from stepzoo.search.world.scenarios import builtin_names, custom_scenario, load_scenario, pose
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
        from stepzoo.search.world.scenarios import speed
        vx = speed(args.speed, "--speed")
        scenarios = [replace(s, speed=vx) for s in scenarios]
    return scenarios


def main(args) -> int:
    scenarios = _scenarios(args)
    batch = args.all or len(scenarios) > 1
    records = plan(scenarios, args.out, args.config, args.seed, reverse=args.reverse,
                   scheduler=args.scheduler, batch=batch, progress=args.progress)
    show(records, args.out, batch, args.format)
    return status(records)


