"""Stiffness named, point by point. At an operating point the model is stiff for a tolerance
when stability, not accuracy, bounds the explicit step there: the largest step some method
(implicit, Rosenbrock, or explicit within its own limits) meets the tolerance at, stable,
is STIFF_RATIO or more times the largest step any explicit method may take there (the
smaller of its predicted and measured limits). The sweep's answer is that of the point where
the ratio is largest, with the mode that bounds the explicit step there: its eigenvalue, the
state that takes the largest part in it (participation factors) and where."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from stepzoo.bench.tune.margin import limit

# Hairer and Wanner's practical sense of stiffness (Solving Ordinary Differential Equations
# II, sec. IV.1-2: stiff where the step is restricted by stability rather than accuracy;
# Lambert: a step "excessively small in relation to the smoothness of the exact solution")
# is a ratio above 1. The accurate step is read on the sweep's grid of steps, so a ratio
# below 2 can be where the grid's steps happen to fall: from 2, accuracy allows at least
# twice the explicit bound.
STIFF_RATIO = 2.0
RULE = (f"stiff at an operating point where the largest step at which some method, stable "
        f"and within its own limits, meets the tolerance there is at least {STIFF_RATIO:g} x "
        "the largest step an explicit method may take there (the smaller of its predicted and "
        "measured limits); the answer is the point where that ratio is largest, its binding "
        "mode named by its eigenvalue, the state with the largest participation factor in it, "
        "the time and the operating point")


def participation(jac, lam: complex) -> np.ndarray:
    """Participation factors (d,) of each state in the mode of the Jacobian `jac` (d, d)
    whose eigenvalue is nearest `lam`: |v_i w_i| (right and left eigenvectors), summing to 1;
    unit-free, so a state's share does not depend on the units it is written in."""
    vals, right = np.linalg.eig(np.asarray(jac, float))
    k = int(np.argmin(np.abs(vals - lam)))
    # A defective Jacobian (a repeated eigenvalue without a full set of eigenvectors, as
    # states that only integrate others give) has no left eigenvectors to pair: the
    # pseudo-inverse gives the nearest pairing, whose shares still name the mode's states.
    left = np.linalg.pinv(right)
    share = np.abs(right[:, k] * left[k, :])
    return share / share.sum()


def _explicit(names) -> np.ndarray:
    from stepzoo.integrators import METHODS
    return np.array([n in METHODS and not METHODS[n].implicit for n in names], bool)


def explicit_limit(limits: pd.DataFrame) -> tuple[float, pd.Series | None]:
    """(the largest step [s] some explicit method may take at every point, the limits row
    where that method's limit binds); (NaN, None) when no explicit method has a finite one."""
    lim = limits[_explicit(limits["method"])].copy()
    if lim.empty:
        return float("nan"), None
    h_meas = lim["h_meas"] if "h_meas" in lim else np.full(len(lim), np.inf)
    lim["h_limit"] = limit(h_meas, lim["h_pred"])
    lim = lim[np.isfinite(lim["h_limit"])]
    if lim.empty:
        return float("nan"), None
    per_method = lim.loc[lim.groupby("method")["h_limit"].idxmin()]
    row = per_method.loc[per_method["h_limit"].idxmax()]
    return float(row["h_limit"]), row


def accurate_step(runs: pd.DataFrame, limits: pd.DataFrame, column: str,
                  tol: float) -> tuple[float, str | None]:
    """(the largest step h [s] at which some method is stable, at or below the smaller of its
    predicted and measured limits, and within `tol` in `column` at every point, that method);
    (NaN, None) when none is."""
    df = runs.merge(limits[["method", "point", "h_meas", "h_pred"]], on=["method", "point"])
    with np.errstate(invalid="ignore"):
        df["ok"] = df["stable"] & (df["h"] <= limit(df["h_meas"], df["h_pred"])) \
            & (df[column] <= tol)
    ok = df.groupby(["method", "h"])["ok"].all().reset_index()
    ok = ok[ok["ok"]]
    if ok.empty:
        return float("nan"), None
    best = ok.loc[ok["h"].idxmax()]
    return float(best["h"]), str(best["method"])


def mode(cfg, row: pd.Series | None, variables) -> dict | None:
    """The mode where an explicit limit binds (a limits row): its eigenvalue [1/s], the time
    [s], the operating point, and (with the sweep config `cfg`) the state with the largest
    participation factor in it at that state of the reference."""
    if row is None or not np.isfinite(row.get("lam_re_bind", np.nan)):
        return None
    lam = complex(row["lam_re_bind"], row["lam_im_bind"])
    out = {"method": str(row["method"]), "lambda_re_per_s": float(lam.real),
           "lambda_im_per_s": float(abs(lam.imag)), "t_s": float(row["t_bind"]),
           "point": {v: float(row[v]) for v in variables if v in row},
           "state": None, "participation": None}
    if cfg is None:
        return out
    from stepzoo.bench.model.frozen_jacobian import jacobians
    spec = cfg.spec
    x = np.array([row[f"bind_{s}"] for s in spec.states], float)
    _, u, p = spec.arrays([cfg.points[int(row["point"])]])
    jac = jacobians(spec.rhs, np.array([row["t_bind"]]), x[None, None], u, p)[0, 0]
    share = participation(jac, lam)
    k = int(np.argmax(share))
    out.update(state=spec.states[k], participation=float(share[k]))
    return out


