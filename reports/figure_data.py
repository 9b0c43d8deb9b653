"""What each report figure shows, computed once from the loaded result tables: one function
per figure returning its `figure_types` record (series, labels, caption, file name), which
the PNG renderer (`figures`) and the interactive one (`interactive`) only draw."""
from __future__ import annotations

import numpy as np
import pandas as pd

from stepzoo.bench.sweep.config import ESTIMATES
from stepzoo.integrators import METHODS
from stepzoo.integrators.stability import amplification_theory, region_grid
from stepzoo.reports.figure_types import (ErrorPanel, ErrorVsStep, LimitCurve, LimitPanel,
                                          PlanMap, Plans, RegionPanel, Regions, Run,
                                          StableStep, Trajectories, TrajectoryPanel, WorkLine,
                                          WorkPrecision)
from stepzoo.reports.load import tolerance

BLOWUP_FACTOR = 3.0            # a sample run this far beyond the reference's range diverged
REGION_GRID = 181              # grid points per axis of a stability region
ERROR_NORM = "worst error (error states over their scales)"


def method_order(names) -> list[str]:
    """Methods in the zoo's registry order (families together), unknown names last."""
    names = set(names)
    return [m for m in METHODS if m in names] + sorted(names - set(METHODS))


def worst_case(runs: pd.DataFrame, error: str = "err") -> pd.DataFrame:
    """Per (method, h): `worst`, the largest `error` (a runs column: err_pos [m], or err, the
    error norm) over the envelope's operating points, the largest error norm `err` (the one
    orders are fitted on) and the median costs; only steps stable at every point (an
    unstable point has no error)."""
    g = runs.groupby(["method", "h"])
    table = pd.DataFrame({
        "all_stable": g["stable"].all(),
        "worst": g[error].max(),
        "err": g["err"].max(),
        "evals_per_s": g["evals_per_s"].median(),
        "time_per_s": g["time_per_step_s"].median(),
    }).reset_index()
    table["time_per_s"] = table["time_per_s"] / table["h"]     # wall seconds per simulated s
    ok = table["all_stable"] & np.isfinite(table["worst"]) & (table["worst"] > 0)
    return table[ok].sort_values(["method", "h"])


def binding_point(sweep, tuned, margin: float):
    """(point, why) where the tuned (method, h) is nearest a bound it must keep: the
    operating point of largest tightness max(h / ((1 - margin) h_meas), error / tol), both 1
    at the bound (h_meas the point's measured largest stable step, the error the one the
    tuned tolerance bounds); None when the sweep has no run of that (method, h)."""
    view = sweep.view.with_tolerance(tuned)
    tol, name, h = tolerance(tuned), tuned["method"], float(tuned["h"])
    runs = sweep.runs[(sweep.runs["method"] == name) & np.isclose(sweep.runs["h"], h)]
    lim = sweep.limits[sweep.limits["method"] == name][["point", "h_meas"]]
    df = runs.merge(lim, on="point")
    if df.empty or not tol:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        stab = (h / ((1.0 - margin) * df["h_meas"].to_numpy(float)))
        acc = df[view.error].to_numpy(float) / tol
    tight = np.fmax(np.nan_to_num(stab, nan=np.inf), np.nan_to_num(acc, nan=np.inf))
    i = int(np.argmax(tight))
    point = {v: float(df[v].iloc[i]) for v in view.variables}
    unit = f" {view.error_unit}" if view.error_unit else ""
    why = (f"the point where the tuned {name} at h = {h:g} s is nearest a bound it keeps: "
           f"h / h_meas = {h / df['h_meas'].iloc[i]:.3g} (at most {1 - margin:g}), "
           f"{view.error_label} {df[view.error].iloc[i]:.3g}{unit} (at most {tol:g}{unit})")
    return point, why


# Figures 1-2: sampled runs against the reference.

