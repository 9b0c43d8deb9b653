"""Tuning: from a sweep's tables, the cheapest (method, h) that keeps a safety margin below
the smaller of the predicted and measured largest stable steps (bench/tune/margin.py) and meets a
tolerance at every operating point of the envelope: on the position error of a vehicle model,
or on the config's error norm of any. Where the fastest mode bounds explicit steps far below
what accuracy needs, the answer says the model is stiff and which mode (bench/model/stiffness.py).

Cost is measured time per simulated second (`time`, the default): each qualifying method's
time per step, calibrated where the planner spends it (bench/timing/calibrate.py), times its steps
per second; candidates whose times differ by less than the calibration's spread (at most
TIE_MAX) are a tie that the fewer right-hand-side evaluations win. `evals` ranks by
evaluations per simulated second (median over points), ties to the smaller worst error."""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd

from stepzoo.bench.timing.calibrate import PLANNER_BATCH, PLANNER_INTERVAL_S, ROUNDS, calibrate
from stepzoo.bench.model import stiffness
from stepzoo.bench.tune.margin import BEYOND_PREDICTED, beyond, limit, stable_with_margin
from stepzoo.bench.sweep.folder import check_columns, check_finished
from stepzoo.errors import NoAnswer, UsageError
from stepzoo.validate import check

COSTS = ("time", "evals")
# The largest time difference, as a fraction of the fastest candidate's, that may count as a
# tie: beyond it time decides, however noisy the calibration, so the choice is never slower
# than the fastest qualifying candidate by more than this.
TIE_MAX = 0.1


def load_results(folder) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """(runs, limits, manifest) of a finished sweep folder; UsageError if it is not one."""
    folder = Path(folder)
    files = ["manifest.json", "runs.parquet", "limits.parquet"]
    missing = [f for f in files if not (folder / f).is_file()]
    if missing:
        raise UsageError(f"{folder} is not a finished sweep folder (lacks {', '.join(missing)});"
                         f" run `stepzoo sweep CONFIG --out {folder}` first")
    try:
        manifest = json.loads((folder / "manifest.json").read_text())
        runs = pd.read_parquet(folder / "runs.parquet")
        limits = pd.read_parquet(folder / "limits.parquet")
    except OSError:
        raise                     # unreadable, not damaged: the command says which
    except Exception as err:  # damaged bytes raise many types from pyarrow and json
        raise UsageError(f"{folder}: a result file is damaged ({type(err).__name__}); rerun "
                         "`stepzoo sweep`") from None
    check_finished(folder, manifest, runs, limits)
    return runs, limits, manifest


def check_error_column(folder, runs: pd.DataFrame, manifest: dict, column: str):
    """UsageError unless `runs` of the sweep `folder` has the error `column` a tolerance
    bounds: err_pos exists for vehicle models only, err for every model since models are
    data."""
    if column in runs:
        return
    if column == "err_pos" and not (manifest.get("model_spec") or {}).get("vehicle", True):
        raise UsageError(f"{folder} has no {column} column: its model has no position (X, Y); "
                         "tune it with --tol E, the config's error norm")
    check_columns(folder, {"runs.parquet": runs}, {"runs.parquet": [column]})


@dataclass(frozen=True)
class Criterion:
    """What the tolerance bounds: the worst position error [m] (--pos-tol, vehicle models)
    or the config's error norm, the largest error state over its scale (--tol, any model)."""
    column: str
    tol: float
    flag: str
    unit: str
    what: str

    def show(self, value) -> str:
        return f"{value:.3g}{' ' + self.unit if self.unit else ''}"


def criterion(pos_tol=None, tol=None) -> Criterion:
    """The criterion of the command's flags: exactly one of --pos-tol and --tol."""
    if (pos_tol is None) == (tol is None):
        raise UsageError("give one tolerance: --tol E (the config's error norm, any model) or "
                         "--pos-tol M (position error, vehicle models)")
    if pos_tol is not None:
        return Criterion("err_pos", check("pos_tol", "--pos-tol", pos_tol), "--pos-tol", "m",
                         "position error")
    return Criterion("err", check("tol", "--tol", tol), "--tol", "", "error (error states "
                     "over their scales)")


