"""`stepzoo run`: the whole pipeline into one folder by calling the other commands in turn:
sweep -> tune -> plan the built-in scenarios with the tuned step -> report. Progress goes to
stderr (with each command's own output); stdout ends with the report's path."""
from __future__ import annotations

import contextlib
import json
import os
import sys
import time
from pathlib import Path

from stepzoo import bench, environment
from stepzoo.bench.tune import DEFAULT_MARGIN
from stepzoo.errors import UsageError
from stepzoo.results_folder import check_kind, writing
from stepzoo.validate import check

# Package data of bench, beside its modules (a module's file, not the package's: an editable
# install may make bench a namespace package, which has none).
DEFAULT_CONFIG = Path(bench.__file__).with_name("configs") / "envelope.toml"


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


def _say(line: str):
    sys.stderr.write(f"stepzoo run: {line}\n")
    sys.stderr.flush()


def config_path(given) -> Path:
    path = Path(given) if given else DEFAULT_CONFIG
    if not path.is_file():
        raise UsageError(f"sweep config {path} not found; give --config FILE (a sweep TOML, "
                         "e.g. bench/configs/small.toml)")
    return path


def stages(args, out: Path) -> list[tuple[str, list[str]]]:
    """(name, `stepzoo` argv) of each command the pipeline runs before the report."""
    return [
        # --resume: a rerun reuses a finished sweep of the same config and completes an
        # interrupted one; a different config is refused by the sweep with its own line.
        ("sweep", ["sweep", str(config_path(args.config)), "--out", str(out / "sweep"),
                   "--resume"]),
        ("tune", ["tune", str(out / "sweep"), "--pos-tol", repr(args.pos_tol),
                  "--margin", repr(args.margin), "--out", str(out / "tuned.toml")]),
        ("plan", ["plan", "--all", "--config", str(out / "tuned.toml"),
                  "--seed", str(args.seed), "--out", str(out / "plans")]),
    ]


def main(args) -> int:
    from stepzoo.bench.tune import check_arguments
    say = (lambda line: None) if args.quiet else _say
    # Every argument is checked before the first stage starts, not when its stage comes.
    check_arguments(args.pos_tol, args.margin)
    check("seed", "--seed", args.seed)
    out = check_kind(args.out, "run")
    steps = stages(args, out)
    with writing(out, "run"):
        return _run(args, out, steps, say)


def _run(args, out: Path, steps, say) -> int:
    """Run the stages, then the report; 1 when a plan is not exact (the report is made)."""
    from stepzoo.bench import cli
    from stepzoo.reports import cmd_report
    total = len(steps) + 1
    status = 0
    budget = [x for flag, value in (("--max-memory", args.max_memory),
                                    ("--max-steps", args.max_steps))
              if value is not None for x in (flag, repr(value))]
    started, began = time.perf_counter(), environment.now()
    took = {}
    for i, (name, argv) in enumerate(steps, 1):
        say(f"[{i}/{total}] {name}: stepzoo {' '.join(argv)}")
        t0 = time.perf_counter()
        # The commands' own tables are progress here: stdout is kept for the final path.
        # -q: the stages print nothing either; else their progress follows the run's.
        quiet = ["-q"] if args.quiet else [] if args.progress else ["--no-progress"]
        with open(os.devnull, "w") as null, \
                contextlib.redirect_stdout(null if args.quiet else sys.stderr):
            code = cli.main(argv + quiet + budget if name in cli.INTEGRATE else argv)
        if code == 1 and name == "plan":
            status = 1
            say("not every plan is exact; the report shows them")
        elif code == cli.INTERRUPTED:
            return code                   # the stage said so, and how to resume, in one line
        elif code:
            say(f"stopped: `stepzoo {name}` failed (exit {code}); see its message above")
            return code
        took[name] = round(time.perf_counter() - t0, 3)
        say(f"[{i}/{total}] {name} done in {took[name]:.1f} s")
    say(f"[{total}/{total}] report: stepzoo report {out} --out {out / 'report'}")
    index, _, _ = cmd_report.build(out / "sweep", out / "report", out / "tuned.toml",
                                   out / "plans", progress=args.progress)
    took["report"] = round(time.perf_counter() - started - sum(took.values()), 3)
    environment.write_manifest(out, "run", began, {
        "stages": [name for name, _ in steps] + ["report"], "stage_s": took,
        "sweep": "sweep", "tuned": "tuned.toml", "plans": "plans",
        "report": "report/index.html"})
    say(f"done in {time.perf_counter() - started:.1f} s")
    if args.format == "json":
        sys.stdout.write(json.dumps({"sweep": str(out / "sweep"),
                                     "tuned": str(out / "tuned.toml"),
                                     "plans": str(out / "plans"), "report": str(index)}) + "\n")
    else:
        sys.stdout.write(f"{index}\n")
    return status
