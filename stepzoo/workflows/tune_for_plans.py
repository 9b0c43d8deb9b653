"""`stepzoo tune SWEEP --for-plans QUERIES`: the tuned (method, h) chosen where the step is
spent. The sweep's qualifying candidates (tune's choice and its qualifying runners-up, each
method's cheapest qualifying step) plan the queries with plan-bench's engine; the smallest
median plan time among those at the best exact rate whose replays stay within --replay-tol of
their plans is written as tune writes it, with the evidence in a [plans] table."""
from __future__ import annotations

import hashlib
import sys
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

from stepzoo.errors import UsageError

if TYPE_CHECKING:
    from stepzoo.search.planner.config import PlannerConfig

FLAGS = ("--replay-tol", "--runs", "--seed", "--planner-config", "--max-hours")
# The car the planner plans with (search.planner.shooting): the dynamic bicycle.
PLANNER_MODEL = "dynamic5"


@dataclass(frozen=True)
class Trial:
    """What --for-plans plans: `queries` read from `path`, `runs` seeds from `seed`, at
    `vx` [m/s] with `config`'s planner parameters, a replay tolerance `tol_m` [m]."""
    path: str
    queries: list
    config: PlannerConfig
    tol_m: float
    tol_from: str
    runs: int
    seed: int
    vx: float
    progress: bool
    max_hours: float

    def check_sweep(self, results) -> None:
        """UsageError, before tuning, if the sweep folder `results` is not of the car the
        planner plans with: its (method, h) would be chosen for another model."""
        from stepzoo.bench.tune.cheapest import load_results
        model = load_results(results)[2].get("model")
        if model != PLANNER_MODEL:
            raise UsageError(f"--for-plans plans with the planner's car, the {PLANNER_MODEL} "
                             f"bicycle, but {results} is a sweep of {model!r}; give a sweep of "
                             f"model = \"{PLANNER_MODEL}\", or tune without --for-plans")

    def choose(self, tuned: dict, results) -> dict:
        """`tuned` (bench.tune's dict, from the sweep folder `results`) with the candidate
        that plans best as its choice, the others as runners-up, and the [plans] table."""
        from stepzoo.workflows.plan_bench import estimate
        from stepzoo.search.plan_bench.integrators import Integrator
        from stepzoo.search.plan_bench.engine import plan_all
        from stepzoo.search.plan_bench.choice import choose
        qualified = [r for r in tuned["runners_up"] if "h" in r and r.get("qualifies", True)]
        entries = [tuned, *qualified]
        estimate(len(self.queries), len(entries), self.runs, self.config, self.max_hours)
        integrators = [Integrator(e["method"], float(e["h"]), "tuned" if k == 0 else
                                  "runner-up") for k, e in enumerate(entries)]
        _, summaries = plan_all(self.queries, integrators, self.config, runs=self.runs,
                                seed=self.seed, vx=self.vx,
                                on_row=_show_progress if self.progress else None)
        won, evidence = choose(summaries, self.tol_m)
        return self._written(tuned, results, entries, won, evidence)

    def _written(self, tuned, results, entries, won, evidence) -> dict:
        column, worst = (("err_pos", "err_pos_max_m") if "pos_tol_m" in tuned
                         else ("err", "err_max"))
        new, old = entries[won], entries[0]
        out = dict(tuned)
        out.update({"method": new["method"], "h": float(new["h"]),
                    **{k: new[k] for k in ("cost_evals_per_s", "cost_time_per_s",
                                           "cost_time_spread_per_s") if k in new}})
        if won:                 # the sweep's numbers of a runner-up, as tune gives its choice
            row = _sweep_row(tuned, results, new, column)
            out.update({worst: float(row[column]), "h_meas_min_s": float(row["h_meas_min"]),
                        "h_pred_min_s": float(row["h_pred_min"]),
                        "h_over_h_pred_max": float(row["h_over_h_pred_max"])})
        label = evidence[won]["integrator"]
        out["why"] = (f"{new['method']} at h = {new['h']:g} s: planning {self.path} "
                      f"({len(self.queries)} queries x {self.runs} runs) it has "
                      f"{evidence[won]['verdict'].removeprefix('chosen: ')} (largest "
                      f"deviation {evidence[won]['max_replay_deviation_m']:.3g} m); by --cost "
                      f"{tuned.get('cost', 'time')} alone tune chose {old['method']} at h = "
                      f"{old['h']:g} s")
        order = sorted(range(len(entries)), key=lambda i: _rank(evidence[i]))
        out["runners_up"] = [_runner(entries[i], evidence[i]) for i in order if i != won] \
            + [r for r in tuned["runners_up"] if r not in entries]
        from stepzoo.search.planner.config import DEFAULT_CONFIG
        planner = ("" if self.config.source == str(DEFAULT_CONFIG)
                   else f" --planner-config {self.config.source}")
        # The planner settings the choice was measured with go with it: a planner reading
        # this file plans as the evidence did (its margin, its budgets).
        overrides = self.config.params.model_dump(exclude_defaults=True)
        if overrides:
            out["planner"] = overrides
        out["provenance"] = (f"{tuned['provenance']}; chosen for plans by --for-plans "
                             f"{self.path} --replay-tol {self.tol_m:g}{planner} --runs "
                             f"{self.runs} --seed {self.seed} at "
                             f"{datetime.now(timezone.utc).isoformat(timespec='seconds')}")
        out["plans"] = {
            "queries": self.path, "queries_sha256": _sha256(self.path),
            "queries_count": len(self.queries), "runs": self.runs, "seed": self.seed,
            "seeds": list(range(self.seed, self.seed + self.runs)), "speed_mps": self.vx,
            "replay_tol_m": self.tol_m, "replay_tol_from": self.tol_from,
            "chosen": label, "tune_choice": evidence[0]["integrator"],
            "why": evidence[won]["verdict"], "tune_why": tuned["why"],
            "planner": self.config.params.model_dump(),
            "candidates": [{k: v for k, v in e.items() if v is not None}
                           for e in (evidence[i] for i in order)]}
        return out


