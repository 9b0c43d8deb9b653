"""The pipeline of `stepzoo run`: sweep -> tune -> plan the built-in scenarios with the tuned
step -> report, into one folder, through the same workflows the commands call. Progress
goes to stderr (with each stage's own output)."""
from __future__ import annotations

import contextlib
import os
import sys
import time
from pathlib import Path
from typing import NamedTuple

from stepzoo import bench, environment
from stepzoo.errors import NoAnswer, UsageError
from stepzoo.results_folder import check_kind, claim
from stepzoo.validate import DEFAULT_MARGIN, check


# Package data of bench, beside its modules (a module's file, not the package's: an editable
# install may make bench a namespace package, which has none).
DEFAULT_CONFIG = Path(bench.__file__).with_name("configs") / "envelope.toml"


def _say(line: str):
    sys.stderr.write(f"stepzoo run: {line}\n")
    sys.stderr.flush()


def config_path(given) -> Path:
    path = Path(given) if given else DEFAULT_CONFIG
    if not path.is_file():
        raise UsageError(f"sweep config {path} not found; give --config FILE (a sweep TOML, "
                         "e.g. bench/configs/small.toml)")
    from stepzoo.bench.sweep.config import check_one_problem
    from stepzoo.validate import read_toml
    check_one_problem(read_toml(path, "sweep config", "give --config FILE"), path)
    return path


class Run(NamedTuple):
    """What `run` wrote into its folder."""
    sweep: Path     # the sweep's results folder
    tuned: Path     # the tuned planner config
    plans: Path     # a plan folder per built-in scenario and their summary
    report: Path    # the report's index.html
    exact: bool     # every plan reached its goal exactly


def stages(out: Path, config: Path, pos_tol: float, margin: float, seed: int,
           progress: bool, ahead) -> list:
    """(name, the equivalent `stepzoo` argv, call) of each stage before the report; the
    sweep shares its chunks with the second process `ahead` (workflows.second_process.Ahead)."""
    from stepzoo.workflows import plan as plan_cmd, sweep as sweep_cmd, tune as tune_cmd
    from stepzoo.search.world.scenarios import builtin_names, load_scenario
    sweep, tuned, plans = out / "sweep", out / "tuned.toml", out / "plans"

    def sweep_stage():
        return sweep_cmd.show(sweep_cmd.sweep(config, sweep, resume=True, progress=progress,
                                              runner=ahead.sweep_runner(config)), sweep)

    def tune_stage():
        chosen = tune_cmd.kept(tuned, sweep, pos_tol, margin)
        if chosen is not None:
            # The stage's own output: stderr under `run`, nothing when quiet.
            print("tuned config kept: the file holds the choice made from this sweep with "
                  "this tolerance and margin")
        else:
            chosen = tune_cmd.tune(sweep, pos_tol, margin, tuned)
        tune_cmd.show(chosen, tuned)

    def plan():
        from stepzoo.search.planner.config import load_config
        scenarios = [load_scenario(n) for n in builtin_names()]
        records = plan_cmd.finished(plans, load_config(tuned), seed, scenarios)
        if records is not None:
            # The stage's own output: stderr under `run`, nothing when quiet.
            print("plans kept: the folder holds every built-in scenario planned with this "
                  "tuned step, its parameters and this seed")
        else:
            records = plan_cmd.plan(scenarios, plans, tuned, seed, batch=True,
                                    progress=progress, beside=ahead)
        plan_cmd.show(records, plans, True)
        return plan_cmd.status(records)

    return [
        # resume: a rerun reuses a finished sweep of the same config and completes an
        # interrupted one; a different config is refused by the sweep with its own line.
        ("sweep", ["sweep", str(config), "--out", str(sweep), "--resume"], sweep_stage),
        ("tune", ["tune", str(sweep), "--pos-tol", repr(pos_tol), "--margin", repr(margin),
                  "--out", str(tuned)],
         tune_stage),
        ("plan", ["plan", "--all", "--config", str(tuned), "--seed", str(seed),
                  "--out", str(plans)], plan),
    ]


