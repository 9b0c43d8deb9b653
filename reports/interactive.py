"""The report's interactive figures: Plotly versions of Figures 1-7, drawn from the same tables
as the static ones, to zoom, hover for exact values and click a method in the legend to hide
or show it (a double click shows it alone). Each function returns Plotly figures; `divs` turns
them into HTML fragments that need plotly.js once in the page (`plotly_js`), so the page
works offline."""
from __future__ import annotations

import base64
import io

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from plotly.colors import qualitative
from plotly.offline import get_plotlyjs
from plotly.subplots import make_subplots

from stepzoo.integrators import METHODS
from stepzoo.integrators.stability import amplification_theory, region_grid
from stepzoo.reports.figures import (ERROR_NORM, _sample_runs, envelope_axes, error_axis,
                                     method_order, scaled_eigenvalues, solver_limited,
                                     state_label, variable_label, verdict_label, worst_case)
from stepzoo.reports.load import tolerance

HEIGHT_PX = 460
MAX_POINTS = 400          # points kept per trajectory trace: enough for the eye and the hover
REFERENCE = dict(color="black", dash="dash", width=1.5)
UNSTABLE = "#d62728"
VERDICT = "#ff7f0e"
DASHES = ("solid", "dash", "dot", "dashdot", "longdash", "longdashdot")
CONFIG = {"responsive": True, "displaylogo": False, "scrollZoom": False,
          "modeBarButtonsToRemove": ["select2d", "lasso2d"]}


def plotly_js() -> str:
    """The plotly.js library, to be inlined once in the page."""
    return get_plotlyjs()


def divs(figures: list, prefix: str) -> list[str]:
    """HTML fragments of `figures` (ids prefix-1, prefix-2, ...), without plotly.js."""
    return [fig.to_html(full_html=False, include_plotlyjs=False, config=CONFIG,
                        div_id=f"{prefix}-{i}", default_width="100%",
                        default_height=f"{fig.layout.height or HEIGHT_PX}px")
            for i, fig in enumerate(figures, 1)]


def _colours(names) -> dict:
    palette = qualitative.Dark24
    return {n: palette[i % len(palette)] for i, n in enumerate(names)}


def _layout(fig: go.Figure, xtitle: str, ytitle: str, *, logx=False, logy=False,
            height=HEIGHT_PX) -> go.Figure:
    # Legend below the plot: on a phone a legend beside it would take the plot's width.
    fig.update_layout(template="plotly_white", height=height, hovermode="closest",
                      margin=dict(l=60, r=10, t=30, b=10),
                      legend=dict(orientation="h", yanchor="top", y=-0.15, x=0,
                                  groupclick="togglegroup", font=dict(size=11)))
    fig.update_xaxes(title_text=xtitle, type="log" if logx else "linear",
                     exponentformat="power", showline=True, linecolor="#888")
    fig.update_yaxes(title_text=ytitle, type="log" if logy else "linear",
                     exponentformat="power", showline=True, linecolor="#888")
    return fig


def _thin(df: pd.DataFrame) -> pd.DataFrame:
    """At most MAX_POINTS rows, evenly spread, the last one kept."""
    if len(df) <= MAX_POINTS:
        return df
    keep = np.unique(np.linspace(0, len(df) - 1, MAX_POINTS).round().astype(int))
    return df.iloc[keep]


def _shown_first(names, tuned) -> set:
    """Methods drawn at first in the crowded trajectory figures: the tuned one, else the
    first three; the others are a click away in the legend."""
    if tuned and tuned["method"] in names:
        return {tuned["method"]}
    return set(list(names)[:3])


