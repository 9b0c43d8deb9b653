"""The report's figures, one function each: draw from loaded result tables, save a PNG into
the report folder and return a `Shown` record with the caption (what it shows, what to read).
Matplotlib runs headless through the Agg canvas, without pyplot's global state."""
from __future__ import annotations

import io
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from stepzoo.bench.sweep_config import ESTIMATES
from stepzoo.integrators import METHODS
from stepzoo.reports.load import tolerance
from stepzoo.output import atomic_write
from stepzoo.integrators.stability import amplification_theory, region_grid

# Log-axis tick labels go through mathtext, which probes STIX fonts that some matplotlib
# wheels do not ship; the fallback to DejaVu Sans renders the same, so the probe's
# warnings (20 lines per report) are noise.
logging.getLogger("matplotlib.font_manager").setLevel(logging.ERROR)

DPI = 100
NCOLS = 4
PANEL_IN = (3.2, 2.5)          # [inch] one small-multiple panel
PANEL_ASPECT = 1.35            # width / height of a panel's plotting area, labels aside
BLOWUP_FACTOR = 3.0            # a sample run this far beyond the reference's range diverged
STABLE_FILL, UNSTABLE = "#cfe3f5", "#d62728"
VERDICT = "#ff7f0e"            # the steps asked about with `stepzoo report --verdict`


@dataclass(frozen=True)
class Shown:
    """A numbered figure of the report: its PNG files (name, sub-caption) and caption."""
    number: int
    title: str
    caption: str
    images: list


def _save(fig: Figure, out_dir: Path, name: str) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format=Path(name).suffix[1:], dpi=DPI, bbox_inches="tight")
    atomic_write(out_dir / name, buf.getvalue())       # a full disk names the file
    return name