def assess(h_explicit: float, explicit_row, h_accurate: float, accurate_method,
           cfg=None, variables=()) -> dict:
    """The stiffness record (the JSON/TOML `stiffness` table): stiff, the two steps [s], their
    ratio, the binding mode (`mode`) and a sentence saying so."""
    ratio = h_accurate / h_explicit if h_explicit > 0 else float("nan")
    stiff = bool(math.isfinite(ratio) and ratio >= STIFF_RATIO)
    found = mode(cfg, explicit_row, variables)
    return {"stiff": stiff, "h_explicit_max_s": h_explicit, "h_accurate_max_s": h_accurate,
            "accurate_method": accurate_method, "ratio": ratio, "stiff_ratio": STIFF_RATIO,
            "mode": found, "says": says(stiff, h_explicit, h_accurate, accurate_method, found)}


def describe(found: dict | None) -> str:
    """'lambda = -8900 1/s (mostly omega_f, 0.97) at t = 0.4 s, vx = 10' for a mode."""
    if found is None:
        return "no binding mode"
    im = f"{found['lambda_im_per_s']:+.3g}i" if found["lambda_im_per_s"] else ""
    state = (f" (mostly {found['state']}, participation {found['participation']:.2f})"
             if found["state"] else "")
    where = ", ".join(f"{k} = {v:.4g}" for k, v in found["point"].items())
    return (f"lambda = {found['lambda_re_per_s']:.4g}{im} 1/s{state} at t = "
            f"{found['t_s']:.3g} s{', ' + where if where else ''}")


def says(stiff: bool, h_explicit: float, h_accurate: float, method, found) -> str:
    """The stiffness finding in one sentence."""
    if not math.isfinite(h_explicit):
        return "stiffness not assessed: no explicit method with a finite limit was swept"
    if not math.isfinite(h_accurate):
        return (f"stiffness not assessed: no method meets the tolerance within its limits; "
                f"explicit steps are bound below {h_explicit:.3g} s by {describe(found)}")
    ratio = h_accurate / h_explicit
    if stiff:
        return (f"the model is stiff: explicit steps are bound below {h_explicit:.3g} s by "
                f"{describe(found)}, while {method} meets the tolerance within its limits up "
                f"to h = {h_accurate:.3g} s ({ratio:.3g} x)")
    return (f"not stiff: accuracy allows {h_accurate:.3g} s ({method}), {ratio:.3g} x the "
            f"largest explicit limit {h_explicit:.3g} s (stiff from {STIFF_RATIO:g} x), bound "
            f"by {describe(found)}")


def per_point(runs: pd.DataFrame, limits: pd.DataFrame, column: str,
              tol: float) -> pd.DataFrame:
    """Per operating point (its rows indexed by point): h_explicit, the largest step [s] an
    explicit method may take there (the smaller of its predicted and measured limits, the
    best explicit method's); explicit_row, the limits row of that method there;
    h_accurate, the largest step [s] at which some method, stable there and within its own
    limits, meets `tol` in `column` there; accurate_method; and ratio = h_accurate /
    h_explicit (NaN where either is missing)."""
    lim = limits.copy()
    h_meas = lim["h_meas"] if "h_meas" in lim else np.full(len(lim), np.inf)
    lim["h_limit"] = limit(h_meas, lim["h_pred"])
    exp = lim[_explicit(lim["method"]) & np.isfinite(lim["h_limit"])]
    out = pd.DataFrame(index=pd.Index(sorted(lim["point"].unique()), name="point"))
    best = exp.loc[exp.groupby("point")["h_limit"].idxmax()] if len(exp) else exp
    out["h_explicit"] = best.set_index("point")["h_limit"]
    out["explicit_row"] = pd.Series(best.index, index=best["point"].to_numpy())
    df = runs.merge(lim[["method", "point", "h_limit"]], on=["method", "point"])
    with np.errstate(invalid="ignore"):
        ok = df[df["stable"] & (df["h"] <= df["h_limit"]) & (df[column] <= tol)]
    acc = ok.loc[ok.groupby("point")["h"].idxmax()] if len(ok) else ok
    out["h_accurate"] = acc.set_index("point")["h"]
    out["accurate_method"] = acc.set_index("point")["method"]
    out["ratio"] = out["h_accurate"] / out["h_explicit"]
    return out


def of_sweep(runs, limits, column: str, tol: float, cfg=None, variables=()) -> dict:
    """The stiffness record of a sweep's tables at tolerance `tol` on `column`, point by
    point (`per_point`): the model is stiff where accuracy allows STIFF_RATIO or more times
    the largest explicit step at some point; the record is that of the point where the ratio
    is largest (where no point has one, the explicit bound over every point, `assess`)."""
    at = per_point(runs, limits, column, tol)
    ratios = at["ratio"].dropna()
    if ratios.empty:
        h_exp, row = explicit_limit(limits)
        h_acc, method = accurate_step(runs, limits, column, tol)
        return dict(assess(h_exp, row, h_acc, method, cfg, variables), stiff_points=0,
                    points=len(at))
    p = ratios.idxmax()
    row = limits.loc[at.loc[p, "explicit_row"]]
    h_acc = float(at.loc[p, "h_accurate"])
    found = assess(float(at.loc[p, "h_explicit"]), row, h_acc,
                   str(at.loc[p, "accurate_method"]), cfg, variables)
    stiff_points = int((ratios >= STIFF_RATIO).sum())
    found["says"] += f" (stiff at {stiff_points} of {len(at)} points"
    found["says"] += ("; the sweep's largest step: accuracy may allow more)"
                      if h_acc >= runs["h"].max() else ")")
    return dict(found, stiff_points=stiff_points, points=len(at))