def _trajectories(sweep, tuned, xcol, ycol, equal) -> go.Figure:
    ref, runs = _sample_runs(sweep.trajectories)
    colours = _colours(runs)
    shown = _shown_first(runs, tuned)
    fig = go.Figure()
    xlabel, ylabel = state_label(sweep.view, xcol), state_label(sweep.view, ycol)
    hover = f"%{{meta}}<br>{xlabel} = %{{x:.6g}}<br>{ylabel} = %{{y:.6g}}<extra></extra>"
    ref_t = _thin(ref)
    fig.add_trace(go.Scatter(x=ref_t[xcol], y=ref_t[ycol], mode="lines", name="reference",
                             line=REFERENCE, meta="reference", hovertemplate=hover))
    box = [ref[[xcol, ycol]].to_numpy()]
    for name, samples in runs.items():
        for k, (h, run, past) in enumerate(samples):
            run = _thin(run.replace([np.inf, -np.inf], np.nan))
            label = f"{name}, h = {h:.4g} s" + (" (past the limit)" if past else "")
            line = dict(color=UNSTABLE, dash="dot", width=1.5) if past else \
                dict(color=colours[name], dash=DASHES[k % len(DASHES)], width=1.5)
            fig.add_trace(go.Scatter(
                x=run[xcol], y=run[ycol], mode="lines", name=f"h = {h:.4g} s"
                + (" past limit" if past else ""), legendgroup=name,
                legendgrouptitle_text=name if k == 0 else None, line=line, meta=label,
                hovertemplate=hover, visible=True if name in shown else "legendonly"))
            if not past:
                box.append(run[[xcol, ycol]].to_numpy())
    # The view of the stable runs: a blown-up run leaves it (zoom out to follow it).
    pts = np.vstack(box)
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.05 * np.maximum(hi - lo, 1e-6)
    _layout(fig, xlabel, ylabel, height=560)
    fig.update_xaxes(range=[lo[0] - pad[0], hi[0] + pad[0]])
    fig.update_yaxes(range=[lo[1] - pad[1], hi[1] + pad[1]])
    if equal:
        fig.update_yaxes(scaleanchor="x", scaleratio=1)
    return fig


def yaw_rate(sweep, tuned=None) -> list:
    """Figure 1: the plotted state (the bicycle's yaw rate [rad/s]) against time [s] of every
    sampled run and the reference."""
    return [_trajectories(sweep, tuned, "t", sweep.view.plot_state, False)]


def xy_paths(sweep, tuned=None) -> list:
    """Figure 2: the X-Y path [m] (or two states' plane) of every sampled run and the
    reference."""
    xs, ys = sweep.view.plane
    return [_trajectories(sweep, tuned, xs, ys, sweep.view.vehicle)]


def _boundary(m, re, im) -> tuple[np.ndarray, np.ndarray]:
    """The |R(z)| = 1 curve(s) of method m on the grid, NaN between pieces."""
    import contourpy
    x, y, amp = region_grid(m, re=re, im=im, n=181)
    # Capped: interpolating the level-1 crossing against huge values would bias it.
    amp = np.minimum(np.nan_to_num(amp, nan=2.0, posinf=2.0), 2.0)
    lines = contourpy.contour_generator(x, y, amp).lines(1.0)
    if not lines:
        return np.zeros(0), np.zeros(0)
    joined = np.vstack([np.vstack([piece, [np.nan, np.nan]]) for piece in lines])
    return joined[:, 0], joined[:, 1]


def stability_regions(sweep, tuned=None) -> list:
    """Figure 3: every method's stability boundary, with h*lambda of the envelope at the tuned
    step (red where it lies outside the tuned method's region)."""
    names = [m for m in method_order(sweep.summary["method"]) if m in METHODS]
    h, z, re, im = scaled_eigenvalues(sweep, tuned)
    colours = _colours(names)
    fig = go.Figure()
    for name in names:
        x, y = _boundary(METHODS[name], re, im)
        width = 3.5 if tuned and name == tuned["method"] else 2.0
        fig.add_trace(go.Scatter(
            x=x, y=y, mode="lines", name=name, line=dict(color=colours[name], width=width),
            meta=name, hovertemplate="%{meta}: |R(z)| = 1 at z = %{x:.4g} %{y:+.4g}i"
            "<extra></extra>"))
    if z.size:
        out = ~(np.nan_to_num(amplification_theory(METHODS[tuned["method"]], z), nan=np.inf)
                <= 1.0 + 1e-12)
        for mask, colour, label in ((~out, "#1f77b4", "inside"), (out, UNSTABLE, "outside")):
            if mask.any():
                fig.add_trace(go.Scatter(
                    x=z.real[mask], y=z.imag[mask], mode="markers",
                    marker=dict(color=colour, size=7, symbol="x" if label == "outside"
                                else "circle"),
                    name=f"h*lambda at h = {h:g} s, {label} {tuned['method']}'s region",
                    hovertemplate="h*lambda = %{x:.4g} %{y:+.4g}i<extra></extra>"))
    _layout(fig, "Re(h lambda)", "Im(h lambda)", height=560)
    fig.update_xaxes(range=list(re), zeroline=True, zerolinecolor="#999")
    fig.update_yaxes(range=list(im), scaleanchor="x", scaleratio=1, zeroline=True,
                     zerolinecolor="#999")
    return [fig]