def _panels(n: int, ncols: int = NCOLS, panel=PANEL_IN, **kwargs):
    """(figure, axes list of length n) for small multiples; unused slots are hidden, and
    with n = 0 one empty panel says so."""
    ncols = max(1, min(ncols, n))
    nrows = max(1, math.ceil(n / ncols))
    fig = Figure(figsize=(panel[0] * ncols, panel[1] * nrows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False, **kwargs).ravel()
    if n == 0:
        axes[0].text(0.5, 0.5, "nothing to show", ha="center", va="center")
        axes[0].set_axis_off()
        return fig, []
    for ax in axes[n:]:
        ax.set_visible(False)
    for ax in axes[:n]:
        # Shared axes hide inner tick labels, which leaves a short last row unlabelled.
        ax.tick_params(labelbottom=True, labelleft=True)
    return fig, list(axes[:n])


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


def _sample_runs(traj: pd.DataFrame):
    """(reference run, {method: [(h, run, past its stability limit)]}) of the trajectories."""
    ref = traj[traj["method"] == "reference"].sort_values("t")
    states = [c for c in traj.columns if c not in ("method", "h", "t", "past_limit")]
    bound = {c: BLOWUP_FACTOR * max(np.abs(ref[c]).max(), 1e-9) for c in states}
    runs = {}
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


def _trajectory_figure(traj, xcol, ycol, xlabel, ylabel, equal):
    """Per-method panels of ycol against xcol at each sampled step, over the reference.
    Returns (figure, names of the (method, h) runs past the stability limit)."""
    ref, runs = _sample_runs(traj)
    fig, axes = _panels(len(runs), sharex=not equal)
    past_runs = []
    for ax, (name, samples) in zip(axes, runs.items()):
        stable_h = [h for h, _, past in samples if not past]
        colours = dict(zip(stable_h, _shades(len(stable_h))))
        shown = [ref[[xcol, ycol]].to_numpy()]
        for h, run, past in samples:
            xy = run[[xcol, ycol]].to_numpy()
            if past:
                past_runs.append(f"{name} at h = {h:.3g} s")
                ax.plot(xy[:, 0], xy[:, 1], color=UNSTABLE, ls=":", lw=1.2,
                        label=f"h={h:.3g} s, past limit")
            else:
                shown.append(xy)
                ax.plot(xy[:, 0], xy[:, 1], color=colours[h], lw=1.2, label=f"h={h:.3g} s")
        ax.plot(ref[xcol], ref[ycol], color="black", ls="--", lw=1.0, label="reference")
        # Limits from the reference and the stable runs: a blown-up run leaves the panel.
        pts = np.vstack(shown)
        pts = pts[np.isfinite(pts).all(axis=1)]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        half = 0.54 * np.maximum(hi - lo, 1e-6)
        if equal:
            # Widen the short side to the panel's shape, so equal axes fill the panel.
            half = np.maximum(half, half[::-1] * np.array([PANEL_ASPECT, 1 / PANEL_ASPECT]))
            ax.set_aspect("equal", adjustable="box")
        mid = 0.5 * (lo + hi)
        ax.set_xlim(mid[0] - half[0], mid[0] + half[0])
        ax.set_ylim(mid[1] - half[1], mid[1] + half[1])
        ax.set_title(name, fontsize=10)
        ax.set_xlabel(xlabel, fontsize=8)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.tick_params(which="both", labelsize=7)
        ax.legend(fontsize=6, loc="best")
    return fig, past_runs


def _shades(n):
    return [colormaps["viridis"](v) for v in np.linspace(0.1, 0.75, max(n, 1))][:n]


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


def trajectory_title(view) -> str:
    return "Yaw rate against time" if view.plot_state == "r" else \
        f"{view.plot_state} against time"


def yaw_rate(sweep, out_dir: Path, why: str = "") -> Shown:
    """Figure 1: the plotted state (the bicycle's yaw rate r [rad/s]) against time t [s],
    each method at several steps; `why`: why this operating point, for the caption."""
    view = sweep.view
    state = view.plot_state
    fig, past = _trajectory_figure(sweep.trajectories, "t", state, "t [s]",
                                   state_label(view, state), equal=False)
    name = _save(fig, out_dir, "fig1_yaw_rate.png")
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
    return Shown(1, trajectory_title(view), caption, [(name, "")])


def plane_title(view) -> str:
    return "X-Y paths" if view.vehicle else f"{view.plane[0]}-{view.plane[1]} phase plane"


def xy_paths(sweep, out_dir: Path, why: str = "") -> Shown:
    """Figure 2: the X-Y path [m] (or, for a model without position, the plane of two of its
    states) of each method at several steps, with the reference; `why` as Figure 1's."""
    view = sweep.view
    xs, ys = view.plane
    fig, past = _trajectory_figure(sweep.trajectories, xs, ys, state_label(view, xs),
                                   state_label(view, ys), equal=view.vehicle)
    name = _save(fig, out_dir, "fig2_xy_paths.png")
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
    return Shown(2, plane_title(view), caption, [(name, "")])


def scaled_eigenvalues(sweep, tuned):
    """(h [s] or None, h*lambda of every distinct eigenvalue of the envelope and its
    conjugate, the (Re, Im) view that holds them and the regions' interesting part)."""
    eig = sweep.eigenvalues
    lam = eig["lam_re"].to_numpy() + 1j * eig["lam_im"].to_numpy()
    # Regions are symmetric: show both halves, each distinct eigenvalue once.
    lam = np.unique(np.concatenate([lam, lam.conj()]))
    h = float(tuned["h"]) if tuned else None
    z = h * lam if h else np.zeros(0, complex)
    reach = max(4.0, 1.1 * float(np.max(-z.real, initial=0.0)))
    tall = max(3.5, 1.1 * float(np.max(np.abs(z.imag), initial=0.0)))
    return h, z, (-reach, 1.5), (-tall, tall)


def stability_regions(sweep, tuned, out_dir: Path) -> Shown:
    """Figure 3: each method's stability region with h*lambda of the envelope at the tuned h."""
    names = [m for m in method_order(sweep.summary["method"]) if m in METHODS]
    h, z, re, im = scaled_eigenvalues(sweep, tuned)
    fig, axes = _panels(len(names), sharex=True, sharey=True)
    outside_by = {}
    for ax, name in zip(axes, names):
        m = METHODS[name]
        x, y, amp = region_grid(m, re=re, im=im, n=181)
        stable = np.nan_to_num(amp, nan=np.inf) <= 1.0
        ax.contourf(x, y, stable.astype(float), levels=[0.5, 1.5], colors=[STABLE_FILL])
        ax.contour(x, y, stable.astype(float), levels=[0.5], colors="#1f4e79", linewidths=0.8)
        ax.axhline(0, color="grey", lw=0.5)
        ax.axvline(0, color="grey", lw=0.5)
        title = name
        if z.size:
            out = ~(np.nan_to_num(amplification_theory(m, z), nan=np.inf) <= 1.0 + 1e-12)
            outside_by[name] = int(out.sum())
            ax.plot(z.real[~out], z.imag[~out], ".", color="#1f77b4", ms=3)
            ax.plot(z.real[out], z.imag[out], "x", color=UNSTABLE, ms=4)
            title += f" ({out.sum()} of {z.size} outside)" if out.any() else " (all inside)"
        weight = "bold" if tuned and name == tuned["method"] else "normal"
        ax.set_title(title, fontsize=9, fontweight=weight)
        ax.set_xlabel("Re(h lambda)", fontsize=8)
        ax.set_ylabel("Im(h lambda)", fontsize=8)
        ax.tick_params(which="both", labelsize=7)
    name = _save(fig, out_dir, "fig3_stability_regions.png")
    if h:
        safe = [n for n, k in outside_by.items() if k == 0]
        caption = (f"Stability region of each method (shaded: |R(z)| <= 1, or the root "
                   f"condition for multistep methods) with h*lambda for every eigenvalue of "
                   f"df/dx at the initial state of each of the envelope's operating points at "
                   f"the tuned step h = "
                   f"{h:g} s (blue dots inside, red crosses outside; the tuned method "
                   f"{tuned['method']} has a bold title). A method is stable at this step on "
                   f"the whole envelope when every point lies in its region: "
                   f"{', '.join(safe) or 'none'}.")
    else:
        caption = ("Stability region of each method (shaded: |R(z)| <= 1, or the root "
                   "condition for multistep methods). No tuned config was given, so no "
                   "h*lambda points are drawn.")
    return Shown(3, "Stability regions and h*lambda at the tuned step", caption, [(name, "")])


ERROR_NORM = "worst error (error states over their scales)"


def verdict_label(name: str, h: float) -> str:
    return f"{name} at h = {h:g} s (verdict)"


def error_vs_step(sweep, out_dir: Path, verdicts=()) -> Shown:
    """Figure 4: worst error norm against h [s], log-log, with declared slopes; each
    (method, h) of `verdicts` a vertical line on its method's panel."""
    table = worst_case(sweep.runs)
    table = table[np.isfinite(table["err"]) & (table["err"] > 0)]
    names = method_order(table["method"])
    summary = sweep.summary.set_index("method")
    fig, axes = _panels(len(names), sharex=True, sharey=True)
    for ax, name in zip(axes, names):
        rows = table[table["method"] == name]
        h, err = rows["h"].to_numpy(), rows["err"].to_numpy()
        ax.loglog(h, err, "o-", color="#1f77b4", ms=3, lw=1.0, label="measured")
        order = summary["order_declared"].get(name)
        if pd.notna(order) and len(h):
            # Slope line through the middle point: the eye compares slopes, not offsets.
            i = len(h) // 2
            hh = np.array([h.min(), h.max()])
            ax.loglog(hh, err[i] * (hh / h[i]) ** int(order), "--", color="grey", lw=1.0,
                      label=f"slope {int(order)} (declared)")
        for vname, vh in verdicts:
            if vname == name:
                ax.axvline(vh, color=VERDICT, ls="-.", lw=1.2, label=verdict_label(vname, vh))
        fit = float(summary["order_fit_median"].get(name, np.nan))
        ax.set_title(f"{name}" + (f" (fit {fit:.2f})" if np.isfinite(fit) else ""), fontsize=9)
        ax.set_xlabel("h [s]", fontsize=8)
        ax.set_ylabel(ERROR_NORM, fontsize=8)
        ax.tick_params(which="both", labelsize=7)
        ax.legend(fontsize=6)
    name = _save(fig, out_dir, "fig4_error_vs_step.png")
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
    return Shown(4, "Error against step size", caption, [(name, "")])


def _verdict_text(verdicts, how: str) -> str:
    if not verdicts:
        return ""
    return (f" The steps asked about with --verdict are {how} dash-dotted lines on their "
            "method's panel: " + ", ".join(f"{n} at {h:g} s" for n, h in verdicts) + ".")


def _styles(names):
    cmap = colormaps["tab20"]
    marks = "os^vDP*Xh<>p"
    return {n: (cmap(i % 20), marks[i % len(marks)]) for i, n in enumerate(names)}


def error_axis(view) -> str:
    unit = f" [{view.error_unit}]" if view.error_unit else ""
    return f"worst {view.error_label} over the envelope{unit}"


def work_precision(sweep, tuned, out_dir: Path, number: int = 5,
                   problem: str | None = None) -> Shown:
    """Figure 5 (or `number`): worst error (position [m], or the error norm) against RHS
    evaluations and wall time per simulated second; of one `problem` of a suite when named."""
    view = sweep.view.with_tolerance(tuned)
    tol = tolerance(tuned)
    unit = f" {view.error_unit}" if view.error_unit else ""
    table = worst_case(sweep.runs, view.error)
    names = method_order(table["method"])
    style = _styles(names)
    fig = Figure(figsize=(12.5, 5.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2, sharey=True)
    for ax, col, label in zip(axes, ["evals_per_s", "time_per_s"],
                              ["right-hand-side evaluations per simulated second",
                               "measured wall time per simulated second [s]"]):
        for name in names:
            rows = table[table["method"] == name]
            colour, mark = style[name]
            ax.loglog(rows[col], rows["worst"], marker=mark, color=colour, ms=4, lw=1.0,
                      label=name)
        if tuned:
            ax.axhline(tol, color="black", ls=":", lw=1.0)
            pick = table[(table["method"] == tuned["method"])
                         & np.isclose(table["h"], float(tuned["h"]))]
            ax.loglog(pick[col], pick["worst"], "*", color="black", ms=14, mfc="none")
        ax.set_xlabel(label)
        ax.grid(True, which="major", lw=0.3)
    axes[0].set_ylabel(error_axis(view))
    handles, labels = axes[0].get_legend_handles_labels()
    if tuned:
        handles += [Line2D([], [], color="black", ls=":"),
                    Line2D([], [], marker="*", color="black", ls="", ms=12, mfc="none")]
        labels += [f"tolerance {tol:g}{unit}", "tuned choice"]
    fig.legend(handles, labels, loc="outside right center", fontsize=8)
    name = _save(fig, out_dir, f"fig{number}_work_precision"
                 + (f"_{problem}" if problem else "") + ".png")
    caption = ((f"Problem {problem}. " if problem else "")
               + f"Work-precision: worst {view.error_label} over the envelope against cost, one line "
               "per method, one point per step size (stable at every operating point), against "
               "two costs: right-hand-side evaluations per simulated second, and measured wall "
               "time per simulated second (the fastest of the sweep's timed rounds; the "
               "interactive figure's bars reach the median round). Lower-left is better; the cheapest method at a given "
               "error is the leftmost line at that height"
               + (", and the tuned choice (star) is the cheapest point under the tolerance "
                  "(dotted) within the stability margin." if tuned else "."))
    return Shown(number, "Work-precision" + (f": {problem}" if problem else ""), caption,
                 [(name, "")])


def solver_limited(limits: pd.DataFrame) -> np.ndarray:
    """Which limits rows a failed nonlinear solve ended (limit_cause; none in a folder swept
    before it was recorded)."""
    if "limit_cause" not in limits:
        return np.zeros(len(limits), bool)
    return (limits["limit_cause"] == "solver failed").to_numpy()


def envelope_axes(view, limits):
    """(x variable, colour variable or None, the colour variable's values)."""
    xvar = view.variables[0]
    cvar = view.variables[1] if len(view.variables) > 1 else None
    values = sorted(limits[cvar].unique()) if cvar else [None]
    return xvar, cvar, values


def variable_label(var: str) -> str:
    units = {"vx": "m/s", "v": "m/s", "delta": "rad"}
    return f"{var} [{units[var]}]" if var in units else var


def limit_title(view) -> str:
    return f"Measured and predicted largest stable step against {view.variables[0]}"


def stable_step_vs_speed(sweep, out_dir: Path, verdicts=()) -> Shown:
    """Figure 6: largest stable step [s] over the first envelope variable (the bicycle's vx
    [m/s]), one line per value of the second; predicted (lines) and measured (dots); each
    (method, h) of `verdicts` a horizontal line on its method's panel."""
    limits = sweep.limits
    view = sweep.view
    names = method_order(limits["method"])
    xvar, cvar, deltas = envelope_axes(view, limits)
    colours = dict(zip(deltas, _shades(len(deltas))))
    h_tried = sweep.runs.groupby("method")["h"].max()
    fig, axes = _panels(len(names), sharex=True, sharey=True)
    unlimited = []
    for ax, name in zip(axes, names):
        rows = limits[limits["method"] == name]
        if not np.isfinite(rows["h_pred"]).any():
            unlimited.append(name)
            ax.text(0.5, 0.5, "no limit predicted\n(A-stable)", ha="center", va="center",
                    transform=ax.transAxes, fontsize=8)
        for delta in deltas:
            sub = (rows if cvar is None else rows[rows[cvar] == delta]).sort_values(xvar)
            colour = colours[delta]
            finite = np.isfinite(sub["h_pred"])
            ax.plot(sub[xvar][finite], sub["h_pred"][finite], "-", color=colour, lw=1.2,
                    label=f"{cvar}={delta:.3g}" if cvar else "predicted")
            meas = sub["h_meas"].to_numpy(dtype=float)
            ok = np.isfinite(meas) & (meas > 0)
            solver = solver_limited(sub)
            ax.plot(sub[xvar][ok & ~solver], meas[ok & ~solver], "o", color=colour, ms=4,
                    mfc="none")
            ax.plot(sub[xvar][ok & solver], meas[ok & solver], "X", color=colour, ms=6)
            if (~ok).any() and name in h_tried:
                # No blow-up at any tried step: the true limit lies above the largest one.
                ax.plot(sub[xvar][~ok], np.full((~ok).sum(), h_tried[name]), "^",
                        color=colour, ms=5)
        for vname, vh in verdicts:
            if vname == name:
                ax.axhline(vh, color=VERDICT, ls="-.", lw=1.2, label=verdict_label(vname, vh))
        ax.set_yscale("log")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(variable_label(xvar), fontsize=8)
        ax.set_ylabel("largest stable h [s]", fontsize=8)
        ax.tick_params(which="both", labelsize=7)
    failed = sorted(set(limits["method"][solver_limited(limits)]), key=names.index)
    if axes:
        handles, labels = axes[0].get_legend_handles_labels()
        marks = [("o", "none", "blow-up measured"), ("^", None, "no blow-up up to the "
                 "largest step tried")] + ([("X", None, "a nonlinear solve failed")]
                                          if failed else [])
        for mark, face, label in marks:
            handles.append(Line2D([], [], marker=mark, color="grey", mfc=face, ls=""))
            labels.append(label)
        axes[0].legend(handles, labels, fontsize=6)
        for ax, name in zip(axes[1:], names[1:]):
            if any(vname == name for vname, _ in verdicts):
                ax.legend(fontsize=6)
    name = _save(fig, out_dir, "fig6_stable_step_vs_speed.png")
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
    return Shown(6, limit_title(view), caption, [(name, "")])


def _plan_png(plan, out_dir: Path) -> str:
    rec, occ = plan.record, plan.occupied
    res, (ox, oy) = float(rec["map"]["resolution"]), rec["map"]["origin"]
    extent = (ox, ox + occ.shape[1] * res, oy, oy + occ.shape[0] * res)
    aspect = (extent[3] - extent[2]) / (extent[1] - extent[0])
    fig = Figure(figsize=(7.0, min(max(7.0 * aspect, 3.0), 10.0)), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.imshow(occ, cmap="gray_r", vmin=0, vmax=1, origin="lower", extent=extent,
              interpolation="nearest")
    ax.add_collection(LineCollection(rec["tree"], colors="blue", linewidths=0.5,
                                     label="tree"))
    if rec["path"]:
        path = np.asarray(rec["path"], dtype=float)
        ax.plot(path[:, 1], path[:, 2], color="red", lw=2.0, label="path")
    arrow = 0.04 * (extent[1] - extent[0])          # heading arrows [m], sized to the map
    for pose, marker, label in ((rec["start"], "o", "start"), (rec["goal"], "*", "goal")):
        ax.plot(pose[0], pose[1], marker, color="#2ca02c", ms=10, mec="black", label=label)
        ax.arrow(pose[0], pose[1], arrow * math.cos(pose[2]), arrow * math.sin(pose[2]),
                 width=arrow / 12, color="#2ca02c", length_includes_head=True)
    ax.set(xlim=extent[:2], ylim=extent[2:], xlabel="X [m]", ylabel="Y [m]",
           title=f"{plan.name}: {rec['status']}")
    ax.set_aspect("equal")
    ax.legend(fontsize=8, loc="best")
    return _save(fig, out_dir, f"fig7_plan_{_slug(plan.name)}.png")


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


def plans(plan_list, out_dir: Path) -> Shown:
    """Figure 7: every planned scenario, obstacles black, tree blue, path red."""
    images = [(_plan_png(p, out_dir), _plan_caption(p)) for p in plan_list]
    caption = ("Each planned scenario as the paper drew its results: obstacles black, the "
               "explored tree blue, the final path (tree part and connection) red, start "
               "(circle) and goal (star) green with heading arrows. A red line from start to "
               "goal means a plan was found; its sub-caption gives the search effort."
               if images else "No plan folders were given, so no scenario is drawn.")
    return Shown(7, "Planned scenarios", caption, images)