def _sample_runs(traj: pd.DataFrame):
    """(reference run, {method: [(h, run, past its stability limit)]}) of the trajectories."""
    ref = traj[traj["method"] == "reference"].sort_values("t")
    states = [c for c in traj.columns if c not in ("method", "h", "t", "past_limit")]
    bound = {c: BLOWUP_FACTOR * max(np.abs(ref[c]).max(), 1e-9) for c in states}
    runs: dict[str, list] = {}
    for (name, h), run in traj[traj["method"] != "reference"].groupby(["method", "h"]):
        run = run.sort_values("t")
        # The sweep marks the run it placed past the predicted limit; without the mark, a
        # run that left the reference's range far behind (or overflowed) is the one.
        if "past_limit" in run:
            past = bool(run["past_limit"].any())
        else:
            past = (not np.isfinite(run[states].to_numpy()).all()
                    or any(np.abs(run[c]).max() > bound[c] for c in bound))
        runs.setdefault(name, []).append((float(h), run, past))
    return ref, {m: runs[m] for m in method_order(runs)}


def _trajectory_panels(traj, xcol, ycol):
    """((reference x, y), a TrajectoryPanel per method) of ycol against xcol."""
    ref, runs = _sample_runs(traj)
    ref_xy = ref[[xcol, ycol]].to_numpy(float)
    panels = []
    for name, samples in runs.items():
        drawn, shown = [], [ref_xy]
        for h, run, past in samples:
            xy = run[[xcol, ycol]].to_numpy(float)
            drawn.append(Run(h, xy[:, 0], xy[:, 1], past))
            if not past:
                shown.append(xy)
        pts = np.vstack(shown)
        pts = pts[np.isfinite(pts).all(axis=1)]
        panels.append(TrajectoryPanel(name, drawn, pts.min(axis=0), pts.max(axis=0)))
    return (ref_xy[:, 0], ref_xy[:, 1]), panels


def _past(panels) -> list[str]:
    return [f"{p.method} at h = {r.h:.3g} s" for p in panels for r in p.runs if r.past]


def _operating_point(sweep) -> str:
    point = sweep.manifest.get("trajectory_point") or sweep.manifest.get("paper_point")
    if isinstance(point, dict) and {"vx", "delta"} <= set(point):
        return f" at vx = {point['vx']:g} m/s, delta = {point['delta']:.3g} rad"
    if isinstance(point, dict) and point:
        return " at " + ", ".join(f"{k} = {v:.4g}" for k, v in point.items())
    return " at the paper's operating point"


def state_label(view, state: str) -> str:
    """An axis label: the bicycle's states with their units, any other by name."""
    units = {"X": "m", "Y": "m", "psi": "rad", "vy": "m/s", "r": "rad/s", "t": "s"}
    return f"{state} [{units[state]}]" if (view.vehicle or state == "t") and state in units \
        else state


def _tuned_name(tuned) -> str | None:
    return tuned["method"] if tuned else None


def yaw_rate(sweep, why: str = "", tuned=None) -> Trajectories:
    """Figure 1: the plotted state (the bicycle's yaw rate r [rad/s]) against time t [s],
    each method at several steps; `why`: why this operating point, for the caption."""
    view = sweep.view
    state = view.plot_state
    ref, panels = _trajectory_panels(sweep.trajectories, "t", state)
    past = _past(panels)
    what = "Yaw rate" if state == "r" else f"The state {state} of {view.model}"
    caption = (f"{what} against time for each method at several fixed step sizes (coloured "
               f"by step){_operating_point(sweep)}{f' ({why})' if why else ''}, over the "
               "tight reference (black, "
               "dashed); for the bicycle, the paper's Figure 2. A stable step follows the "
               "reference, and the gap grows with the step; red dotted runs are past the "
               "method's predicted stability limit: they oscillate with growing amplitude "
               "and leave the panel. "
               + (f"Past the limit: {', '.join(past)}." if past
                  else "No sampled run is past its limit (A-stable methods have none)."))
    title = "Yaw rate against time" if state == "r" else f"{state} against time"
    return Trajectories(1, title, caption, "fig1_yaw_rate.png", "t [s]",
                        state_label(view, state), False, ref, panels, _tuned_name(tuned))