def _verdict_lines(fig, verdicts, colours, x=None, y=None) -> None:
    """Each (method, h) of `verdicts` as a dash-dotted line in its method's colour: vertical
    at h over the y values `y`, or horizontal at h over the x values `x`."""
    for name, h in verdicts:
        span = [float(np.nanmin(x if x is not None else y)),
                float(np.nanmax(x if x is not None else y))]
        xs, ys = (span, [h, h]) if x is not None else ([h, h], span)
        fig.add_trace(go.Scatter(
            x=xs, y=ys, mode="lines", name=verdict_label(name, h), legendgroup=name,
            line=dict(color=colours.get(name, VERDICT), dash="dashdot", width=2),
            hovertemplate=f"{verdict_label(name, h)}<extra></extra>"))


def error_vs_step(sweep, tuned=None, verdicts=()) -> list:
    """Figure 4: worst error norm against h [s], log-log, declared slopes dashed, the
    steps of `verdicts` dash-dotted."""
    table = worst_case(sweep.runs)
    table = table[np.isfinite(table["err"]) & (table["err"] > 0)]
    names = method_order(table["method"])
    summary = sweep.summary.set_index("method")
    colours = _colours(names)
    fig = go.Figure()
    for name in names:
        rows = table[table["method"] == name]
        h, err = rows["h"].to_numpy(), rows["err"].to_numpy()
        fit = summary["order_fit_median"].get(name, np.nan)
        label = name + (f" (fitted order {fit:.2f})" if pd.notna(fit) else "")
        fig.add_trace(go.Scatter(
            x=h, y=err, mode="lines+markers", name=label, legendgroup=name, meta=name,
            line=dict(color=colours[name]),
            hovertemplate="%{meta}<br>h = %{x:.5g} s<br>worst error = %{y:.4g}"
            "<extra></extra>"))
        order = summary["order_declared"].get(name)
        if pd.notna(order) and len(h):
            i = len(h) // 2
            hh = np.array([h.min(), h.max()])
            fig.add_trace(go.Scatter(
                x=hh, y=err[i] * (hh / h[i]) ** int(order), mode="lines", legendgroup=name,
                showlegend=False, line=dict(color=colours[name], dash="dash", width=1),
                hovertemplate=f"{name}: slope {int(order)} (declared order)<extra></extra>"))
    if len(table):
        _verdict_lines(fig, verdicts, colours, y=table["err"].to_numpy(float))
    _layout(fig, "step size h [s]", ERROR_NORM,
            logx=True, logy=True, height=560)
    return [fig]


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


