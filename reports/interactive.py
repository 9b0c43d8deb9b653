"""The report's interactive figures: `draw` renders a `figure_types` record (the same one the
static PNG is drawn from) as Plotly figures, to zoom, hover for exact values and click a
method in the legend to hide or show it (a double click shows it alone). `divs` turns them
into HTML fragments that need plotly.js once in the page (`plotly_js`), so the page works
offline. Both are packed (gzip, then base64): the library is most of the page's bytes, and
the page unpacks it with the browser's own gzip (DecompressionStream), see reports.html."""
from __future__ import annotations

import base64
import gzip
import io
from functools import cache
from typing import Callable

import numpy as np
import plotly.graph_objects as go
from plotly.colors import qualitative
from plotly.io.json import to_json_plotly
from plotly.offline import get_plotlyjs
from plotly.subplots import make_subplots

from stepzoo.reports import figure_types as ft

HEIGHT_PX = 460
MAX_POINTS = 400          # points kept per trajectory trace: enough for the eye and the hover
REFERENCE = dict(color="black", dash="dash", width=1.5)
UNSTABLE = "#d62728"
VERDICT = "#ff7f0e"
DASHES = ("solid", "dash", "dot", "dashdot", "longdash", "longdashdot")
CONFIG = {"responsive": True, "displaylogo": False, "scrollZoom": False,
          "modeBarButtonsToRemove": ["select2d", "lasso2d"]}


def pack(text: str) -> str:
    """`text` as the page carries it: gzip, then base64 (no byte of it ends a script)."""
    return base64.b64encode(gzip.compress(text.encode(), 9, mtime=0)).decode()


@cache
def plotly_js() -> str:
    """The plotly.js library, packed, to be inlined once in the page."""
    return pack(get_plotlyjs())


def divs(figures: list, prefix: str) -> list[str]:
    """HTML fragments of `figures` (ids prefix-1, prefix-2, ...): an empty plot and its
    packed figure (data, layout, config), which the page draws once plotly.js is unpacked."""
    out = []
    for i, fig in enumerate(figures, 1):
        spec = to_json_plotly({**fig.to_plotly_json(), "config": CONFIG})
        out.append(f'<div id="{prefix}-{i}" class="plotly-graph-div" style="height:'
                   f'{fig.layout.height or HEIGHT_PX}px; width:100%;"></div>\n'
                   f'<script type="application/octet-stream" class="plot-spec" '
                   f'data-for="{prefix}-{i}">{pack(spec)}</script>')
    return out


def _colours(names) -> dict:
    palette = qualitative.Dark24
    return {n: palette[i % len(palette)] for i, n in enumerate(names)}


def _layout(fig: go.Figure, axes: ft.Axes, *, height=HEIGHT_PX) -> go.Figure:
    """The figure's look, and its axes' titles and scales as the figure record gives them."""
    # Legend below the plot: on a phone a legend beside it would take the plot's width.
    fig.update_layout(template="plotly_white", height=height, hovermode="closest",
                      margin=dict(l=60, r=10, t=30, b=10),
                      legend=dict(orientation="h", yanchor="top", y=-0.15, x=0,
                                  groupclick="togglegroup", font=dict(size=11)))
    fig.update_xaxes(title_text=axes.xlabel, type=axes.xscale, exponentformat="power",
                     showline=True, linecolor="#888")
    fig.update_yaxes(title_text=axes.ylabel, type=axes.yscale, exponentformat="power",
                     showline=True, linecolor="#888")
    if axes.equal:
        fig.update_yaxes(scaleanchor="x", scaleratio=1)
    return fig


def _thin(x: np.ndarray, y: np.ndarray):
    """At most MAX_POINTS points, evenly spread, the last one kept; infinities as gaps."""
    if len(x) > MAX_POINTS:
        keep = np.unique(np.linspace(0, len(x) - 1, MAX_POINTS).round().astype(int))
        x, y = x[keep], y[keep]
    return (np.where(np.isinf(x), np.nan, x), np.where(np.isinf(y), np.nan, y))


def _shown_first(names, tuned) -> set:
    """Methods drawn at first in the crowded trajectory figures: the tuned one, else the
    first three; the others are a click away in the legend."""
    if tuned in names:
        return {tuned}
    return set(list(names)[:3])