def candidates(runs: pd.DataFrame, limits: pd.DataFrame, tol, margin: float,
               column: str = "err_pos", beyond_predicted: bool = False):
    """One row per (method, h): worst error (`column`) over the points, whether every point
    is stable with the margin (below the smaller of h_pred and h_meas; below h_meas alone
    with `beyond_predicted`) and within the tolerance, whether some point is beyond its
    predicted limit (and by how much at most), and the two costs."""
    df = runs.merge(limits[["method", "point", "h_meas", "h_pred"]], on=["method", "point"])
    df["in_margin"] = stable_with_margin(df["stable"], df["h"], df["h_meas"], margin,
                                         df["h_pred"], beyond_predicted)
    df["h_limit"] = limit(df["h_meas"], df["h_pred"])
    df["beyond_predicted"] = beyond(df["h"], df["h_pred"])
    with np.errstate(divide="ignore", invalid="ignore"):
        df["h_over_h_pred"] = df["h"] / df["h_pred"]
    df["time_per_s"] = df["time_per_step_s"] / df["h"]
    g = df.groupby(["method", "h"])
    table = pd.DataFrame({
        "in_margin": g["in_margin"].all(),
        column: g[column].max(),
        "cost_evals_per_s": g["evals_per_s"].median(),
        "cost_time_per_s": g["time_per_s"].median(),
        "h_meas_min": g["h_meas"].min(),
        "h_pred_min": g["h_pred"].min(),
        "h_limit_min": g["h_limit"].min(),
        "beyond_predicted": g["beyond_predicted"].any(),
        "h_over_h_pred_max": g["h_over_h_pred"].max(),
        "stable_all": g["stable"].all(),
        "points": g["point"].nunique(),
    }).reset_index()
    table["ok"] = table["in_margin"] & np.isfinite(table[column]) & (table[column] <= tol)
    return table


def check_arguments(pos_tol, margin: float, tol=None, cost: str = "time",
                    rounds: int = ROUNDS) -> Criterion:
    """The criterion, or UsageError unless the tolerance, the margin, the cost and the
    calibration's rounds are in range."""
    crit = criterion(pos_tol, tol)
    check("margin", "--margin", margin)
    if cost not in COSTS:
        raise UsageError(f"--cost must be one of {', '.join(COSTS)}, got {cost!r}")
    check("rounds", "--rounds", rounds)
    return crit