def xy_paths(sweep, why: str = "", tuned=None) -> Trajectories:
    """Figure 2: the X-Y path [m] (or, for a model without position, the plane of two of its
    states) of each method at several steps, with the reference; `why` as Figure 1's."""
    view = sweep.view
    xs, ys = view.plane
    ref, panels = _trajectory_panels(sweep.trajectories, xs, ys)
    past = _past(panels)
    past_text = (" Past the limit: " + (", ".join(past) or "none") + "."
                 + (f" The operating point{_operating_point(sweep)}: {why}." if why else ""))
    if view.vehicle:
        caption = ("The vehicle's path in the plane for the same runs as Figure 1; the "
                   "paper's Figure 3. The steady turn of the reference (black, dashed) is a "
                   "circle; a stable step stays on it, a coarse one drifts off it, and a run "
                   "past the stability limit (red, dotted) veers off." + past_text)
    else:
        caption = (f"The same runs as Figure 1 in the plane of {xs} and {ys}: a stable step "
                   "stays near the reference (black, dashed), a run past the stability limit "
                   "(red, dotted) leaves it." + past_text)
    title = "X-Y paths" if view.vehicle else f"{xs}-{ys} phase plane"
    return Trajectories(2, title, caption, "fig2_xy_paths.png", state_label(view, xs),
                        state_label(view, ys), view.vehicle, ref, panels, _tuned_name(tuned))


# Figure 3: stability regions.

def trajectory_eigenvalues(sweep) -> np.ndarray:
    """The eigenvalues [1/s] of the envelope: at each point's initial state, and along its
    reference where each method's predicted limit binds (limits' lam_*_bind, at t_bind)."""
    eig = sweep.eigenvalues
    lim = sweep.limits
    lam = eig["lam_re"].to_numpy() + 1j * eig["lam_im"].to_numpy()
    if "lam_re_bind" in lim:
        bind = lim["lam_re_bind"].to_numpy(float) + 1j * lim["lam_im_bind"].to_numpy(float)
        lam = np.concatenate([lam, bind[np.isfinite(bind)]])
    return lam


def scaled_eigenvalues(sweep, tuned):
    """(h [s] or None, h*lambda of every distinct eigenvalue of the envelope along the
    trajectories (trajectory_eigenvalues) and its conjugate, the (Re, Im) view that holds
    them and the regions' interesting part)."""
    lam = trajectory_eigenvalues(sweep)
    # Regions are symmetric: show both halves, each distinct eigenvalue once.
    lam = np.unique(np.concatenate([lam, lam.conj()]))
    h = float(tuned["h"]) if tuned else None
    z = h * lam if h else np.zeros(0, complex)
    reach = max(4.0, 1.1 * float(np.max(-z.real, initial=0.0)))
    tall = max(3.5, 1.1 * float(np.max(np.abs(z.imag), initial=0.0)))
    return h, z, (-reach, 1.5), (-tall, tall)


def _outside(m, z) -> np.ndarray:
    return ~(np.nan_to_num(amplification_theory(m, z), nan=np.inf) <= 1.0 + 1e-12)


def _boundary(x, y, amp) -> tuple[np.ndarray, np.ndarray]:
    """The |R(z)| = 1 curve(s) on the grid, NaN between pieces."""
    import contourpy
    # Capped: interpolating the level-1 crossing against huge values would bias it.
    amp = np.minimum(np.nan_to_num(amp, nan=2.0, posinf=2.0), 2.0)
    lines = contourpy.contour_generator(x, y, amp).lines(1.0)
    if not lines:
        return np.zeros(0), np.zeros(0)
    # contourpy's stub types lines() for every line type; the default gives (n, 2) arrays
    joined = np.vstack([np.vstack([piece, [np.nan, np.nan]])  # type: ignore[list-item]
                        for piece in lines])
    return joined[:, 0], joined[:, 1]


