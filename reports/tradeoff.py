"""The paper's trade-off from a plan-bench folder: median plan time against replay deviation,
a point per integrator, its exact rate as the marker's size, the tuned choice and the paper's
RK4 marked and the Pareto front drawn. `tradeoff_points` computes the data from the folder's
summary table and `tradeoff` makes it the figure's record, which both renderers draw."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from stepzoo.errors import UsageError
from stepzoo.reports.figure_types import Tradeoff

NUMBER = 8
PAPER_METHOD = "rk4"           # the paper plans with the classical Runge-Kutta method
TITLE = "Plan time against replay deviation"

# The columns of plan-bench's summary.csv this figure reads.
SUMMARY_COLUMNS = ["integrator", "method", "h", "median_time_s", "median_replay_deviation_m",
                   "max_replay_deviation_m", "exact_rate", "role"]


def load_bench_summary(folder) -> pd.DataFrame:
    """The summary per integrator of a `stepzoo plan-bench` folder (summary.parquet), with
    the planner's collision margin [m] from its manifest in `attrs["margin_m"]` (None if
    not recorded)."""
    from stepzoo.safe_parse import json_loads
    path = Path(folder) / "summary.parquet"
    if not path.is_file():
        raise UsageError(f"--plan-bench {folder} holds no summary.parquet; give a folder "
                         "written by `stepzoo plan-bench`")
    try:
        summary = pd.read_parquet(path)
    except OSError:
        raise                     # unreadable, not damaged: the command says which
    except Exception as err:      # damaged bytes raise many types from pyarrow
        raise UsageError(f"--plan-bench {folder}: summary.parquet is damaged "
                         f"({type(err).__name__}); rerun `stepzoo plan-bench`") from None
    missing = [c for c in SUMMARY_COLUMNS if c not in summary]
    if missing:
        raise UsageError(f"--plan-bench {folder}: summary.parquet lacks {', '.join(missing)}; "
                         "give a folder written by `stepzoo plan-bench --integrator ...`")
    try:
        manifest = json_loads((Path(folder) / "manifest.json").read_text())
        summary.attrs["margin_m"] = float(manifest["settings"]["params"]["margin"])
    except (OSError, ValueError, KeyError, TypeError):
        summary.attrs["margin_m"] = None
    return summary


def pareto(x, y) -> np.ndarray:
    """Whether each point (x_i, y_i) is on the front of the smallest x and y: no other point
    is at most as large in both and smaller in one. NaN points are never on it."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    out = np.zeros(len(x), bool)
    for i in np.flatnonzero(ok):
        beaten = ok & (x <= x[i]) & (y <= y[i]) & ((x < x[i]) | (y < y[i]))
        out[i] = not beaten.any()
    return out


def tradeoff_points(summary: pd.DataFrame, tuned: dict | None = None) -> pd.DataFrame:
    """A row per integrator: integrator, method, h [s], median_time_s, the median and largest
    replay deviation [m] of its exact plans, exact_rate, and whether it is the tuned choice
    (the bench's role "tuned", or the (method, h) of `tuned`, a tuned TOML's table), the
    paper's method, and on the Pareto front of (deviation, time). `attrs["margin_m"]`: the
    planner's collision margin, as the summary's."""
    out = summary[SUMMARY_COLUMNS].copy()
    out["tuned"] = out["role"] == "tuned"
    if tuned:
        out["tuned"] |= (out["method"] == tuned["method"]) & np.isclose(out["h"],
                                                                         float(tuned["h"]))
    out["paper"] = out["method"] == PAPER_METHOD
    out["pareto"] = pareto(out["median_replay_deviation_m"], out["median_time_s"])
    out = out.reset_index(drop=True)
    out.attrs["margin_m"] = summary.attrs.get("margin_m")
    return out


def _caption(points: pd.DataFrame) -> str:
    front = points[points["pareto"]].sort_values("median_replay_deviation_m")
    return ("Each integrator of a plan-bench (the same queries and seeds for each): median "
            "plan time against the median replay deviation of its exact plans (the planned "
            "path against the same controls driven through the true models by a tight "
            "reference; the thin line reaches the largest), the marker's area its exact "
            "rate. The dashed line is the Pareto front, the integrators no other beats in "
            "both time and deviation: " + ", ".join(front["integrator"]) + ". The tuned "
            "choice is ringed black; the paper's method (RK4) is a square"
            + ("; the dotted line is the planner's collision margin, the inflation of the "
               "footprint that a deviation beyond it may eat through."
               if points.attrs.get("margin_m") else "."))


def tradeoff(points: pd.DataFrame, number: int = NUMBER) -> Tradeoff:
    """Figure `number`'s data: the points with both medians (an integrator with no exact
    plan has no deviation to draw)."""
    drawn = points.dropna(subset=["median_replay_deviation_m", "median_time_s"])

    def col(c, kind=float):
        return drawn[c].to_numpy(kind)
    return Tradeoff(number, TITLE, _caption(points), f"fig{number}_plan_tradeoff.png",
                    [str(v) for v in drawn["integrator"]], [str(v) for v in drawn["role"]],
                    col("median_time_s"), col("median_replay_deviation_m"),
                    col("max_replay_deviation_m"), col("exact_rate"), col("tuned", bool),
                    col("paper", bool), col("pareto", bool), points.attrs.get("margin_m"))
