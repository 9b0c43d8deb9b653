"""Tune as the commands run it: the cheapest (method, h) of a sweep folder, priced in the
planner's own call, optionally chosen by planning, written as a tuned config and printed."""
import sys

from stepzoo.workflows import tune_for_plans as tune_plans
from stepzoo.bench.timing.calibrate import ROUNDS
from stepzoo.output import text_table, to_json
from stepzoo.results_folder import TUNED_FILE, check_file_target


def planner_call() -> tuple[int, float]:
    """(trajectories, interval [s]) of one call of the planner's integrator with its default
    parameters: batch_nodes x (n_arc + n_random) shootings of one horizon each."""
    from stepzoo.search.planner.config import PlannerParams
    d = PlannerParams()
    return d.batch_nodes * (d.n_arc + d.n_random), float(d.horizon)


def tune(results, pos_tol, margin: float, out, tol=None, cost: str = "time",
         rounds: int | None = None, plans=None, beyond_predicted: bool = False) -> dict:
    """Choose (method, h) from the sweep folder `results` (a position tolerance `pos_tol` [m]
    or a tolerance `tol` on the config's error norm, stability margin `margin`, a fraction),
    ranked by `cost` ("time", calibrated in the planner's call, or "evals"), and write it to
    the file `out`; returns the choice, chosen among the qualifying candidates by planning
    when `plans` (a tune_plans.Trial) is given; `beyond_predicted` drops the predicted limit
    from the margin rule (--allow-beyond-predicted-limit). `stepzoo tune` and `stepzoo run`
    call it."""
    from stepzoo.bench.tune.cheapest import tune as choose
    from stepzoo.bench.tune.cheapest import write
    out = check_file_target(out, kind=TUNED_FILE)     # before the work, not only when writing
    if plans is not None:
        plans.check_sweep(results)
    batch, interval = planner_call()
    tuned = choose(results, pos_tol, margin, tol, batch=batch, interval_s=interval, cost=cost,
                   rounds=ROUNDS if rounds is None else rounds,
                   beyond_predicted=beyond_predicted)
    if plans is not None:
        tuned = plans.choose(tuned, results)
    write(tuned, out)
    return tuned


def kept(out, results, pos_tol: float, margin: float) -> dict | None:
    """The tuned config in the file `out` where `stepzoo tune` wrote it from this finished
    sweep folder `results` (its path, its config's sha256 and its creation time) with this
    position tolerance `pos_tol` [m], stability margin and the default cost: how `stepzoo
    run` keeps its choice when run again, as it keeps its sweep and plans, so that a
    resumed run does not choose again by a new timing (a near tie can then change the
    choice and with it every plan). None where anything differs or cannot be read."""
    import json
    import tomllib
    from pathlib import Path
    try:
        tuned = tomllib.loads(Path(out).read_text())
        manifest = json.loads((Path(results) / "manifest.json").read_text())
        same = (tuned["sweep"] == str(Path(results).resolve())
                and tuned["sweep_config_sha256"] == manifest["config_sha256"]
                and tuned["sweep_created"] == str(manifest.get("created", "?"))
                and (tuned.get("pos_tol_m"), tuned["margin"]) == (pos_tol, margin)
                and tuned["cost"] == "time" and not tuned["allow_beyond_predicted_limit"]
                and "plans" not in tuned)
        return tuned if same else None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def show(tuned: dict, out, fmt: str = "text") -> None:
    """Print the choice, its runners-up and where it was written, or JSON."""
    if fmt == "json":
        from stepzoo.bench.sweep.engine import _finite
        # JSON has neither inf nor NaN (an A-stable choice's limits are inf): null.
        print(to_json(_finite({"out": str(out), **tuned})))
        return
    print(f"chose {tuned['method']} at h = {tuned['h']:g} s: {tuned['why']}")
    if not tuned["stiff"]:          # a stiff finding is in `why` already
        print(tuned["stiffness"]["says"])
    rows = [{"method": r["method"], "h": r.get("h"), "evals_per_s": r.get("cost_evals_per_s"),
             "time_per_s": r.get("cost_time_per_s"), "reason": r["reason"]}
            for r in tuned["runners_up"]]
    sys.stdout.write(text_table(rows, ["method", "h", "evals_per_s", "time_per_s", "reason"])
                     + "\n")
    tune_plans.show(tuned)
    print(f"wrote {out}")