def stability_regions(sweep, tuned) -> Regions:
    """Figure 3: each method's stability region with h*lambda of the envelope at the tuned h."""
    names = [m for m in method_order(sweep.summary["method"]) if m in METHODS]
    h, z, re, im = scaled_eigenvalues(sweep, tuned)
    panels = []
    for name in names:
        x, y, amp = region_grid(METHODS[name], re=re, im=im, n=REGION_GRID)
        stable = np.nan_to_num(amp, nan=np.inf) <= 1.0
        out = _outside(METHODS[name], z) if z.size else np.zeros(0, bool)
        panels.append(RegionPanel(name, x, y, stable, _boundary(x, y, amp), out))
    if h:
        safe = [p.method for p in panels if not p.outside.any() and _measured_ok(sweep,
                                                                                p.method, h)]
        caption = (f"Stability region of each method (shaded: |R(z)| <= 1, or the root "
                   f"condition for multistep methods) with h*lambda at the tuned step h = "
                   f"{h:g} s for every eigenvalue of df/dx at the initial state of each of the "
                   f"envelope's operating points and, along each point's reference, where "
                   f"each method's predicted limit binds (blue dots inside, red crosses "
                   f"outside; the tuned method {tuned['method']} has a bold title). A method "
                   f"is stable at this step on the whole envelope, along the trajectories, "
                   f"when every point lies in its region and the step is at most its smallest "
                   f"measured limit: {', '.join(safe) or 'none'}.")
        outside = _outside(METHODS[tuned["method"]], z)
    else:
        caption = ("Stability region of each method (shaded: |R(z)| <= 1, or the root "
                   "condition for multistep methods). No tuned config was given, so no "
                   "h*lambda points are drawn.")
        outside = np.zeros(0, bool)
    return Regions(3, "Stability regions and h*lambda at the tuned step", caption,
                   "fig3_stability_regions.png", h, z, re, im, _tuned_name(tuned), outside,
                   panels)


def _measured_ok(sweep, name: str, h: float) -> bool:
    """h [s] is at most the method's smallest measured limit (NaN: none measured)."""
    lim = sweep.limits[sweep.limits["method"] == name]["h_meas"].to_numpy(float)
    return not (lim < h).any()


# Figure 4: error against step.

def _verdict_text(verdicts, how: str) -> str:
    if not verdicts:
        return ""
    return (f" The steps asked about with --verdict are {how} dash-dotted lines on their "
            "method's panel: " + ", ".join(f"{n} at {h:g} s" for n, h in verdicts) + ".")


def error_vs_step(sweep, verdicts=()) -> ErrorVsStep:
    """Figure 4: worst error norm against h [s], log-log, with declared slopes; each
    (method, h) of `verdicts` a vertical line on its method's panel."""
    verdicts = list(verdicts)
    table = worst_case(sweep.runs)
    table = table[np.isfinite(table["err"]) & (table["err"] > 0)]
    summary = sweep.summary.set_index("method")
    panels = []
    for name in method_order(table["method"]):
        rows = table[table["method"] == name]
        h, err = rows["h"].to_numpy(float), rows["err"].to_numpy(float)
        order = summary["order_declared"].get(name)
        slope = None
        if pd.notna(order) and len(h):
            # Slope line through the middle point: the eye compares slopes, not offsets.
            i = len(h) // 2
            hh = np.array([h.min(), h.max()])
            slope = (hh, err[i] * (hh / h[i]) ** int(order), int(order))
        fit = float(summary["order_fit_median"].get(name, np.nan))
        panels.append(ErrorPanel(name, h, err, fit, slope,
                                 [vh for vname, vh in verdicts if vname == name]))
    errs = sweep.view.error_states
    final = sweep.manifest.get("error_estimate") == ESTIMATES["final"]
    over = "at the end of the run" if final else "over the run"
    caption = (f"Worst error over the envelope (largest over its operating points, {over}, "
               f"of |error| / scale of the error states {', '.join(errs)}, against the "
               "reference; the error the sweep fits its orders on) against step "
               "size, log-log, for every step stable at all points; the dashed line has the "
               "slope of the method's declared order, and the title gives the fitted order "
               "(median over points). In the asymptotic range the measured line is parallel "
               "to the dashed one; at small steps it may flatten at the reference's accuracy "
               "or round-off." + _verdict_text(verdicts, "vertical"))
    return ErrorVsStep(4, "Error against step size", caption, "fig4_error_vs_step.png",
                       ERROR_NORM, panels, verdicts)


# Figure 5: work-precision.

def error_axis(view) -> str:
    unit = f" [{view.error_unit}]" if view.error_unit else ""
    return f"worst {view.error_label} over the envelope{unit}"


