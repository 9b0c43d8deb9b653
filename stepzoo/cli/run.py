"""`stepzoo run`: the whole pipeline into one folder, through the functions the other
commands call: sweep -> tune -> plan the built-in scenarios with the tuned step -> report.
Progress goes to stderr (with each stage's own output); stdout ends with the report's path."""
from __future__ import annotations

import json
import sys

from stepzoo.validate import DEFAULT_MARGIN
from stepzoo.workflows.pipeline import run



def add_arguments(p):
    p.add_argument("--out", default="results", metavar="DIR",
                   help="output folder: sweep/, tuned.toml, plans/, report/ (default results)")
    p.add_argument("--config", metavar="FILE",
                   help="sweep config TOML (default: the shipped bench/configs/envelope.toml)")
    p.add_argument("--pos-tol", type=float, default=0.1, metavar="M",
                   help="position tolerance of the tuning [m] (default 0.1)")
    p.add_argument("--margin", type=float, default=DEFAULT_MARGIN, metavar="F",
                   help=f"stability margin of the tuning, a fraction (default {DEFAULT_MARGIN})")
    p.add_argument("--seed", type=int, default=0, help="seed of the planner (default 0)")
    p.add_argument("--format", choices=["text", "json"], default="text",
                   help="what is printed at the end: the report's path, or JSON with every "
                   "artefact")


def main(args) -> int:
    done = run(args.out, args.config, args.pos_tol, args.margin, args.seed,
               progress=args.progress, quiet=args.quiet)
    if args.format == "json":
        sys.stdout.write(json.dumps({"sweep": str(done.sweep), "tuned": str(done.tuned),
                                     "plans": str(done.plans), "report": str(done.report)})
                         + "\n")
    else:
        sys.stdout.write(f"{done.report}\n")
    return 0 if done.exact else 1