def run(out="results", config=None, pos_tol: float = 0.1, margin: float = DEFAULT_MARGIN,
        seed: int = 0, *, progress: bool = True, quiet: bool = False) -> Run:
    """The whole pipeline into the folder `out`: sweep the config file `config` (default: the
    shipped envelope), tune under position tolerance `pos_tol` [m] and stability margin
    `margin`, plan the built-in scenarios with planner seed `seed`, build the report.
    Every argument is checked before the first stage starts. `progress`: progress bars and
    a line per stage on stderr, with each stage's own tables; `quiet`: nothing but errors.
    A stage's error is raised with the stage's name. `stepzoo run` calls it, e.g.
    `run("results", "bench/configs/small.toml")`."""
    from stepzoo.bench.tune.cheapest import check_arguments
    check_arguments(pos_tol, margin)
    check("seed", "--seed", seed)
    out = check_kind(out, "run")
    config = config_path(config)
    from stepzoo.bench.sweep.config import load
    cfg = load(config)
    if not cfg.spec.vehicle:     # found before the sweep, not at the tune stage after it
        raise UsageError(f"{config}: its model {cfg.spec.name} has no position (X, Y), and "
                         "`stepzoo run` tunes to a position tolerance (--pos-tol) for the "
                         "planner's car; "
                         f"run `stepzoo sweep {config} --out DIR`, then `stepzoo tune DIR --tol "
                         "E --out tuned.toml`")
    with claim(out, "run"):
        # A second process (stepzoo.workflows.second_process) computes some of the sweep's
        # chunks, draws Figures 1-6 and then plans some of the scenarios while this process
        # plans the others, and builds the report.
        from stepzoo.workflows.second_process import Ahead
        ahead = Ahead()
        try:
            steps = stages(out, config, pos_tol, margin, seed, progress and not quiet, ahead)
            return _run(out, steps, progress and not quiet, quiet, ahead)
        finally:
            ahead.close()


def _run(out: Path, steps, progress: bool, quiet: bool, ahead) -> Run:
    """Run the stages, then the report (made also when a plan is not exact)."""
    say = (lambda line: None) if quiet else _say
    total = len(steps) + 1
    exact = True
    started, began = time.perf_counter(), environment.now()
    took = {}
    for i, (name, argv, call) in enumerate(steps, 1):
        say(f"[{i}/{total}] {name}: stepzoo {' '.join(argv)}")
        t0 = time.perf_counter()
        # The stages' own tables are progress here: stdout is kept for the final path.
        try:
            with open(os.devnull, "w") as null, \
                    contextlib.redirect_stdout(null if quiet else sys.stderr):
                code = call()
        except (UsageError, NoAnswer) as err:
            raise type(err)(f"stopped at {name}: {err}") from None
        if code:
            exact = False
            say("not every plan is exact; the report shows them")
        took[name] = round(time.perf_counter() - t0, 3)
        say(f"[{i}/{total}] {name} done in {took[name]:.1f} s")
        if name == "tune":
            ahead.figures(out / "sweep", out / "tuned.toml")
    say(f"[{total}/{total}] report: stepzoo report {out} --out {out / 'report'}")
    report = (out / "sweep", out / "report", out / "tuned.toml", out / "plans", progress)
    index = ahead.report(*report)
    if index is None:
        from stepzoo.workflows import report as report_cmd
        index, _, _ = report_cmd.build(*report)
    took["report"] = round(time.perf_counter() - started - sum(took.values()), 3)
    environment.write_manifest(out, "run", began, {
        "stages": [name for name, _, _ in steps] + ["report"], "stage_s": took,
        "sweep": "sweep", "tuned": "tuned.toml", "plans": "plans",
        "report": "report/index.html"})
    say(f"done in {time.perf_counter() - started:.1f} s")
    return Run(out / "sweep", out / "tuned.toml", out / "plans", index, exact)