def work_precision(sweep, tuned=None) -> list:
    """Figure 5: worst error (position [m], or the error norm) against RHS evaluations and
    against the fastest round's wall time per simulated second, bars reaching the median
    round."""
    view = sweep.view.with_tolerance(tuned)
    table = worst_case(sweep.runs, view.error).merge(_timing_spread(sweep.runs), on=["method", "h"],
                                         how="left")
    names = method_order(table["method"])
    colours = _colours(names)
    fig = make_subplots(rows=2, cols=1, shared_yaxes=True, vertical_spacing=0.12)
    for name in names:
        rows = table[table["method"] == name]
        # Bars from the fastest round to the median one: the slowest is often an outlier.
        spread = rows["time_per_step_median_s"].to_numpy(float) - rows["time_per_s"].to_numpy()
        custom = np.column_stack([rows["h"], rows["time_per_s"],
                                  rows["time_per_step_median_s"], rows["time_per_step_max_s"]])
        for row, col in ((1, "evals_per_s"), (2, "time_per_s")):
            fig.add_trace(go.Scatter(
                x=rows[col], y=rows["worst"], mode="lines+markers", name=name,
                legendgroup=name, showlegend=row == 1, line=dict(color=colours[name]),
                meta=name, customdata=custom,
                error_x=dict(type="data", array=spread, arrayminus=np.zeros(len(rows)),
                             visible=row == 2 and bool(np.isfinite(spread).any()),
                             thickness=1, width=0),
                hovertemplate="%{meta}, h = %{customdata[0]:.5g} s<br>worst "
                f"{view.error_label} = %{{y:.4g}} {view.error_unit}<br>" + ("RHS evaluations per simulated s = %{x:.5g}" if row == 1
                                       else "wall time per simulated s: fastest %{customdata[1]"
                                       ":.4g} s, median %{customdata[2]:.4g} s, slowest "
                                       "%{customdata[3]:.4g} s") + "<extra></extra>"),
                row=row, col=1)
    if tuned:
        tol = tolerance(tuned)
        pick = table[(table["method"] == tuned["method"])
                     & np.isclose(table["h"], float(tuned["h"]))]
        for row, col in ((1, "evals_per_s"), (2, "time_per_s")):
            fig.add_hline(y=tol, line=dict(color="black", dash="dot", width=1), row=row, col=1)
            fig.add_trace(go.Scatter(
                x=pick[col], y=pick["worst"], mode="markers", name="tuned choice",
                legendgroup="tuned", showlegend=row == 1,
                marker=dict(symbol="star-open", size=16, color="black"),
                hovertemplate=f"tuned: {tuned['method']} at h = {float(tuned['h']):g} s"
                "<extra></extra>"), row=row, col=1)
    _layout(fig, "", error_axis(view), logx=True, logy=True, height=820)
    fig.update_xaxes(title_text="right-hand-side evaluations per simulated second", row=1,
                     col=1)
    fig.update_xaxes(title_text="wall time per simulated second, fastest round [s]", row=2,
                     col=1)
    fig.update_layout(legend=dict(y=-0.08))
    return [fig]


def stable_step_vs_speed(sweep, tuned=None, verdicts=()) -> list:
    """Figure 6: largest stable step [s] against the first envelope variable (the bicycle's
    vx [m/s]), a dash per value of the second: predicted lines, measured markers, the steps
    of `verdicts` dash-dotted."""
    limits = sweep.limits
    names = method_order(limits["method"])
    colours = _colours(names)
    xvar, cvar, deltas = envelope_axes(sweep.view, limits)
    fig = go.Figure()
    for name in names:
        rows = limits[limits["method"] == name]
        first, failed_shown = True, False
        for k, delta in enumerate(deltas):
            sub = (rows if cvar is None else rows[rows[cvar] == delta]).sort_values(xvar)
            pred = sub["h_pred"].to_numpy(float)
            meas = sub["h_meas"].to_numpy(float)
            custom = np.column_stack([np.full(len(sub), np.nan if delta is None else delta),
                                      pred, meas])
            hover = ("%{meta}" + (f", {cvar} = %{{customdata[0]:.3g}}" if cvar else "")
                     + f", {xvar} = %{{x:.4g}}<br>"
                     "largest stable h: predicted %{customdata[1]:.4g} s, measured "
                     "%{customdata[2]:.4g} s<extra></extra>")
            ok = np.isfinite(pred)
            if ok.any():
                fig.add_trace(go.Scatter(
                    x=sub[xvar][ok], y=pred[ok], mode="lines", name=name, legendgroup=name,
                    showlegend=first, meta=name, customdata=custom[ok], hovertemplate=hover,
                    line=dict(color=colours[name], dash=DASHES[k % len(DASHES)], width=1.5)))
                first = False
            found = np.isfinite(meas) & (meas > 0)
            solver = solver_limited(sub)
            for keep, symbol, what in ((found & ~solver, "circle-open", "blow-up"),
                                       (found & solver, "x", "a nonlinear solve failed")):
                if keep.any():
                    fig.add_trace(go.Scatter(
                        x=sub[xvar][keep], y=meas[keep], mode="markers",
                        name=f"{name}: {what}" if symbol == "x" else name, legendgroup=name,
                        showlegend=first if symbol != "x" else not failed_shown,
                        meta=f"{name} ({what})",
                        customdata=custom[keep], hovertemplate=hover,
                        marker=dict(color=colours[name], symbol=symbol, size=8)))
                    first, failed_shown = False, failed_shown or symbol == "x"
    _verdict_lines(fig, verdicts, colours, x=limits[xvar].to_numpy(float))
    _layout(fig, variable_label(xvar), "largest stable step h [s]", logy=True, height=560)
    return [fig]