def trajectories(data: ft.Trajectories) -> list:
    """Figures 1-2: every sampled run over the reference, a legend group per method."""
    names = [p.method for p in data.panels]
    colours = _colours(names)
    shown = _shown_first(names, data.tuned)
    fig = go.Figure()
    hover = f"%{{meta}}<br>{data.xlabel} = %{{x:.6g}}<br>{data.ylabel} = %{{y:.6g}}<extra></extra>"
    ref_x, ref_y = _thin(*data.reference)
    fig.add_trace(go.Scatter(x=ref_x, y=ref_y, mode="lines", name="reference",
                             line=REFERENCE, meta="reference", hovertemplate=hover))
    for p in data.panels:
        for k, r in enumerate(p.runs):
            x, y = _thin(r.x, r.y)
            label = f"{p.method}, h = {r.h:.4g} s" + (" (past the limit)" if r.past else "")
            line = dict(color=UNSTABLE, dash="dot", width=1.5) if r.past else \
                dict(color=colours[p.method], dash=DASHES[k % len(DASHES)], width=1.5)
            fig.add_trace(go.Scatter(
                x=x, y=y, mode="lines", name=f"h = {r.h:.4g} s"
                + (" past limit" if r.past else ""), legendgroup=p.method,
                legendgrouptitle_text=p.method if k == 0 else None, line=line, meta=label,
                hovertemplate=hover, visible=True if p.method in shown else "legendonly"))
    # The view of the stable runs: a blown-up run leaves it (zoom out to follow it).
    lo = np.min([p.lo for p in data.panels], axis=0)
    hi = np.max([p.hi for p in data.panels], axis=0)
    pad = 0.05 * np.maximum(hi - lo, 1e-6)
    _layout(fig, data.axes[0], height=560)
    fig.update_xaxes(range=[lo[0] - pad[0], hi[0] + pad[0]])
    fig.update_yaxes(range=[lo[1] - pad[1], hi[1] + pad[1]])
    return [fig]


def regions(data: ft.Regions) -> list:
    """Figure 3: every method's stability boundary, with h*lambda of the envelope at the tuned
    step (red where it lies outside the tuned method's region)."""
    colours = _colours([p.method for p in data.panels])
    fig = go.Figure()
    for p in data.panels:
        fig.add_trace(go.Scatter(
            x=p.boundary[0], y=p.boundary[1], mode="lines", name=p.method,
            line=dict(color=colours[p.method], width=3.5 if p.method == data.tuned else 2.0),
            meta=p.method, hovertemplate="%{meta}: |R(z)| = 1 at z = %{x:.4g} %{y:+.4g}i"
            "<extra></extra>"))
    z, out = data.z, data.outside
    for mask, colour, label in ((~out, "#1f77b4", "inside"), (out, UNSTABLE, "outside")):
        if z.size and mask.any():
            fig.add_trace(go.Scatter(
                x=z.real[mask], y=z.imag[mask], mode="markers",
                marker=dict(color=colour, size=7, symbol="x" if label == "outside"
                            else "circle"),
                name=f"h*lambda at h = {data.h:g} s, {label} {data.tuned}'s region",
                hovertemplate="h*lambda = %{x:.4g} %{y:+.4g}i<extra></extra>"))
    _layout(fig, data.axes[0], height=560)
    fig.update_xaxes(range=list(data.re), zeroline=True, zerolinecolor="#999")
    fig.update_yaxes(range=list(data.im), zeroline=True, zerolinecolor="#999")
    return [fig]


def _verdict_lines(fig, verdicts, colours, x=None, y=None) -> None:
    """Each (method, h) of `verdicts` as a dash-dotted line in its method's colour: vertical
    at h over the y span `y`, or horizontal at h over the x span `x`."""
    for name, h in verdicts:
        xs, ys = (list(x), [h, h]) if x is not None else ([h, h], list(y))
        fig.add_trace(go.Scatter(
            x=xs, y=ys, mode="lines", name=ft.verdict_label(name, h), legendgroup=name,
            line=dict(color=colours.get(name, VERDICT), dash="dashdot", width=2),
            hovertemplate=f"{ft.verdict_label(name, h)}<extra></extra>"))


def error_vs_step(data: ft.ErrorVsStep) -> list:
    """Figure 4: worst error norm against h [s], log-log, declared slopes dashed, the
    steps of `verdicts` dash-dotted."""
    colours = _colours([p.method for p in data.panels])
    fig = go.Figure()
    for p in data.panels:
        label = p.method + (f" (fitted order {p.fit:.2f})" if np.isfinite(p.fit) else "")
        fig.add_trace(go.Scatter(
            x=p.h, y=p.err, mode="lines+markers", name=label, legendgroup=p.method,
            meta=p.method, line=dict(color=colours[p.method]),
            hovertemplate="%{meta}<br>h = %{x:.5g} s<br>worst error = %{y:.4g}"
            "<extra></extra>"))
        if p.slope is not None:
            hh, yy, order = p.slope
            fig.add_trace(go.Scatter(
                x=hh, y=yy, mode="lines", legendgroup=p.method, showlegend=False,
                line=dict(color=colours[p.method], dash="dash", width=1),
                hovertemplate=f"{p.method}: slope {order} (declared order)<extra></extra>"))
    errs = np.concatenate([p.err for p in data.panels]) if data.panels else np.zeros(0)
    if errs.size:
        _verdict_lines(fig, data.verdicts, colours, y=(errs.min(), errs.max()))
    _layout(fig, data.axes[0], height=560)
    return [fig]