def tune(folder, pos_tol, margin: float, tol=None, *, batch: int = PLANNER_BATCH,
         interval_s: float = PLANNER_INTERVAL_S, cost: str = "time",
         rounds: int = ROUNDS, beyond_predicted: bool = False) -> dict:
    """The tuned config as a dict (the TOML's content): under --pos-tol (pos_tol [m]) or
    --tol (tol, in the sweep's error norm), ranked by `cost` ("time" or "evals"). Each
    qualifying method is calibrated at its largest qualifying step in calls of `batch`
    trajectories over `interval_s` [s] (default: the planner's default call), `rounds`
    rounds: both costs are recorded whichever ranks. A step qualifies at or below (1 -
    margin) x the smaller of its predicted and measured limits at every point; the measured
    one alone with `beyond_predicted` (--allow-beyond-predicted-limit)."""
    crit = check_arguments(pos_tol, margin, tol, cost, rounds)
    runs, limits, manifest = load_results(folder)
    col = crit.column
    check_error_column(folder, runs, manifest, col)
    table = candidates(runs, limits, crit.tol, margin, col, beyond_predicted)
    cfg = _config(folder)
    variables = (manifest.get("model_spec") or {}).get("variables", ["vx", "delta"])
    stiff = stiffness.of_sweep(runs, limits, col, crit.tol, cfg, variables)
    ok = table[table["ok"]].copy()
    if ok.empty:
        best = table[table["in_margin"]].sort_values(col).head(1)
        hint = (f"the smallest worst-case error within the margin is "
                f"{crit.show(best[col].iloc[0])} ({best['method'].iloc[0]} at h = "
                f"{best['h'].iloc[0]:g} s)" if len(best) else "no step is within the margin")
        raise NoAnswer(f"no (method, h) of {folder} is stable with margin {margin:g} and "
                       f"within {crit.show(crit.tol)} at every point: {hint}; loosen "
                       f"{crit.flag} or sweep smaller steps ({stiff['says']})")
    cal = _calibrate(cfg, ok, batch, interval_s, rounds)
    ok["cost_time_per_s"] = [cal[m].per_sim_s(h) for m, h in zip(ok["method"], ok["h"])]
    ok["cost_time_spread_per_s"] = ok["method"].map(lambda m: cal[m].spread_s) / ok["h"]
    ok["spread"] = ok["method"].map(lambda m: cal[m].spread)
    ranked, fastest = _rank(ok, cost, col)
    per_method = ranked.groupby("method", sort=False).head(1)  # each method's cheapest step
    choice = per_method.iloc[0]
    n_points = int(choice["points"])
    why = (f"{choice['method']} at h = {choice['h']:g} s is the "
           f"{'fastest (within the measured spread)' if cost == 'time' else 'cheapest'} step "
           "that stays within "
           f"{1 - margin:g} x {_limit_words(beyond_predicted)} and within "
           f"{crit.show(crit.tol)} at all {n_points} operating points: "
           + (f"{choice['cost_time_per_s']:.3g} s of wall time per simulated second in the "
              f"planner's call ({batch} trajectories of {interval_s:g} s, the fastest of "
              f"{rounds} rounds), {choice['cost_evals_per_s']:.4g} RHS evaluations"
              if cost == "time" else
              f"{choice['cost_evals_per_s']:.4g} RHS evaluations per simulated second")
           + f", worst {crit.what} {crit.show(choice[col])}")
    if cost == "time" and fastest != choice.name:
        f = ranked.loc[fastest]
        why += (f"; {f['method']} at h = {f['h']:g} s is {f['cost_time_per_s']:.3g} s, "
                f"faster by less than the calibration's spread, with "
                f"{_tie_loss(f, choice, col)}")
    if choice["beyond_predicted"]:
        why += (f"; it is {choice['h_over_h_pred_max']:.3g} x its predicted limit at some "
                f"point, allowed by {BEYOND_PREDICTED} only")
    if stiff["stiff"]:
        why += (f"; {stiff['says']}; implicit and Rosenbrock methods are ranked with the "
                "explicit ones by measured time")
    runners = [_runner(r, choice, crit, cost) for _, r in per_method.iloc[1:].iterrows()]
    for name in sorted(set(table["method"]) - set(per_method["method"])):
        runners.append(_infeasible(table[table["method"] == name], name, crit, margin,
                                   beyond_predicted))
    sweep_name = manifest.get("config_name", "sweep")
    limit = {"pos_tol_m": float(crit.tol)} if col == "err_pos" else {"tol": float(crit.tol)}
    worst = {"err_pos_max_m" if col == "err_pos" else "err_max": float(choice[col])}
    return {
        "method": str(choice["method"]),
        "h": float(choice["h"]),
        "why": why,
        **limit,
        "margin": float(margin),
        "cost": cost,
        "cost_evals_per_s": float(choice["cost_evals_per_s"]),
        "cost_time_per_s": float(choice["cost_time_per_s"]),
        "cost_time_spread_per_s": float(choice["cost_time_spread_per_s"]),
        **worst,
        "h_meas_min_s": float(choice["h_meas_min"]),
        "h_pred_min_s": float(choice["h_pred_min"]),
        "h_over_h_pred_max": float(choice["h_over_h_pred_max"]),
        "allow_beyond_predicted_limit": bool(beyond_predicted),
        "stiff": stiff["stiff"],
        "stiffness": _toml_safe(stiff),
        "horizon_s": float(manifest.get("horizon_s", float("nan"))),
        "model": str(manifest.get("model", "dynamic5")),
        "sweep_config_sha256": manifest["config_sha256"],
        "sweep": str(Path(folder).resolve()),
        "sweep_created": str(manifest.get("created", "?")),
        "provenance": (f"stepzoo tune {folder} {crit.flag} {crit.tol:g} --margin {margin:g} "
                       f"--cost {cost}{' ' + BEYOND_PREDICTED if beyond_predicted else ''} at "
                       f"{datetime.now(timezone.utc).isoformat(timespec='seconds')}, from "
                       f"the sweep '{sweep_name}' created {manifest.get('created', '?')}"),
        "envelope": {**{v: [float(runs[v].min()), float(runs[v].max())] for v in variables
                        if v in runs}, "points": n_points},
        "calibration": _calibration_record(cal, batch, interval_s, rounds),
        "runners_up": runners,
    }


def _config(folder):
    """The sweep's own config (its copy in the folder)."""
    from stepzoo.bench.sweep.config import load
    return load(Path(folder) / "config.toml")


def _limit_words(beyond_predicted: bool) -> str:
    return ("the measured largest stable step (the predicted one ignored: "
            f"{BEYOND_PREDICTED})" if beyond_predicted else
            "the smaller of the predicted and measured largest stable steps")


def _toml_safe(record: dict) -> dict:
    """A record for TOML, which has no null: None and NaN keys left out, nested alike."""
    out = {}
    for k, v in record.items():
        if isinstance(v, dict):
            v = _toml_safe(v)
        if v is None or (isinstance(v, float) and math.isnan(v)):
            continue
        out[k] = v
    return out


