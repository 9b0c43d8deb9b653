"""`stepzoo report RESULTS --out DIR`: the HTML report (index.html, summary.md, PNGs) built
from result folders alone. RESULTS is a sweep folder, or a `stepzoo run` folder whose
sweep/, tuned.toml and plans/ are picked up; --tuned and --plans name them explicitly."""
from __future__ import annotations

import json
import sys
from stepzoo.workflows.report import build




def add_arguments(p):
    p.add_argument("results", metavar="RESULTS",
                   help="a sweep folder, or a `stepzoo run` folder (sweep/, tuned.toml, plans/)")
    p.add_argument("--tuned", metavar="FILE", help="tuned config from `stepzoo tune` "
                   "(default: RESULTS/tuned.toml of a run folder, if there)")
    p.add_argument("--plans", metavar="DIR", help="a plan folder from `stepzoo plan`, or a "
                   "folder of them from `stepzoo plan --all` (default: RESULTS/plans of a run "
                   "folder, if there)")
    p.add_argument("--plan-bench", metavar="DIR", help="a folder from `stepzoo plan-bench`: "
                   "adds its trade-off figure, plan time against replay deviation")
    p.add_argument("--out", required=True, metavar="DIR", help="report folder to write")
    p.add_argument("--verdict", action="append", default=[], metavar="METHOD:H",
                   help="add the per-point verdict of this (method, step [s]) on the sweep's "
                   "envelope, as `stepzoo verdict` gives it, and draw H on the limit and "
                   "error figures (repeatable)")
    p.add_argument("--format", choices=["text", "json"], default="text",
                   help="what is printed: the report's path, or JSON with every file")


def main(args) -> int:
    index, md, shown = build(args.results, args.out, args.tuned, args.plans,
                             progress=args.progress, verdicts=args.verdict,
                             bench_dir=args.plan_bench)
    if args.format == "json":
        files = [name for s in shown for name, _ in s.images]
        sys.stdout.write(json.dumps({"index": str(index), "summary": str(md),
                                     "figures": files}) + "\n")
    else:
        sys.stdout.write(f"report written to {index} (and {md.name})\n")
    return 0
