"""`stepzoo tune RESULTS --tol E | --pos-tol M --out tuned.toml`: the cheapest (method, h) of a
sweep that is stable with a margin and meets a tolerance everywhere, as a TOML config."""
import sys

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
    p.add_argument("--out", required=True, metavar="FILE", help="tuned planner config (TOML)")
    p.add_argument("--format", choices=["text", "json"], default="text")


def tune(results, pos_tol, margin: float, out, tol=None) -> dict:
    """Choose (method, h) from the sweep folder `results` (a position tolerance `pos_tol` [m]
    or a tolerance `tol` on the config's error norm, stability margin `margin`, a fraction)
    and write it to the file `out`; returns the choice. `stepzoo tune` and `stepzoo run`
    call it."""
    from stepzoo.bench.tune import tune as choose
    from stepzoo.bench.tune import write
    out = check_file_target(out)          # before the work, not only when writing
    tuned = choose(results, pos_tol, margin, tol)
    write(tuned, out)
    return tuned


def show(tuned: dict, out, fmt: str = "text") -> None:
    """Print the choice, its runners-up and where it was written, or JSON."""
    if fmt == "json":
        print(to_json({"out": str(out), **tuned}))
        return
    print(f"chose {tuned['method']} at h = {tuned['h']:g} s: {tuned['why']}")
    rows = [{"method": r["method"], "h": r.get("h"), "evals_per_s": r.get("cost_evals_per_s"),
             "reason": r["reason"]} for r in tuned["runners_up"]]
    sys.stdout.write(text_table(rows, ["method", "h", "evals_per_s", "reason"]) + "\n")
    print(f"wrote {out}")


def main(args) -> int:
    tuned = tune(args.results, args.pos_tol, args.margin, args.out, args.tol)
    show(tuned, args.out, args.format)
    return 0