def _calibrate(cfg, ok: pd.DataFrame, batch: int, interval_s: float, rounds: int) -> dict:
    """Each qualifying method's Calibration at its largest qualifying step (its cheapest in
    time, the per-step time being the method's), on the sweep's own model and envelope."""
    steps = ok.groupby("method", sort=True)["h"].max()
    return calibrate({str(m): float(h) for m, h in steps.items()}, cfg.spec, batch,
                     interval_s, rounds, resolve=cfg.method)


def _rank(ok: pd.DataFrame, cost: str, col: str) -> tuple[pd.DataFrame, object]:
    """The qualifying rows, the chosen first, then by cost; and the fastest row's label.
    By time: every row slower than the fastest by less than the larger of the two methods'
    spreads (at most TIE_MAX) ties with it, and the tie goes to the fewest evaluations, then
    to the smaller worst error."""
    if cost == "evals":
        ranked = ok.sort_values(["cost_evals_per_s", col, "method"], kind="stable")
        return ranked, None
    by_time = ok.sort_values(["cost_time_per_s", "cost_evals_per_s", col, "method"],
                             kind="stable")
    fastest = by_time.iloc[0]
    window = np.minimum(np.maximum(by_time["spread"], fastest["spread"]), TIE_MAX)
    tied = by_time[by_time["cost_time_per_s"] <= fastest["cost_time_per_s"] * (1 + window)]
    # Equal evaluations too: the smaller worst error, which no noise can flip.
    chosen = tied.sort_values(["cost_evals_per_s", col, "cost_time_per_s", "method"],
                              kind="stable").index[0]
    order = [chosen] + [i for i in by_time.index if i != chosen]
    return by_time.loc[order], by_time.index[0]


def _calibration_record(cal: dict, batch: int, interval_s: float, rounds: int) -> dict:
    return {"batch": batch, "interval_s": float(interval_s), "rounds": rounds,
            "tie_max": TIE_MAX, "xla_flags": os.environ.get("XLA_FLAGS", ""),
            "methods": {m: {"h": c.h, "n_steps": c.n_steps, "per_step_s": c.per_step_s,
                            "spread_s": c.spread_s} for m, c in sorted(cal.items())}}


def _runner(row, choice, crit, cost: str) -> dict:
    key, what = (("cost_time_per_s", "time") if cost == "time"
                 else ("cost_evals_per_s", "RHS evaluations"))
    factor = row[key] / choice[key]
    if cost == "time" and factor <= 1:      # a tie within the spread that the choice won
        lost = (f"is {factor:.3g} x the choice in time, a tie within the calibration's "
                f"spread, with {_tie_loss(row, choice, crit.column)}")
    else:
        lost = f"costs {factor:.3g} x the choice in {what}"
    return {"method": str(row["method"]), "h": float(row["h"]), "qualifies": True,
            "cost_evals_per_s": float(row["cost_evals_per_s"]),
            "cost_time_per_s": float(row["cost_time_per_s"]),
            "cost_time_spread_per_s": float(row["cost_time_spread_per_s"]),
            "reason": (f"qualifies at h = {row['h']:g} s (worst error "
                       f"{crit.show(row[crit.column])}) but {lost}")}


def _tie_loss(row, choice, col: str) -> str:
    """Why `row` lost a time tie to `choice`."""
    if row["cost_evals_per_s"] > choice["cost_evals_per_s"]:
        return "more RHS evaluations"
    return "as many RHS evaluations and a larger worst error"


def _infeasible(rows: pd.DataFrame, name: str, crit, margin: float,
                beyond_predicted: bool = False) -> dict:
    inside = rows[rows["in_margin"]]
    if inside.empty:
        reason = (f"every step tried is past {1 - margin:g} x "
                  f"{_limit_words(beyond_predicted)} at some operating point")
    else:
        best = inside.loc[inside[crit.column].idxmin()]
        reason = (f"no step qualifies: within the margin its smallest worst-case {crit.what} "
                  f"is {crit.show(best[crit.column])} (h = {best['h']:g} s) > "
                  f"{crit.show(crit.tol)}")
    return {"method": name, "qualifies": False, "reason": reason}


def write(tuned: dict, out) -> Path:
    import tomli_w

    from stepzoo.output import atomic_write
    from stepzoo.results_folder import TUNED_FILE, check_file_target
    check_file_target(out, kind=TUNED_FILE)
    header = ("# Planner config written by `stepzoo tune`: `method` and `h` [s] are what the "
              "planner reads.\n")
    return atomic_write(out, header + tomli_w.dumps(tuned))
