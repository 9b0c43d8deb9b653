"""Verdicts on a fixed step that people ship: for one (method, h) and a config's model and
envelope, at every operating point, whether h is stable (the sweep's blow-up test), how far
below the measured largest stable step there it lies (the margin rule of bench/tune/margin.py),
and how large its error is against the tight reference; and where in the envelope each
verdict holds, in words that name no point of another verdict."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd

from stepzoo.bench.tune import margin as margin_rule
from stepzoo.bench.sweep import metrics
from stepzoo.bench.model import nonfinite as model_nan
from stepzoo.bench.sweep.block import Block
from stepzoo.bench.sweep.engine import n_blocks

# The per-point fields of `stepzoo verdict` (CSV columns, JSON keys), after the envelope's
# variables.
POINT_FIELDS = ["stable", "accurate", "error", "h_over_h_meas", "cause", "h_meas", "h_pred",
                "limit_cause", "verdict"]


def verdict(cfg, method_name: str, h: float) -> pd.DataFrame:
    """One row per operating point: its variables, h_pred [s] (frozen Jacobians), h_meas
    [s] (the sweep's limit search, started from h: inf when nothing failed up to
    h_probe_max) and limit_cause (what failed above it), stable (measured at h), cause
    ('unstable', 'solver failed' or ''), err (the error norm, over the run or at its end as
    the config's [error] estimate says, as the sweep's), err_pos [m] for vehicle models.
    Implicit methods solve with the config's [newton] options."""
    meth = cfg.method(method_name)
    n = max(1, round(cfg.horizon / h))
    # The accuracy runs take n steps of h, as the sweep's; the limit search brackets from h,
    # and probes above it even when h is past the config's largest probe.
    cfg = dataclasses.replace(cfg, hs=(h,), h_probe_max=max(cfg.h_probe_max, 2.0 * h))
    cache: dict = {}
    rows: list[dict] = []
    for block in range(n_blocks(cfg)):
        work = Block(cfg, block, cache, max_steps=max(n, cfg.stab_steps))
        pts = work.points
        grid = work.stable(meth, np.full((len(pts), 1), h))
        ok, conv = grid.stable, grid.converged
        run = work.run(meth, pts.x0, pts.u, pts.p, h, n)
        x, acc_conv = run.x, run.converged
        ref = work.reference(h, n).x
        err = metrics.run_error(cfg.spec, x, ref, cfg.error_estimate)
        predicted = work.predicted(meth)
        h_meas, limit_cause = work.measured_limits(meth, grid, np.array([p.h for p in predicted]))
        nan_t = model_nan.lane_times(work)
        for lane, i in enumerate(pts.ids):
            row = {k: v[lane] for k, v in pts.columns().items()}
            stable = bool(ok[lane, 0] and acc_conv[lane])
            row.update(point=i, h_pred=predicted[lane].h, h_meas=float(h_meas[lane]),
                       limit_cause=str(limit_cause[lane]), stable=stable,
                       cause="" if stable else ("unstable" if conv[lane, 0] and acc_conv[lane]
                                                else "solver failed"),
                       err=float(err[lane]) if stable else float("inf"))
            if cfg.spec.vehicle:
                ix, iy = cfg.spec.states.index("X"), cfg.spec.states.index("Y")
                d = np.hypot(x[lane, :, ix] - ref[lane, :, ix], x[lane, :, iy] - ref[lane, :, iy])
                row["err_pos"] = float(np.nanmax(d)) if stable else float("inf")
            if np.isfinite(nan_t[lane]):
                row.update(stable=False, cause=model_nan.cause(nan_t[lane]), h_pred=np.nan,
                           h_meas=np.nan)
            rows.append(row)
    return pd.DataFrame(rows)


def verdicts(cfg, pairs, column: str, tol: float, margin: float, unit: str = ""):
    """[(summary dict, judged per-point table)] per (method, h [s]) of `pairs` on the sweep
    config `cfg`: judged on `column` against `tol`, with `margin` (a fraction)."""
    variables = list(cfg.spec.variables)
    out = []
    for name, h in pairs:
        table = judge(verdict(cfg, name, h), h, column, tol, margin, unit)
        worst = table.loc[table["error"].idxmax()]
        kinds = classes(table, variables, margin)
        where = {k["verdict"]: k["where"] for k in kinds}
        out.append(({
            "method": name, "h": h, "points": len(table), "stable": int(table["stable"].sum()),
            "stable_with_margin": int(table["with_margin"].sum()),
            "accurate": int(table["accurate"].sum()),
            "unstable_where": where["unstable"],
            "solver_failed_where": where["solver failed"],
            "model_nan_where": where["model returned NaN"],
            "inaccurate_where": where["stable, not accurate"],
            "worst_error": float(worst["error"]),
            "worst_at": {v: float(worst[v]) for v in variables},
            "worst_cause": str(worst["cause"]),
            "h_pred_min": float(table["h_pred"].min()),
            "h_meas_min": float(table["h_meas"].min()),
            "tolerance": {column: tol},
            "margin": margin,
            "classes": kinds,
            "points_list": [point_record(r, variables) for _, r in table.iterrows()],
        }, table))
    return out