def _occupancy_png(occupied: np.ndarray) -> str:
    """The grid as a data-URI PNG, obstacles black, row 0 at the bottom."""
    from PIL import Image
    img = Image.fromarray(np.where(occupied[::-1], 0, 255).astype(np.uint8), mode="L")
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _plan_figure(plan) -> go.Figure:
    rec, occ = plan.record, plan.occupied
    res, (ox, oy) = float(rec["map"]["resolution"]), rec["map"]["origin"]
    width, height = occ.shape[1] * res, occ.shape[0] * res
    fig = go.Figure()
    fig.add_layout_image(source=_occupancy_png(occ), xref="x", yref="y", x=ox, y=oy + height,
                         sizex=width, sizey=height, sizing="stretch", layer="below",
                         opacity=0.9)
    if rec["tree"]:
        pieces = [np.vstack([np.asarray(e, float), [np.nan, np.nan]]) for e in rec["tree"]]
        # Single precision: a tree holds thousands of edges, and float32 places them to well
        # under a pixel on any map, at half the page's bytes.
        tree = np.vstack(pieces).astype(np.float32)
        fig.add_trace(go.Scatter(x=tree[:, 0], y=tree[:, 1], mode="lines", name="tree",
                                 line=dict(color="blue", width=1), hoverinfo="skip"))
    if rec["path"]:
        path = np.asarray(rec["path"], float)
        fig.add_trace(go.Scatter(
            x=path[:, 1], y=path[:, 2], mode="lines", name="path",
            line=dict(color="red", width=3), customdata=path[:, [0, 3]],
            hovertemplate="t = %{customdata[0]:.3f} s<br>X = %{x:.3f} m, Y = %{y:.3f} m<br>"
            "heading = %{customdata[1]:.3f} rad<extra></extra>"))
    for pose, symbol, label in ((rec["start"], "circle", "start"), (rec["goal"], "star", "goal")):
        fig.add_trace(go.Scatter(
            x=[pose[0]], y=[pose[1]], mode="markers", name=label,
            marker=dict(symbol=symbol, size=14, color="#2ca02c", line=dict(color="black",
                                                                           width=1)),
            hovertemplate=f"{label}: X = {pose[0]:.3f} m, Y = {pose[1]:.3f} m, heading = "
            f"{pose[2]:.3f} rad<extra></extra>"))
    tall = max(min(height / width, 1.6), 0.4)
    _layout(fig, "X [m]", "Y [m]", height=int(180 + 420 * tall))
    fig.update_xaxes(range=[ox, ox + width], showgrid=False)
    fig.update_yaxes(range=[oy, oy + height], scaleanchor="x", scaleratio=1, showgrid=False)
    fig.update_layout(title=dict(text=f"{plan.name}: {rec['status']}", font=dict(size=14)))
    return fig


def plans(plan_list) -> list:
    """Figure 7: one map per planned scenario with its tree, path, start and goal."""
    return [_plan_figure(p) for p in plan_list]


# The interactive figure of each static one, by number (`figures.py` numbering).
BY_NUMBER = {1: yaw_rate, 2: xy_paths, 3: stability_regions, 4: error_vs_step,
             5: work_precision, 6: stable_step_vs_speed}
