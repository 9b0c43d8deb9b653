"""The paper's trade-off from a plan-bench folder: median plan time against replay deviation,
a point per integrator, its exact rate as the marker's size, the tuned choice and the paper's
RK4 marked and the Pareto front drawn. `tradeoff_points` computes the data from the folder's
summary table; `tradeoff_png` and `tradeoff_plot` draw it (static and interactive)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from stepzoo.errors import UsageError
from stepzoo.reports.figures import Shown, _save
from stepzoo.reports.interactive import _layout

NUMBER = 8
PAPER_METHOD = "rk4"           # the paper plans with the classical Runge-Kutta method
SIZE_PT2 = 300.0               # [pt^2] marker area of an exact rate of 1
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


def tradeoff_png(points: pd.DataFrame, out_dir: Path, number: int = NUMBER) -> Shown:
    """Figure `number` as a PNG in `out_dir`."""
    fig = Figure(figsize=(8.0, 5.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    drawn = points.dropna(subset=["median_replay_deviation_m", "median_time_s"])
    for k, row in enumerate(drawn.itertuples()):
        colour = f"C{k % 10}"
        ax.plot([row.median_replay_deviation_m, row.max_replay_deviation_m],
                [row.median_time_s] * 2, color=colour, lw=0.8, alpha=0.6)
        ax.scatter(row.median_replay_deviation_m, row.median_time_s,
                   s=SIZE_PT2 * row.exact_rate, color=colour, alpha=0.8,
                   marker="s" if row.paper else "o",
                   edgecolors="black" if row.tuned else "none", linewidths=2.0)
        ax.annotate(row.integrator, (row.median_replay_deviation_m, row.median_time_s),
                    xytext=(6, 6), textcoords="offset points", fontsize=8)
    front = drawn[drawn["pareto"]].sort_values("median_replay_deviation_m")
    ax.plot(front["median_replay_deviation_m"], front["median_time_s"], "k--", lw=1.0)
    margin = points.attrs.get("margin_m")
    if margin:
        ax.axvline(margin, color="black", ls=":", lw=1.0)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("median replay deviation of the exact plans [m] (line: to the largest)")
    ax.set_ylabel("median plan time [s]")
    ax.grid(True, which="major", lw=0.3)
    handles = [Line2D([], [], marker="o", color="grey", ls="", mec="black", mew=2, ms=10),
               Line2D([], [], marker="s", color="grey", ls="", ms=10),
               Line2D([], [], color="black", ls="--")]
    labels = ["tuned choice", "the paper's RK4", "Pareto front"]
    if margin:
        handles.append(Line2D([], [], color="black", ls=":"))
        labels.append(f"the planner's margin {margin:g} m")
    ax.legend(handles, labels, fontsize=8, loc="best")
    name = _save(fig, out_dir, f"fig{number}_plan_tradeoff.png")
    return Shown(number, TITLE, _caption(points), [(name, "")])


def tradeoff_plot(points: pd.DataFrame) -> list:
    """The same figure in Plotly: hover for each integrator's numbers."""
    drawn = points.dropna(subset=["median_replay_deviation_m", "median_time_s"])
    fig = go.Figure()
    for row in drawn.itertuples():
        fig.add_trace(go.Scatter(
            x=[row.median_replay_deviation_m], y=[row.median_time_s], mode="markers+text",
            name=row.integrator, text=[row.integrator], textposition="top right",
            marker=dict(size=8 + 22 * row.exact_rate, symbol="square" if row.paper else
                        "circle", line=dict(width=3 if row.tuned else 0, color="black")),
            error_x=dict(type="data", symmetric=False, array=[row.max_replay_deviation_m
                                                              - row.median_replay_deviation_m],
                         arrayminus=[0.0], thickness=1),
            hovertemplate=(f"{row.integrator} ({row.role})<br>median plan time %{{y:.3g}} s"
                           f"<br>replay deviation median %{{x:.3g}} m, largest "
                           f"{row.max_replay_deviation_m:.3g} m<br>exact rate "
                           f"{row.exact_rate:.3g}<extra></extra>")))
    front = drawn[drawn["pareto"]].sort_values("median_replay_deviation_m")
    fig.add_trace(go.Scatter(x=front["median_replay_deviation_m"], y=front["median_time_s"],
                             mode="lines", name="Pareto front",
                             line=dict(color="black", dash="dash", width=1)))
    return [_layout(fig, "median replay deviation of the exact plans [m]",
                    "median plan time [s]", logx=True, logy=True)]
