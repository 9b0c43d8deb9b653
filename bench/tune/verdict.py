"""Verdicts on a fixed step that people ship: for one (method, h) and a config's model and
envelope, at every operating point, whether h is stable (the sweep's stability test), how far
below the smaller of the predicted and measured largest stable steps there it lies (the
margin rule of bench/tune/margin.py; never "stable with margin" beyond the predicted one), and how
large its error is against the tight reference (finite wherever the run is); where in the
envelope each verdict holds, in words that name no point of another verdict; and whether the
model is stiff, with the mode that binds explicit steps (bench/model/stiffness.py)."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from stepzoo.bench.model import frozen_jacobian as frozen
from stepzoo.bench.sweep import metrics
from stepzoo.bench.model import nonfinite as model_nan
from stepzoo.bench.model import stiffness
from stepzoo.bench.tune import margin as margin_rule
from stepzoo.bench.sweep.block import Block
from stepzoo.bench.sweep.engine import n_blocks
from stepzoo.bench.sweep.config import run_steps

# The per-point fields of `stepzoo verdict` (CSV columns, JSON keys), after the envelope's
# variables.
POINT_FIELDS = ["stable", "accurate", "error", "h_over_h_meas", "cause", "h_meas", "h_pred",
                "limit_cause", "verdict", "h_over_h_pred", "beyond_predicted", "finite"]
BEYOND = "beyond the predicted limit"


def verdict(cfg, method_name: str, h: float) -> pd.DataFrame:
    """One row per operating point: its variables, h_pred [s] (frozen Jacobians), h_meas
    [s] (the sweep's limit search, started from h: inf when nothing failed up to
    h_probe_max) and limit_cause (what failed above it), stable (measured at h), cause
    ('unstable', 'solver failed' or ''), err (the error norm, over the run or at its end as
    the config's [error] estimate says, as the sweep's), err_pos [m] for vehicle models.
    Implicit methods solve with the config's [newton] options. `finite`: the accuracy run
    stayed finite over the horizon; its error is then finite whatever the stability test
    says (inf only where the run itself is not finite)."""
    return _verdict(cfg, method_name, h)[0]


def _verdict(cfg, method_name: str, h: float) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(verdict's table, a limits-like table of every explicit method's predicted limit per
    point with where it binds, for bench/stiffness.explicit_limit)."""
    meth = cfg.method(method_name)
    n = max(1, round(cfg.horizon / h))
    cfg = at_step(cfg, h)
    cache: dict = {}
    rows: list[dict] = []
    explicit: list[dict] = []
    for block in range(n_blocks(cfg)):
        work = Block(cfg, block, cache, max_steps=max(n, run_steps(cfg)))
        pts = work.points
        grid = work.stable(meth, np.full((len(pts), 1), h))
        ok, conv = grid.stable, grid.converged
        run = work.run(meth, pts.x0, pts.u, pts.p, h, n)
        x, acc_conv = run.x, run.converged
        ref = work.reference(h, n).x
        err = metrics.run_error(cfg.spec, x, ref, cfg.error.estimate)
        predicted = work.predicted(meth)
        h_meas, limit_cause = work.measured_limits(meth, grid, np.array([p.h for p in predicted]))
        nan_t = model_nan.lane_times(work)
        explicit += _explicit_limits(work)
        for lane, i in enumerate(pts.ids):
            row = {k: v[lane] for k, v in pts.columns().items()}
            stable = bool(ok[lane, 0] and acc_conv[lane])
            finite = bool(np.isfinite(x[lane]).all())
            row.update(point=i, h_pred=predicted[lane].h, h_meas=float(h_meas[lane]),
                       limit_cause=str(limit_cause[lane]), stable=stable, finite=finite,
                       cause="" if stable else ("unstable" if conv[lane, 0] and acc_conv[lane]
                                                else "solver failed"),
                       err=float(err[lane]) if finite else float("inf"))
            if cfg.spec.vehicle:
                ix, iy = cfg.spec.states.index("X"), cfg.spec.states.index("Y")
                d = np.hypot(x[lane, :, ix] - ref[lane, :, ix], x[lane, :, iy] - ref[lane, :, iy])
                row["err_pos"] = float(np.max(d)) if finite else float("inf")
            if np.isfinite(nan_t[lane]):
                row.update(stable=False, cause=model_nan.cause(nan_t[lane]), h_pred=np.nan,
                           h_meas=np.nan)
            rows.append(row)
    return pd.DataFrame(rows), pd.DataFrame(explicit)


def _explicit_limits(work: Block) -> list[dict]:
    """Every explicit method of the zoo: its predicted limit at each point of the block
    (a limits row: h_pred [s], t_bind [s], the binding eigenvalue [1/s] and state)."""
    from stepzoo.integrators import METHODS
    along, pts, spec = work.along(), work.points, work.spec
    rows = []
    for name, m in METHODS.items():
        if m.implicit:
            continue
        for lane, i in enumerate(pts.ids):
            h, k, j = frozen.predicted_limit(m, along.lam[lane])
            lam = along.lam[lane, k, j] if k >= 0 else complex(np.nan, np.nan)
            rows.append({"method": name, "point": i, "h_pred": h, "h_meas": np.inf,
                         "t_bind": along.ts[k] if k >= 0 else np.nan, "lam_re_bind": lam.real,
                         "lam_im_bind": lam.imag,
                         **{v: pts.values[lane, c] for c, v in enumerate(spec.variables)},
                         **{f"bind_{s}": along.xs[lane, k, c] if k >= 0 else np.nan
                            for c, s in enumerate(spec.states)}})
    return rows


