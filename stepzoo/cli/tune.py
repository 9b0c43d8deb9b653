"""`stepzoo tune RESULTS --tol E | --pos-tol M --out tuned.toml`: the cheapest (method, h) of a
sweep that is stable with a margin and meets a tolerance everywhere, as a TOML config; cheapest
in time measured in the planner's own call (--cost time), or in RHS evaluations."""

from stepzoo.workflows import tune_for_plans as tune_plans
from stepzoo.bench.timing.calibrate import ROUNDS
from stepzoo.validate import DEFAULT_MARGIN
from stepzoo.workflows.tune import show, tune


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
    p.add_argument("--allow-beyond-predicted-limit", action="store_true",
                   help="risky: let a step qualify above its predicted (frozen-Jacobian) "
                   "largest stable step where the measurement saw no instability; by default "
                   "h <= (1 - margin) x the smaller of the predicted and measured limits")
    _for_plans_arguments(p)
    p.add_argument("--out", required=True, metavar="FILE", help="tuned planner config (TOML)")
    p.add_argument("--format", choices=["text", "json"], default="text")


def main(args) -> int:
    tuned = tune(args.results, args.pos_tol, args.margin, args.out, args.tol, args.cost,
                 args.rounds, tune_plans.trial(args), args.allow_beyond_predicted_limit)
    show(tuned, args.out, args.format)
    return 0


def _for_plans_arguments(p):
    p.add_argument("--for-plans", metavar="QUERIES", help="choose among the qualifying "
                   "candidates by planning this query file (as `stepzoo plan-bench` reads it) "
                   "with each: the smallest median plan time at the best exact rate whose "
                   "replays stay within --replay-tol of their plans; evidence in [plans]")
    p.add_argument("--replay-tol", type=float, metavar="M", help="with --for-plans: largest "
                   "replay deviation allowed on an exact plan [m] (default: the planner's "
                   "collision margin, planner parameter margin)")
    p.add_argument("--planner-config", metavar="FILE", help="with --for-plans: the planner "
                   "config whose [planner] table (budget, margin) the candidates plan with "
                   "(default: the shipped search/planner/tuned_default.toml)")
    p.add_argument("--runs", type=int, metavar="N",
                   help="with --for-plans: runs per query, seeds SEED.. (default 1)")
    p.add_argument("--seed", type=int, metavar="SEED",
                   help="with --for-plans: seed of the first run (default 0)")
    p.add_argument("--max-hours", type=float, metavar="H", help="with --for-plans: refuse "
                   "planning that could take longer, as `stepzoo plan-bench` does (default "
                   "24)")
