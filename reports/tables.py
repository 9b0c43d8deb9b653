"""The report's tables as rows of plain values: the per-method summary of a sweep (order,
stability intervals, largest stable step, cost at the tolerance) and the tuning decision with
its runners-up; and their rendering as Markdown and as HTML."""
from __future__ import annotations

import html
import math
from dataclasses import dataclass

import numpy as np

from stepzoo.bench.tune.margin import stable_with_margin
from stepzoo.bench.sweep.metrics import own_limits
from stepzoo.reports.figure_data import method_order, worst_case


@dataclass(frozen=True)
class Table:
    """A titled table of the report: rows of values, columns as (key, header label)."""
    title: str
    caption: str
    rows: list
    columns: list


METHOD_COLUMNS = [
    ("method", "method"), ("family", "family"), ("order_declared", "order"),
    ("order_fit_median", "fitted order"), ("order_status", "order status"),
    ("real_interval", "real interval"),
    ("imag_interval", "imag. interval"), ("h_pred_min", "h max predicted [s]"),
    ("h_meas_min", "h max measured [s]"), ("worst_ratio", "worst meas./pred."),
    ("solver_failures", "runs with failed solves"),
    ("solver_limited_points", "points limited by a failed solve"),
    ("h_solver_limit_min", "h max where solves converge [s]"),
    ("h_at_tol", "h at tolerance [s]"), ("evals_at_tol", "RHS evals per sim. s"),
    ("time_at_tol", "wall s per sim. s"),
]
TUNING_COLUMNS = [
    ("rank", "rank"), ("method", "method"), ("h", "h [s]"),
    ("cost_evals_per_s", "RHS evals per sim. s"), ("cost_time_per_s", "wall s per sim. s"),
    ("reason", "why"),
]


def method_summary(sweep, tol: float, margin: float, error: str = "err_pos") -> list[dict]:
    """One row per method: the sweep's summary.csv, its limits told apart from the solver's
    (metrics.own_limits, from limits.parquet: a folder swept before summary.csv had them reads
    the same), plus the largest step [s] that is stable at every operating point, keeps
    `margin` below the measured limit (the solver's included) and has a worst error (the
    runs column `error`: position [m], or the error norm) <= tol, with its costs (None when
    no step qualifies); the margin is kept below the predicted limit too, as tune keeps it
    (bench/tune/margin.py)."""
    table = worst_case(sweep.runs, error)
    summary = sweep.summary.set_index("method")
    rows = []
    for name in method_order(summary.index):
        s = summary.loc[name]
        row = {key: _plain(s[key]) for key, _ in METHOD_COLUMNS if key in s.index}
        own = own_limits(sweep.limits[sweep.limits["method"] == name])
        row.update({k: _plain(v) for k, v in own.items()}, method=name)
        limit = np.fmin(np.fmin(own["h_meas_min"], own["h_solver_limit_min"]),
                        float(s["h_pred_min"]))
        ok = table[(table["method"] == name) & (table["worst"] <= tol)]
        if np.isfinite(limit):
            ok = ok[stable_with_margin(True, ok["h"], limit, margin)]
        if len(ok):
            best = ok.loc[ok["h"].idxmax()]
            row.update(h_at_tol=float(best["h"]), evals_at_tol=float(best["evals_per_s"]),
                       time_at_tol=float(best["time_per_s"]))
        rows.append(row)
    return rows


def verdict_table(summary: dict, judged, variables, tol: float, unit: str = "") -> Table:
    """The report's section of one `stepzoo verdict` (method, h): its summary (how many
    points, and where, per kind of answer) as the caption, one row per operating point."""
    kinds = "; ".join(f"{k['verdict']}: {k['points']} ({k['where']})"
                      for k in summary["classes"] if k["points"])
    caption = (f"{summary['method']} at h = {summary['h']:g} s on the sweep's envelope, point "
               f"by point, as `stepzoo verdict` gives it: stable (the sweep's blow-up test at "
               f"h), h / h_meas (the point's measured largest stable step; stable with margin "
               f"when h is at most {1 - summary['margin']:g} x the smaller of it and the "
               f"predicted one, never beyond the predicted one), the error (finite wherever "
               f"the run is) and whether it is within "
               f"{tol:g}{unit}. Of {summary['points']} points: {kinds}.")
    rows = [{**{v: float(r[v]) for v in variables}, "h_over_h_meas": _plain(r["h_over_h_meas"]),
             "stable": bool(r["stable"]), "error": _plain(r["error"]),
             "accurate": bool(r["accurate"]), "verdict": r["verdict"]}
            for _, r in judged.iterrows()]
    columns = [(v, v) for v in variables] + [
        ("h_over_h_meas", "h / h_meas"), ("stable", "stable"), ("error", f"error{unit}"),
        ("accurate", "accurate"), ("verdict", "verdict")]
    return Table(f"Verdict: {summary['method']} at h = {summary['h']:g} s", caption, rows,
                 columns)


def tuning_rows(tuned: dict) -> list[dict]:
    """The chosen (method, h) as rank 1, then the runners-up in the order tune wrote them."""
    chosen = {"rank": 1, "method": tuned["method"], "h": tuned["h"],
              "cost_evals_per_s": tuned.get("cost_evals_per_s"),
              "cost_time_per_s": tuned.get("cost_time_per_s"),
              "reason": tuned.get("why", "chosen")}
    others = [{"rank": i + 2, **{k: r.get(k) for k, _ in TUNING_COLUMNS[1:]}}
              for i, r in enumerate(tuned.get("runners_up", []))]
    return [chosen, *others]


def tuning_caption(tuned: dict) -> str:
    """What ranked the tuning table: the cost that chose, as the tuned config records it."""
    if tuned.get("cost", "evals") == "time":     # configs from before --cost ranked by evals
        c = tuned.get("calibration", {})
        by = (f"measured wall time per simulated second (each method calibrated in the "
              f"planner's call, {c.get('batch', '?')} trajectories of {c.get('interval_s', '?')}"
              f" s, the fastest of {c.get('rounds', '?')} rounds; a tie within the measured "
              "spread goes to fewer RHS evaluations)")
    else:
        by = "RHS evaluations per simulated second"
    return (f"The (method, h) that `stepzoo tune` chose (rank 1) and its runners-up, ranked by "
            f"{by}, with both costs per simulated second and the reason each lost.")


def _plain(v):
    """numpy scalars to Python; NaN to None."""
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and math.isnan(v):
        return None
    return v


def cell(v) -> str:
    """A value as table text: 4 significant digits, inf as 'unbounded', missing as '-'."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return "unbounded" if math.isinf(v) else f"{v:.4g}"
    return str(v)


def to_markdown(rows: list[dict], columns) -> str:
    def esc(text):
        return text.replace("|", "\\|").replace("\n", " ")
    lines = ["| " + " | ".join(label for _, label in columns) + " |",
             "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(esc(cell(r.get(k))) for k, _ in columns) + " |" for r in rows]
    return "\n".join(lines)


def to_html(rows: list[dict], columns) -> str:
    head = "".join(f"<th>{html.escape(label)}</th>" for _, label in columns)
    body = "\n".join("<tr>" + "".join(f"<td>{html.escape(cell(r.get(k)))}</td>"
                                      for k, _ in columns) + "</tr>" for r in rows)
    return f"<table>\n<thead><tr>{head}</tr></thead>\n<tbody>\n{body}\n</tbody>\n</table>"