def _timing_spread(runs: pd.DataFrame) -> pd.DataFrame:
    """Per (method, h): the rounds' median and largest wall time per simulated second [s]
    (median over the operating points, as worst_case takes the minimum's)."""
    cols = ["time_per_step_median_s", "time_per_step_max_s"]
    if not set(cols) <= set(runs.columns):
        return pd.DataFrame(columns=["method", "h", *cols])      # a sweep timed once
    g = runs.groupby(["method", "h"])[cols].median().reset_index()
    for c in cols:
        g[c] = g[c] / g["h"]
    return g


def _work_line(name, rows) -> WorkLine:
    def col(c):
        return rows[c].to_numpy(float)
    return WorkLine(name, col("h"), col("worst"), col("evals_per_s"), col("time_per_s"),
                    col("time_per_step_median_s"), col("time_per_step_max_s"))


def work_precision(sweep, tuned=None, number: int = 5,
                   problem: str | None = None) -> WorkPrecision:
    """Figure 5 (or `number`): worst error (position [m], or the error norm) against RHS
    evaluations and wall time per simulated second; of one `problem` of a suite when named."""
    view = sweep.view.with_tolerance(tuned)
    unit = f" {view.error_unit}" if view.error_unit else ""
    table = worst_case(sweep.runs, view.error).merge(_timing_spread(sweep.runs),
                                                     on=["method", "h"], how="left")
    lines = [_work_line(n, table[table["method"] == n]) for n in method_order(table["method"])]
    pick = None
    if tuned:
        chosen = table[(table["method"] == tuned["method"])
                       & np.isclose(table["h"], float(tuned["h"]))]
        pick = _work_line(tuned["method"], chosen)
    caption = ((f"Problem {problem}. " if problem else "")
               + f"Work-precision: worst {view.error_label} over the envelope against cost, "
               "one line per method, one point per step size (stable at every operating "
               "point), against two costs: right-hand-side evaluations per simulated second, "
               "and measured wall time per simulated second (the fastest of the sweep's timed "
               "rounds; the interactive figure's bars reach the median round). Lower-left is "
               "better; the cheapest method at a given error is the leftmost line at that "
               "height"
               + (", and the tuned choice (star) is the cheapest point under the tolerance "
                  "(dotted) within the stability margin." if tuned else "."))
    return WorkPrecision(
        number, "Work-precision" + (f": {problem}" if problem else ""), caption,
        f"fig{number}_work_precision" + (f"_{problem}" if problem else "") + ".png",
        error_axis(view), view.error_label, unit, lines, _tuned_name(tuned),
        float(tuned["h"]) if tuned else None, tolerance(tuned), pick)


# Figure 6: largest stable step against the envelope.

def solver_limited(limits: pd.DataFrame) -> np.ndarray:
    """Which limits rows a failed nonlinear solve ended (limit_cause; none in a folder swept
    before it was recorded)."""
    if "limit_cause" not in limits:
        return np.zeros(len(limits), bool)
    return (limits["limit_cause"] == "solver failed").to_numpy()


def variable_label(var: str) -> str:
    units = {"vx": "m/s", "v": "m/s", "delta": "rad"}
    return f"{var} [{units[var]}]" if var in units else var