def trial(args) -> Trial | None:
    """The --for-plans work of the command's flags, its queries read and checked now, before
    the sweep is tuned; None without --for-plans. Every mistake is a UsageError."""
    from stepzoo.workflows.plan_bench import DEFAULT_MAX_HOURS, estimate
    from stepzoo.search.plan_bench.engine import load
    from stepzoo.search.planner.config import load_config
    from stepzoo.search.world.scenarios import DEFAULT_SPEED
    from stepzoo.validate import check
    given = [f for f in FLAGS if getattr(args, f[2:].replace("-", "_")) is not None]
    if args.for_plans is None:
        if given:
            raise UsageError(f"{', '.join(given)} only work with --for-plans QUERIES")
        return None
    if not Path(args.for_plans).is_file():
        raise UsageError(f"--for-plans {args.for_plans}: no such file; give a JSON list of "
                         "queries as `stepzoo plan-bench` reads "
                         "(search/world/queries/streets.json)")
    runs = 1 if args.runs is None else args.runs
    seed = 0 if args.seed is None else args.seed
    if runs < 1 or seed < 0:
        raise UsageError(f"--runs must be >= 1 and --seed >= 0, got {runs} and {seed}")
    config = load_config(args.planner_config)
    if args.replay_tol is None:
        tol, tol_from = config.params.margin, "the planner's collision margin, parameter margin"
    else:
        tol, tol_from = check("pos_tol", "--replay-tol", args.replay_tol), "--replay-tol"
    max_hours = DEFAULT_MAX_HOURS if args.max_hours is None else args.max_hours
    if not max_hours > 0:
        raise UsageError(f"--max-hours must be a number > 0, got {max_hours!r}")
    queries = load(args.for_plans, config, DEFAULT_SPEED)
    # The tune choice plans at least: refused now, before the sweep is tuned.
    estimate(len(queries), 1, runs, config, max_hours)
    return Trial(str(args.for_plans), queries, config, float(tol), tol_from, runs, seed,
                 DEFAULT_SPEED, bool(getattr(args, "progress", False)), max_hours)


def show(tuned: dict) -> None:
    """The [plans] evidence as a table, when the choice was made by planning."""
    from stepzoo.output import text_table
    plans = tuned.get("plans")
    if not plans:
        return
    columns = ["integrator", "exact_rate", "median_time_s", "max_replay_deviation_m",
               "replay_collisions", "verdict"]
    print(f"planned {plans['queries']} ({plans['queries_count']} queries x {plans['runs']} "
          f"runs), replay tolerance {plans['replay_tol_m']:g} m ({plans['replay_tol_from']}):")
    sys.stdout.write(text_table(plans["candidates"], columns) + "\n")


def _rank(e: dict) -> tuple:
    """Evidence rows in the order the rule prefers them: within the rule first, by time."""
    return (not e["within_tol"], -e["exact"], e["median_time_s"])


def _runner(entry: dict, evidence: dict) -> dict:
    keep = ("method", "h", "qualifies", "cost_evals_per_s", "cost_time_per_s",
            "cost_time_spread_per_s")
    return {**{k: entry[k] for k in keep if k in entry}, "qualifies": True,
            "reason": f"qualifies at h = {entry['h']:g} s but in the plans: "
                      f"{evidence['verdict']}"}


def _sweep_row(tuned: dict, results, entry: dict, column: str):
    """The sweep's row of candidate `entry` (worst error, smallest measured and predicted
    stable steps)."""
    from stepzoo.bench.tune.cheapest import candidates, load_results
    runs, limits, _ = load_results(results)
    tol = tuned.get("pos_tol_m", tuned.get("tol"))
    table = candidates(runs, limits, tol, tuned["margin"], column,
                       tuned.get("allow_beyond_predicted_limit", False))
    return table[(table["method"] == entry["method"]) & (table["h"] == entry["h"])].iloc[0]


def _sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _show_progress(done: int, total: int, row: dict) -> None:
    sys.stderr.write(f"stepzoo tune: plan [{done}/{total}] {row['integrator']} {row['query']} "
                     f"run {row['run']}: {row['status']} in {row['time_s']:.2f} s\n")
