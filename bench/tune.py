"""Tuning: from a sweep's tables, the cheapest (method, h) that keeps a safety margin below
the measured largest stable step and meets a position tolerance at every operating point of
the envelope. Cost is right-hand-side evaluations per simulated second (median over points); ties
go to the smaller worst-case error (measured time is noisy, so it is only a second view)."""
from __future__ import annotations

import json
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pandas as pd

from stepzoo.bench.sweep_folder import check_finished
from stepzoo.errors import NoAnswer, UsageError
from stepzoo.validate import check

# The stability margin: h <= (1 - margin) x the measured largest stable step. 0.2, not less:
# the limit is measured at the envelope's grid points only, and a step that close to it
# leaves |R(h lambda)| near 1, so a perturbation decays over hundreds of steps.
DEFAULT_MARGIN = 0.2


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


def candidates(runs: pd.DataFrame, limits: pd.DataFrame, pos_tol: float, margin: float):
    """One row per (method, h): worst position error over the points, whether every point is
    stable with the margin and within tolerance, and the two costs."""
    df = runs.merge(limits[["method", "point", "h_meas"]], on=["method", "point"])
    df["in_margin"] = df["stable"] & (df["h"] <= (1.0 - margin) * df["h_meas"])
    df["time_per_s"] = df["time_per_step_s"] / df["h"]
    g = df.groupby(["method", "h"])
    table = pd.DataFrame({
        "in_margin": g["in_margin"].all(),
        "err_pos": g["err_pos"].max(),
        "cost_evals_per_s": g["evals_per_s"].median(),
        "cost_time_per_s": g["time_per_s"].median(),
        "h_meas_min": g["h_meas"].min(),
        "points": g["point"].nunique(),
    }).reset_index()
    table["ok"] = table["in_margin"] & np.isfinite(table["err_pos"]) \
        & (table["err_pos"] <= pos_tol)
    return table


def check_arguments(pos_tol: float, margin: float):
    """UsageError unless the tolerance [m] and the margin (a fraction) are in range."""
    check("pos_tol", "--pos-tol", pos_tol), check("margin", "--margin", margin)


def tune(folder, pos_tol: float, margin: float) -> dict:
    """The tuned planner config as a dict (the TOML's content)."""
    check_arguments(pos_tol, margin)
    runs, limits, manifest = load_results(folder)
    table = candidates(runs, limits, pos_tol, margin)
    order = ["cost_evals_per_s", "err_pos", "method"]
    ok = table[table["ok"]].sort_values(order, kind="stable")
    if ok.empty:
        best = table[table["in_margin"]].sort_values("err_pos").head(1)
        hint = (f"the smallest worst-case error within the margin is "
                f"{best['err_pos'].iloc[0]:.3g} m ({best['method'].iloc[0]} at h = "
                f"{best['h'].iloc[0]:g} s)" if len(best) else "no step is within the margin")
        raise NoAnswer(f"no (method, h) of {folder} is stable with margin {margin:g} and "
                         f"within {pos_tol:g} m at every point: {hint}; loosen --pos-tol or "
                         "sweep smaller steps")
    per_method = ok.groupby("method", sort=False).head(1)      # each method's cheapest step
    choice = per_method.iloc[0]
    n_points = int(choice["points"])
    why = (f"{choice['method']} at h = {choice['h']:g} s is the cheapest step that stays "
           f"within {1 - margin:g} x the measured largest stable step and within {pos_tol:g} m "
           f"at all {n_points} operating points: {choice['cost_evals_per_s']:.4g} RHS "
           f"evaluations per simulated second, worst position error "
           f"{choice['err_pos']:.3g} m")
    runners = [_runner(r, choice) for _, r in per_method.iloc[1:].iterrows()]
    for name in sorted(set(table["method"]) - set(per_method["method"])):
        runners.append(_infeasible(table[table["method"] == name], name, pos_tol, margin))
    sweep_name = manifest.get("config_name", "sweep")
    return {
        "method": str(choice["method"]),
        "h": float(choice["h"]),
        "why": why,
        "pos_tol_m": float(pos_tol),
        "margin": float(margin),
        "cost_evals_per_s": float(choice["cost_evals_per_s"]),
        "cost_time_per_s": float(choice["cost_time_per_s"]),
        "err_pos_max_m": float(choice["err_pos"]),
        "h_meas_min_s": float(choice["h_meas_min"]),
        "horizon_s": float(manifest.get("horizon_s", float("nan"))),
        "sweep_config_sha256": manifest["config_sha256"],
        "provenance": (f"stepzoo tune {folder} --pos-tol {pos_tol:g} --margin {margin:g} at "
                       f"{datetime.now(timezone.utc).isoformat(timespec='seconds')}, from the "
                       f"sweep '{sweep_name}' created {manifest.get('created', '?')}"),
        "envelope": {"vx": [float(runs["vx"].min()), float(runs["vx"].max())],
                     "delta": [float(runs["delta"].min()), float(runs["delta"].max())],
                     "points": n_points},
        "runners_up": runners,
    }


def _runner(row, choice) -> dict:
    factor = row["cost_evals_per_s"] / choice["cost_evals_per_s"]
    return {"method": str(row["method"]), "h": float(row["h"]),
            "cost_evals_per_s": float(row["cost_evals_per_s"]),
            "cost_time_per_s": float(row["cost_time_per_s"]),
            "reason": (f"qualifies at h = {row['h']:g} s (worst error {row['err_pos']:.3g} m) "
                       f"but costs {factor:.3g} x the choice in RHS evaluations")}


def _infeasible(rows: pd.DataFrame, name: str, pos_tol: float, margin: float) -> dict:
    inside = rows[rows["in_margin"]]
    if inside.empty:
        reason = (f"every step tried is past {1 - margin:g} x its measured largest stable "
                  "step at some operating point")
    else:
        best = inside.loc[inside["err_pos"].idxmin()]
        reason = (f"no step qualifies: within the margin its smallest worst-case position "
                  f"error is {best['err_pos']:.3g} m (h = {best['h']:g} s) > {pos_tol:g} m")
    return {"method": name, "reason": reason}


def write(tuned: dict, out) -> Path:
    import tomli_w

    from stepzoo.output import atomic_write
    from stepzoo.results_folder import check_file_target
    check_file_target(out)
    header = ("# Planner config written by `stepzoo tune`: `method` and `h` [s] are what the "
              "planner reads.\n")
    return atomic_write(out, header + tomli_w.dumps(tuned))