def judge(table: pd.DataFrame, h: float, column: str, tol: float, margin: float,
          unit: str = "") -> pd.DataFrame:
    """The verdict's table with the per-point answer: `error` (the `column` it is judged on),
    accurate (stable and error <= tol), h_over_h_meas, with_margin (the margin rule),
    cause (why the point fails the verdict, '' when it passes) and verdict (in words)."""
    out = table.copy()
    out["error"] = out[column].astype(float)
    out["accurate"] = out["stable"] & (out["error"] <= tol)
    with np.errstate(divide="ignore"):
        out["h_over_h_meas"] = h / out["h_meas"].astype(float)
    out["with_margin"] = margin_rule.stable_with_margin(out["stable"], h, out["h_meas"], margin)
    causes, words = [], []
    for r in out.itertuples():
        if not r.stable:
            causes.append(r.cause)
            words.append(r.cause)
            continue
        solver = " (a failed solve)" if r.limit_cause == "solver failed" else ""
        why = [] if r.with_margin else [
            f"within {margin_rule.percent_below(h, r.h_meas)} of the limit{solver}"]
        stability = f"stable, {why[0]}" if why else "stable with margin"
        if not r.accurate:
            why.append(f"error {r.error:.3g}{unit} > {tol:g}{unit}")
        causes.append("; ".join(why))
        words.append(stability + (", accurate" if r.accurate else ", not accurate"))
    out["cause"], out["verdict"] = causes, words
    return out


def classes(judged: pd.DataFrame, variables, margin: float) -> list[dict]:
    """The verdict's summary: per kind of answer, how many points and where (`region`).
    The kinds overlap (a point near the limit may also be inaccurate); each "where" names
    only points of its own kind."""
    stable = judged["stable"]
    kinds = [("unstable", judged["cause"] == "unstable"),
             ("solver failed", judged["cause"] == "solver failed"),
             ("model returned NaN", judged["cause"].str.startswith(model_nan.PREFIX)),
             (f"stable, within {100 * margin:g}% of the limit", stable & ~judged["with_margin"]),
             ("stable, not accurate", stable & ~judged["accurate"]),
             ("stable with margin and accurate", judged["with_margin"] & judged["accurate"])]
    return [{"verdict": name, "points": int(mask.sum()),
             "where": region(judged, mask, variables)} for name, mask in kinds]


def point_record(row, variables) -> dict:
    """A judged row as the JSON object of one point: the variables by name, then
    POINT_FIELDS (inf and NaN as null: JSON has neither)."""
    def plain(v):
        if isinstance(v, (bool, np.bool_)):
            return bool(v)
        if isinstance(v, (float, np.floating)):
            return float(v) if math.isfinite(v) else None
        return v
    return {**{v: float(row[v]) for v in variables},
            **{k: plain(row[k]) for k in POINT_FIELDS}}


def region(table: pd.DataFrame, mask, variables) -> str:
    """Where the rows of `mask` lie, naming no row outside it: 'nowhere'; a box of the
    envelope ('vx 2..8, delta = 0.3') when every point in it is of `mask`; else the box is
    split at each value of one variable (the one that leaves the fewest parts) and each part
    said alike, the parts joined by '; '."""
    mask = np.asarray(mask, bool)
    if not mask.any():
        return "nowhere"
    values = table[list(variables)].to_numpy(float)
    return "; ".join(_boxes(values, mask, list(variables)))


def _boxes(values: np.ndarray, mask: np.ndarray, names: list) -> list[str]:
    inside = values[mask]
    lo, hi = inside.min(axis=0), inside.max(axis=0)
    in_box = ((values >= lo) & (values <= hi)).all(axis=1)
    spread = [j for j in range(len(names)) if lo[j] < hi[j]]
    if not (in_box & ~mask).any() or not spread:
        return [", ".join(f"{v} {a:.4g}..{b:.4g}" if a < b else f"{v} = {a:.4g}"
                          for v, a, b in zip(names, lo, hi))]
    splits = []
    for j in spread:
        parts = []
        for value in np.unique(inside[:, j]):
            at = values[:, j] == value
            parts += _boxes(values[at], mask[at], names)
        splits.append(parts)
    return min(splits, key=len)
