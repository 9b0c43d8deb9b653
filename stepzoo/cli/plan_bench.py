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
import sys

from stepzoo.errors import UsageError
from stepzoo.output import text_table
from stepzoo.search.plan_bench.engine import (INTEGRATOR_COLUMNS, SUMMARY_COLUMNS,
                                              integrator_summary, summary)
from stepzoo.workflows.plan_bench import DEFAULT_MAX_HOURS, plan_bench



def add_arguments(p):
    from stepzoo.workflows.plan import REVERSE_HELP, settings_help
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = settings_help()
    p.add_argument("queries", metavar="QUERIES", help="JSON list of queries {map (relative to "
                   "the file), cell_size [m/cell], start, goal [x, y, yaw], id}")
    p.add_argument("--runs", type=int, default=1, help="runs per query, seeds SEED.. (default 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first run (default 0)")
    p.add_argument("--speed", type=float, default=5.0, metavar="VX",
                   help="constant speed of the tree [m/s] (default 5)")
    p.add_argument("--config", metavar="FILE", help="planner config TOML (default: the "
                   "shipped search/planner/tuned_default.toml); its [planner] table sets the "
                   "budget")
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


def main(args) -> int:
    if args.runs < 1 or args.seed < 0:
        raise UsageError(f"--runs must be >= 1 and --seed >= 0, got {args.runs} and {args.seed}")
    if args.runners_up is not None and (args.runners_up < 0 or not args.integrators_from):
        raise UsageError("--runners-up N needs --integrators-from and N >= 0")
    if not args.max_hours > 0:
        raise UsageError(f"--max-hours must be a number > 0, got {args.max_hours!r}")
    if args.resume and args.overwrite:
        raise UsageError("--resume and --overwrite contradict each other (continue the "
                         "bench, or discard it); give one")
    out, rows, integrators = plan_bench(
        args.queries, args.out, runs=args.runs, seed=args.seed, speed_mps=args.speed,
        config_file=args.config, integrator=args.integrator, integrators_from=args.integrators_from,
        runners_up=args.runners_up, reverse=args.reverse, resume=args.resume,
        overwrite=args.overwrite, max_hours=args.max_hours, scheduler=args.scheduler,
        progress=args.progress)
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


