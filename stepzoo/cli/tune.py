"""`stepzoo tune RESULTS --tol E | --pos-tol M --out tuned.toml`: the cheapest (method, h) of a
sweep that is stable with a margin and meets a tolerance everywhere, as a TOML config; cheapest
in time measured in the planner's own call (--cost time), or in RHS evaluations."""
import sys

from stepzoo.cli import tune_plans
from stepzoo.bench.calibrate import ROUNDS
from stepzoo.output import text_table, to_json
from stepzoo.results_folder import check_file_target
from stepzoo.validate import DEFAULT_MARGIN


def add_arguments(p):
    p.add_argument("results", metavar="RESULTS", help="a folder written by `stepzoo sweep`")
    p.add_argument("--tol", type=float, metavar="E", help="largest error allowed at every "
                   "operating point, in the config's error norm (the error states over their "
                   "scales); any model")
    p.add_argument("--pos-tol", type=float, metavar="METRES",
                   help="largest position error allowed at every operating point [m]; vehicle "
                   "models")
    p.add_argument("--margin", type=float, default=DEFAULT_MARGIN, metavar="FRACTION",
                   help="keep h <= (1 - margin) x the measured largest stable step (default "
                   f"{DEFAULT_MARGIN})")
    p.add_argument("--cost", choices=["time", "evals"], default="time",
                   help="rank by wall time per simulated second, calibrated in the planner's "
                   "call (default; a tie within the measured spread goes to fewer RHS "
                   "evaluations), or by RHS evaluations per simulated second")
    p.add_argument("--rounds", type=int, default=None, metavar="N",
                   help="timed rounds of each method's calibration (default "
                   f"{ROUNDS}): the fastest counts")
    tune_plans.add_arguments(p)
    p.add_argument("--out", required=True, metavar="FILE", help="tuned planner config (TOML)")
    p.add_argument("--format", choices=["text", "json"], default="text")


def planner_call() -> tuple[int, float]:
    """(trajectories, interval [s]) of one call of the planner's integrator with its default
    parameters: batch_nodes x (n_arc + n_random) shootings of one horizon each."""
    from stepzoo.search.planner_config import PlannerParams
    d = PlannerParams()
    return d.batch_nodes * (d.n_arc + d.n_random), float(d.horizon)


def tune(results, pos_tol, margin: float, out, tol=None, cost: str = "time",
         rounds: int | None = None, plans=None) -> dict:
    """Choose (method, h) from the sweep folder `results` (a position tolerance `pos_tol` [m]
    or a tolerance `tol` on the config's error norm, stability margin `margin`, a fraction),
    ranked by `cost` ("time", calibrated in the planner's call, or "evals"), and write it to
    the file `out`; returns the choice, chosen among the qualifying candidates by planning
    when `plans` (a tune_plans.Trial) is given. `stepzoo tune` and `stepzoo run` call it."""
    from stepzoo.bench.tune import tune as choose
    from stepzoo.bench.tune import write
    out = check_file_target(out)          # before the work, not only when writing
    if plans is not None:
        plans.check_sweep(results)
    batch, interval = planner_call()
    tuned = choose(results, pos_tol, margin, tol, batch=batch, interval_s=interval, cost=cost,
                   rounds=ROUNDS if rounds is None else rounds)
    if plans is not None:
        tuned = plans.choose(tuned, results)
    write(tuned, out)
    return tuned


def show(tuned: dict, out, fmt: str = "text") -> None:
    """Print the choice, its runners-up and where it was written, or JSON."""
    if fmt == "json":
        print(to_json({"out": str(out), **tuned}))
        return
    print(f"chose {tuned['method']} at h = {tuned['h']:g} s: {tuned['why']}")
    rows = [{"method": r["method"], "h": r.get("h"), "evals_per_s": r.get("cost_evals_per_s"),
             "time_per_s": r.get("cost_time_per_s"), "reason": r["reason"]}
            for r in tuned["runners_up"]]
    sys.stdout.write(text_table(rows, ["method", "h", "evals_per_s", "time_per_s", "reason"])
                     + "\n")
    tune_plans.show(tuned)
    print(f"wrote {out}")


def main(args) -> int:
    tuned = tune(args.results, args.pos_tol, args.margin, args.out, args.tol, args.cost,
                 args.rounds, tune_plans.trial(args))
    show(tuned, args.out, args.format)
    return 0