def at_step(cfg, h: float):
    """The sweep config `cfg` as a verdict at the step h [s] runs it: the accuracy runs take
    the horizon in steps of h, as the sweep's; the limit search brackets from h, and probes
    above it even when h is past the config's largest probe."""
    return cfg.changed(steps={"h": (h,)},
                       stability={"h_probe_max": max(cfg.stability.h_probe_max, 2.0 * h)})


def check_workload(cfg, pairs) -> None:
    """UsageError, before any work, with the estimate and the limit, if the verdict on any
    (method, h [s]) of `pairs` would hold more trajectory memory or integrate more steps
    than allowed (the sweep's estimate at that one step)."""
    from stepzoo.bench.sweep.config import check_workload as check
    for name, h in pairs:
        check(at_step(cfg, h).changed(methods=(name,)),
              f"the verdict on {name} at h = {h:g} s")


def verdicts(cfg, pairs, column: str, tol: float, margin: float, unit: str = "",
             beyond_predicted: bool = False):
    """[(summary dict, judged per-point table)] per (method, h [s]) of `pairs` on the sweep
    config `cfg`: judged on `column` against `tol`, with `margin` (a fraction), below the
    smaller of the predicted and measured limits (the measured alone with
    `beyond_predicted`)."""
    check_workload(cfg, pairs)
    variables = list(cfg.spec.variables)
    out = []
    for name, h in pairs:
        raw, explicit = _verdict(cfg, name, h)
        table = judge(raw, h, column, tol, margin, unit, beyond_predicted)
        worst = table.loc[table["error"].idxmax()]
        kinds = classes(table, variables, margin)
        h_exp, bind = stiffness.explicit_limit(explicit)
        within = table["stable"] & ~table["beyond_predicted"] & (h <= table["h_meas"])
        h_acc = h if bool((within & table["accurate"]).all()) else float("nan")
        stiff = stiffness.assess(h_exp, bind, h_acc, name if h_acc == h else None, cfg,
                                 variables)
        where = {k["verdict"]: k["where"] for k in kinds}
        out.append(({
            "method": name, "h": h, "points": len(table), "stable": int(table["stable"].sum()),
            "stable_with_margin": int(table["with_margin"].sum()),
            "accurate": int(table["accurate"].sum()),
            "unstable_where": where["unstable"],
            "solver_failed_where": where["solver failed"],
            "model_nan_where": where["model returned NaN"],
            "beyond_predicted_where": where[BEYOND],
            "beyond_predicted": int(table["beyond_predicted"].sum()),
            "allow_beyond_predicted_limit": bool(beyond_predicted),
            "h_over_h_pred_max": float(table["h_over_h_pred"].max()),
            "stiff": stiff["stiff"],
            "stiffness": stiff,
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
          unit: str = "", beyond_predicted: bool = False) -> pd.DataFrame:
    """The verdict's table with the per-point answer: `error` (the `column` it is judged on),
    accurate (stable and error <= tol), h_over_h_meas, h_over_h_pred, beyond_predicted (h
    above h_pred), with_margin (the margin rule: below the smaller limit, or h_meas alone
    with `beyond_predicted`), cause (why the point fails the verdict, '' when it passes) and
    verdict (in words). A stable point beyond its predicted limit is never "stable with
    margin": it reads "beyond the predicted limit (K x)", or with `beyond_predicted` "stable
    with margin, beyond the predicted limit (K x, allowed)"."""
    out = table.copy()
    out["error"] = out[column].astype(float)
    out["accurate"] = out["stable"] & (out["error"] <= tol)
    if "finite" not in out:          # a table of the sweep's own runs
        out["finite"] = np.isfinite(out["error"])
    with np.errstate(divide="ignore", invalid="ignore"):
        out["h_over_h_meas"] = h / out["h_meas"].astype(float)
        out["h_over_h_pred"] = h / out["h_pred"].astype(float)
    out["beyond_predicted"] = margin_rule.beyond(h, out["h_pred"])
    out["with_margin"] = margin_rule.stable_with_margin(out["stable"], h, out["h_meas"], margin,
                                                        out["h_pred"], beyond_predicted)
    causes, words = [], []
    for r in out.itertuples():
        if not r.stable:
            causes.append(r.cause)
            words.append(r.cause)
            continue
        beyond = f"{BEYOND} ({r.h_over_h_pred:.3g} x)"
        if r.beyond_predicted and not beyond_predicted:
            why = [beyond]
            stability = beyond
        else:
            solver = " (a failed solve)" if r.limit_cause == "solver failed" else ""
            limit = float(margin_rule.limit(r.h_meas, r.h_pred, beyond_predicted))
            why = [] if r.with_margin else [
                f"within {margin_rule.percent_below(h, limit)} of the limit{solver}"]
            stability = f"stable, {why[0]}" if why else "stable with margin"
            if r.beyond_predicted:
                stability += f", {BEYOND} ({r.h_over_h_pred:.3g} x, allowed)"
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
    beyond = judged["cause"].str.startswith(BEYOND)
    kinds = [("unstable", judged["cause"] == "unstable"),
             ("solver failed", judged["cause"] == "solver failed"),
             ("model returned NaN", judged["cause"].str.startswith(model_nan.PREFIX)),
             (BEYOND, stable & beyond),
             (f"stable, within {100 * margin:g}% of the limit",
              stable & ~judged["with_margin"] & ~beyond),
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