def work_precision(data: ft.WorkPrecision) -> list:
    """Figure 5: worst error against RHS evaluations and against the fastest round's wall
    time per simulated second, bars reaching the median round."""
    colours = _colours([line.method for line in data.lines])
    fig = make_subplots(rows=2, cols=1, shared_yaxes=True, vertical_spacing=0.12)
    for line in data.lines:
        # Bars from the fastest round to the median one: the slowest is often an outlier.
        spread = line.time_median - line.time_per_s
        custom = np.column_stack([line.h, line.time_per_s, line.time_median, line.time_max])
        for row, col in ((1, "evals_per_s"), (2, "time_per_s")):
            fig.add_trace(go.Scatter(
                x=getattr(line, col), y=line.worst, mode="lines+markers", name=line.method,
                legendgroup=line.method, showlegend=row == 1,
                line=dict(color=colours[line.method]), meta=line.method, customdata=custom,
                error_x=dict(type="data", array=spread, arrayminus=np.zeros(len(line.h)),
                             visible=row == 2 and bool(np.isfinite(spread).any()),
                             thickness=1, width=0),
                hovertemplate="%{meta}, h = %{customdata[0]:.5g} s<br>worst "
                f"{data.error_label} = %{{y:.4g}}{data.unit}<br>"
                + ("RHS evaluations per simulated s = %{x:.5g}" if row == 1
                   else "wall time per simulated s: fastest %{customdata[1]:.4g} s, median "
                   "%{customdata[2]:.4g} s, slowest %{customdata[3]:.4g} s")
                + "<extra></extra>"), row=row, col=1)
    if data.pick is not None:
        for row, col in ((1, "evals_per_s"), (2, "time_per_s")):
            fig.add_hline(y=data.tol, line=dict(color="black", dash="dot", width=1), row=row,
                          col=1)
            fig.add_trace(go.Scatter(
                x=getattr(data.pick, col), y=data.pick.worst, mode="markers",
                name="tuned choice", legendgroup="tuned", showlegend=row == 1,
                marker=dict(symbol="star-open", size=16, color="black"),
                hovertemplate=f"tuned: {data.tuned} at h = {data.tuned_h:g} s"
                "<extra></extra>"), row=row, col=1)
    _layout(fig, data.axes[0], height=820)
    for row, spec in enumerate(data.axes, 1):
        fig.update_xaxes(title_text=spec.xlabel, type=spec.xscale, row=row, col=1)
    fig.update_layout(legend=dict(y=-0.08))
    return [fig]


def stable_step(data: ft.StableStep) -> list:
    """Figure 6: largest stable step [s] against the first envelope variable, a dash per
    value of the second: predicted lines, measured markers, verdict steps dash-dotted."""
    colours = _colours([p.method for p in data.panels])
    xvar, cvar = data.xvar, data.cvar
    fig = go.Figure()
    for p in data.panels:
        first, failed_shown = True, False
        for k, c in enumerate(p.curves):
            custom = np.column_stack([np.full(len(c.x), np.nan if c.value is None else c.value),
                                      c.pred, c.meas])
            hover = ("%{meta}" + (f", {cvar} = %{{customdata[0]:.3g}}" if cvar else "")
                     + f", {xvar} = %{{x:.4g}}<br>"
                     "largest stable h: predicted %{customdata[1]:.4g} s, measured "
                     "%{customdata[2]:.4g} s<extra></extra>")
            ok = np.isfinite(c.pred)
            if ok.any():
                fig.add_trace(go.Scatter(
                    x=c.x[ok], y=c.pred[ok], mode="lines", name=p.method,
                    legendgroup=p.method, showlegend=first, meta=p.method,
                    customdata=custom[ok], hovertemplate=hover,
                    line=dict(color=colours[p.method], dash=DASHES[k % len(DASHES)],
                              width=1.5)))
                first = False
            for keep, symbol, what in ((c.blowup, "circle-open", "blow-up"),
                                       (c.solver, "x", "a nonlinear solve failed")):
                if keep.any():
                    fig.add_trace(go.Scatter(
                        x=c.x[keep], y=c.meas[keep], mode="markers",
                        name=f"{p.method}: {what}" if symbol == "x" else p.method,
                        legendgroup=p.method,
                        showlegend=first if symbol != "x" else not failed_shown,
                        meta=f"{p.method} ({what})", customdata=custom[keep],
                        hovertemplate=hover,
                        marker=dict(color=colours[p.method], symbol=symbol, size=8)))
                    first, failed_shown = False, failed_shown or symbol == "x"
    _verdict_lines(fig, data.verdicts, colours, x=data.x_span)
    _layout(fig, data.axes[0], height=560)
    return [fig]