def stable_step_vs_speed(sweep, verdicts=()) -> StableStep:
    """Figure 6: largest stable step [s] over the first envelope variable (the bicycle's vx
    [m/s]), one curve per value of the second; predicted and measured; each (method, h) of
    `verdicts` a horizontal line on its method's panel."""
    verdicts = list(verdicts)
    limits = sweep.limits
    view = sweep.view
    names = method_order(limits["method"])
    xvar = view.variables[0]
    cvar = view.variables[1] if len(view.variables) > 1 else None
    values = [float(v) for v in sorted(limits[cvar].unique())] if cvar else [None]
    h_tried = sweep.runs.groupby("method")["h"].max()
    panels, unlimited = [], []
    for name in names:
        rows = limits[limits["method"] == name]
        curves = []
        for value in values:
            sub = (rows if cvar is None else rows[rows[cvar] == value]).sort_values(xvar)
            meas = sub["h_meas"].to_numpy(float)
            found = np.isfinite(meas) & (meas > 0)
            solver = solver_limited(sub)
            tried = float(h_tried[name]) if name in h_tried else None
            curves.append(LimitCurve(
                value, sub[xvar].to_numpy(float), sub["h_pred"].to_numpy(float), meas,
                found & ~solver, found & solver,
                # No blow-up at any tried step: the true limit lies above the largest one.
                ~found if tried is not None else np.zeros(len(sub), bool), tried))
        limited = bool(np.isfinite(rows["h_pred"]).any())
        if not limited:
            unlimited.append(name)
        panels.append(LimitPanel(name, curves, not limited,
                                 [vh for vname, vh in verdicts if vname == name]))
    failed = sorted(set(limits["method"][solver_limited(limits)]), key=names.index)
    bicycle = ("; the limit grows with speed because the eigenvalues scale like 1/vx, so the "
               "slowest speed of the envelope sets the step" if xvar == "vx" else "")
    caption = (f"Largest stable step against {xvar}, per method"
               + (f" and {cvar}" if cvar else "") + ": lines are the "
               "prediction from the eigenvalues of df/dx along the reference and the "
               "stability region, circles the step where the sweep measured blow-up; a "
               "triangle means no blow-up up to the largest step tried; a cross is the "
               "largest step where every nonlinear solve converged, where a solve failed "
               "before any blow-up: the solver's limit, not the method's. Circles on the "
               f"lines confirm the frozen-Jacobian theory{bicycle}."
               + (f" A-stable, no limit predicted: {', '.join(unlimited)}." if unlimited
                  else "")
               + (f" A solve failed first at some points of: {', '.join(failed)}." if failed
                  else "") + _verdict_text(verdicts, "horizontal"))
    xs = limits[xvar].to_numpy(float)
    span = (float(np.nanmin(xs)), float(np.nanmax(xs))) if len(xs) else (0.0, 0.0)
    return StableStep(6, f"Measured and predicted largest stable step against {xvar}",
                      caption, "fig6_stable_step_vs_speed.png", xvar, cvar,
                      variable_label(xvar), values, panels, bool(failed), verdicts, span)


# Figure 7: planned scenarios.

def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in str(text))


def _plan_caption(plan) -> str:
    rec, st = plan.record, plan.record["stats"]

    def num(key, unit, fmt="{:.3g}"):
        v = st.get(key)
        return f"{fmt.format(v)} {unit}".strip() if isinstance(v, (int, float)) else "none"
    return (f"{plan.name}: {rec['status']}"
            + (f" ({rec['reason']})" if rec.get("reason") else "")
            + f"; {st.get('method', '?')} at h = {num('h', 's', '{:.4g}')}, seed "
            f"{st.get('seed', '?')};"
            f" {num('expansions', 'expansions', '{}')}, {num('nodes', 'nodes', '{}')}; tree "
            f"search time {num('search_s', 's')}, connection solve time "
            f"{num('connect_s', 's')}; path length {num('path_length_m', 'm')}, connection "
            f"manoeuvre duration {num('connect_tf_s', 's')}.")


def _plan_map(plan) -> PlanMap:
    rec, occ = plan.record, plan.occupied
    res, (ox, oy) = float(rec["map"]["resolution"]), rec["map"]["origin"]
    extent = (float(ox), float(ox) + occ.shape[1] * res, float(oy),
              float(oy) + occ.shape[0] * res)
    path = np.asarray(rec["path"], dtype=float) if rec["path"] else None
    return PlanMap(plan.name, str(rec["status"]), occ, extent,
                   [np.asarray(e, dtype=float) for e in rec["tree"]], path,
                   tuple(map(float, rec["start"][:3])), tuple(map(float, rec["goal"][:3])),
                   _plan_caption(plan), f"fig7_plan_{_slug(plan.name)}.png")


def plans(plan_list) -> Plans:
    """Figure 7: every planned scenario, obstacles black, tree blue, path red."""
    maps = [_plan_map(p) for p in plan_list]
    caption = ("Each planned scenario as the paper drew its results: obstacles black, the "
               "explored tree blue, the final path (tree part and connection) red, start "
               "(circle) and goal (star) green with heading arrows. A red line from start to "
               "goal means a plan was found; its sub-caption gives the search effort."
               if maps else "No plan folders were given, so no scenario is drawn.")
    return Plans(7, "Planned scenarios", caption, maps)