def _occupancy_png(occupied: np.ndarray) -> str:
    """The grid as a data-URI PNG, obstacles black, row 0 at the bottom."""
    from PIL import Image
    img = Image.fromarray(np.where(occupied[::-1], 0, 255).astype(np.uint8), mode="L")
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _plan_figure(m: ft.PlanMap) -> go.Figure:
    x0, x1, y0, y1 = m.extent
    width, height = x1 - x0, y1 - y0
    fig = go.Figure()
    fig.add_layout_image(source=_occupancy_png(m.occupied), xref="x", yref="y", x=x0, y=y1,
                         sizex=width, sizey=height, sizing="stretch", layer="below",
                         opacity=0.9)
    if m.tree:
        pieces = [np.vstack([e, [np.nan, np.nan]]) for e in m.tree]
        # Single precision: a tree holds thousands of edges, and float32 places them to well
        # under a pixel on any map, at half the page's bytes.
        tree = np.vstack(pieces).astype(np.float32)
        fig.add_trace(go.Scatter(x=tree[:, 0], y=tree[:, 1], mode="lines", name="tree",
                                 line=dict(color="blue", width=1), hoverinfo="skip"))
    if m.path is not None:
        fig.add_trace(go.Scatter(
            x=m.path[:, 1], y=m.path[:, 2], mode="lines", name="path",
            line=dict(color="red", width=3), customdata=m.path[:, [0, 3]],
            hovertemplate="t = %{customdata[0]:.3f} s<br>X = %{x:.3f} m, Y = %{y:.3f} m<br>"
            "heading = %{customdata[1]:.3f} rad<extra></extra>"))
    for pose, symbol, label in ((m.start, "circle", "start"), (m.goal, "star", "goal")):
        fig.add_trace(go.Scatter(
            x=[pose[0]], y=[pose[1]], mode="markers", name=label,
            marker=dict(symbol=symbol, size=14, color="#2ca02c", line=dict(color="black",
                                                                           width=1)),
            hovertemplate=f"{label}: X = {pose[0]:.3f} m, Y = {pose[1]:.3f} m, heading = "
            f"{pose[2]:.3f} rad<extra></extra>"))
    tall = max(min(height / width, 1.6), 0.4)
    _layout(fig, m.axes[0], height=int(180 + 420 * tall))
    fig.update_xaxes(range=[x0, x1], showgrid=False)
    fig.update_yaxes(range=[y0, y1], showgrid=False)
    fig.update_layout(title=dict(text=f"{m.name}: {m.status}", font=dict(size=14)))
    return fig


def plans(data: ft.Plans) -> list:
    """Figure 7: one map per planned scenario with its tree, path, start and goal."""
    return [_plan_figure(m) for m in data.maps]


def tradeoff(data: ft.Tradeoff) -> list:
    """Figure 8: plan time against replay deviation; hover for each integrator's numbers."""
    fig = go.Figure()
    dev, time = data.deviation_m, data.time_s
    for k, name in enumerate(data.integrator):
        fig.add_trace(go.Scatter(
            x=[dev[k]], y=[time[k]], mode="markers+text", name=name, text=[name],
            textposition="top right",
            marker=dict(size=8 + 22 * data.exact_rate[k],
                        symbol="square" if data.paper[k] else "circle",
                        line=dict(width=3 if data.tuned[k] else 0, color="black")),
            error_x=dict(type="data", symmetric=False,
                         array=[data.deviation_max_m[k] - dev[k]], arrayminus=[0.0],
                         thickness=1),
            hovertemplate=(f"{name} ({data.role[k]})<br>median plan time %{{y:.3g}} s"
                           f"<br>replay deviation median %{{x:.3g}} m, largest "
                           f"{data.deviation_max_m[k]:.3g} m<br>exact rate "
                           f"{data.exact_rate[k]:.3g}<extra></extra>")))
    front = np.flatnonzero(data.pareto)
    front = front[np.argsort(dev[front])]
    fig.add_trace(go.Scatter(x=dev[front], y=time[front], mode="lines", name="Pareto front",
                             line=dict(color="black", dash="dash", width=1)))
    return [_layout(fig, data.axes[0])]


# The renderer of each figure record's type.
RENDER: dict[type, Callable[..., list]] = {
          ft.Trajectories: trajectories, ft.Regions: regions, ft.ErrorVsStep: error_vs_step,
          ft.WorkPrecision: work_precision, ft.StableStep: stable_step, ft.Plans: plans,
          ft.Tradeoff: tradeoff}


def draw(data) -> list:
    """The Plotly figures of the figure record `data` (one, or one per planned scenario)."""
    return RENDER[type(data)](data)
