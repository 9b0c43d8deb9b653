"""The report's static figures: `draw` renders a `figure_types` record (computed by
`figure_data`) as PNG(s) in the report folder and returns a `Shown` record with the caption.
Matplotlib runs headless through the Agg canvas, without pyplot's global state; nothing here
computes what is shown, only how it looks."""
from __future__ import annotations

import io
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from stepzoo.output import atomic_write
from stepzoo.reports import figure_types as ft

# Log-axis tick labels go through mathtext, which probes STIX fonts that some matplotlib
# wheels do not ship; the fallback to DejaVu Sans renders the same, so the probe's
# warnings (20 lines per report) are noise.
logging.getLogger("matplotlib.font_manager").setLevel(logging.ERROR)

DPI = 100
NCOLS = 4
PANEL_IN = (3.2, 2.5)          # [inch] one small-multiple panel
PANEL_PAD = (0.75, 0.15, 0.3, 0.5)   # [inch] left, right, top, bottom of a panel: its labels
PANEL_ASPECT = 1.35            # width / height of a panel's plotting area, labels aside
STABLE_FILL, BOUNDARY, UNSTABLE = "#cfe3f5", "#1f4e79", "#d62728"
VERDICT = "#ff7f0e"            # the steps asked about with `stepzoo report --verdict`
SIZE_PT2 = 300.0               # [pt^2] Figure 8's marker area at an exact rate of 1


@dataclass(frozen=True)
class Shown:
    """A numbered figure of the report: its PNG files (name, sub-caption) and caption."""
    number: int
    title: str
    caption: str
    images: list


def _save(fig: Figure, out_dir: Path, name: str) -> str:
    buf = io.BytesIO()
    # Every figure places its labels inside itself (fixed margins, or the constrained
    # layout): "tight" bounds would measure the whole figure again for the same picture.
    fig.savefig(buf, format=Path(name).suffix[1:], dpi=DPI)
    atomic_write(out_dir / name, buf.getvalue())       # a full disk names the file
    return name


def _panels(n: int, ncols: int = NCOLS, panel=PANEL_IN, **kwargs):
    """(figure, axes list of length n) for small multiples; unused slots are hidden, and
    with n = 0 one empty panel says so. Each panel keeps fixed margins for its labels
    (PANEL_PAD): a layout engine would measure every tick label of every panel before each
    draw, for the same place in every panel."""
    ncols = max(1, min(ncols, n))
    nrows = max(1, math.ceil(n / ncols))
    width, height = panel[0] * ncols, panel[1] * nrows
    left, right, top, bottom = PANEL_PAD
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False, gridspec_kw=dict(
        left=left / width, right=1 - right / width, bottom=bottom / height,
        top=1 - top / height, wspace=(left + right) / (panel[0] - left - right),
        hspace=(top + bottom) / (panel[1] - top - bottom)), **kwargs).ravel()
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


def _labels(ax, title: str, axes: ft.Axes, size: int = 9, **title_kw) -> None:
    """The panel's title, and its axes' labels and scales as the figure record gives them."""
    # A title placed at the axes' top: left to find its place itself, it would measure
    # every tick label of the panel at each draw to dodge labels no panel has on top.
    ax.set_title(title, fontsize=size, y=1.0, **title_kw)
    ax.set_xlabel(axes.xlabel, fontsize=8)
    ax.set_ylabel(axes.ylabel, fontsize=8)
    ax.set_xscale(axes.xscale)
    ax.set_yscale(axes.yscale)
    ax.tick_params(which="both", labelsize=7)


def _shades(n):
    return [colormaps["viridis"](v) for v in np.linspace(0.1, 0.75, max(n, 1))][:n]


def _one(data) -> Shown:
    return Shown(data.number, data.title, data.caption, [(data.file, "")])


def trajectories(data: ft.Trajectories, out_dir: Path) -> Shown:
    """Figures 1-2: a panel per method, its runs coloured by step over the reference."""
    fig, axes = _panels(len(data.panels), sharex=not data.equal)
    for ax, panel in zip(axes, data.panels):
        stable_h = [r.h for r in panel.runs if not r.past]
        colours = dict(zip(stable_h, _shades(len(stable_h))))
        for r in panel.runs:
            if r.past:
                ax.plot(r.x, r.y, color=UNSTABLE, ls=":", lw=1.2,
                        label=f"h={r.h:.3g} s, past limit")
            else:
                ax.plot(r.x, r.y, color=colours[r.h], lw=1.2, label=f"h={r.h:.3g} s")
        ax.plot(*data.reference, color="black", ls="--", lw=1.0, label="reference")
        # The view of the reference and the stable runs: a blown-up run leaves the panel.
        half = 0.54 * np.maximum(panel.hi - panel.lo, 1e-6)
        if data.equal:
            # Widen the short side to the panel's shape, so equal axes fill the panel.
            half = np.maximum(half, half[::-1] * np.array([PANEL_ASPECT, 1 / PANEL_ASPECT]))
            ax.set_aspect("equal", adjustable="box")
        mid = 0.5 * (panel.lo + panel.hi)
        ax.set_xlim(mid[0] - half[0], mid[0] + half[0])
        ax.set_ylim(mid[1] - half[1], mid[1] + half[1])
        _labels(ax, panel.method, data.axes[0], size=10)
        ax.legend(fontsize=6, loc="best")
    _save(fig, out_dir, data.file)
    return _one(data)


def regions(data: ft.Regions, out_dir: Path) -> Shown:
    """Figure 3: a panel per method, its region shaded, h*lambda inside (dots) or outside."""
    fig, axes = _panels(len(data.panels), sharex=True, sharey=True)
    z = data.z
    for ax, p in zip(axes, data.panels):
        ax.contourf(p.x, p.y, p.stable.astype(float), levels=[0.5, 1.5], colors=[STABLE_FILL])
        ax.plot(*p.boundary, color=BOUNDARY, lw=0.8)
        ax.axhline(0, color="grey", lw=0.5)
        ax.axvline(0, color="grey", lw=0.5)
        title = p.method
        if z.size:
            out = p.outside
            ax.plot(z.real[~out], z.imag[~out], ".", color="#1f77b4", ms=3)
            ax.plot(z.real[out], z.imag[out], "x", color=UNSTABLE, ms=4)
            title += f" ({out.sum()} of {z.size} outside)" if out.any() else " (all inside)"
        ax.set_xlim(*data.re)
        ax.set_ylim(*data.im)
        _labels(ax, title, data.axes[0], fontweight="bold" if p.method == data.tuned else "normal")
    _save(fig, out_dir, data.file)
    return _one(data)


def error_vs_step(data: ft.ErrorVsStep, out_dir: Path) -> Shown:
    """Figure 4: a log-log panel per method, declared slope dashed, verdict steps vertical."""
    fig, axes = _panels(len(data.panels), sharex=True, sharey=True)
    for ax, p in zip(axes, data.panels):
        ax.plot(p.h, p.err, "o-", color="#1f77b4", ms=3, lw=1.0, label="measured")
        if p.slope is not None:
            hh, yy, order = p.slope
            ax.plot(hh, yy, "--", color="grey", lw=1.0, label=f"slope {order} (declared)")
        for vh in p.verdicts:
            ax.axvline(vh, color=VERDICT, ls="-.", lw=1.2,
                       label=ft.verdict_label(p.method, vh))
        fit = f" (fit {p.fit:.2f})" if np.isfinite(p.fit) else ""
        _labels(ax, p.method + fit, data.axes[0])
        ax.legend(fontsize=6)
    _save(fig, out_dir, data.file)
    return _one(data)


def _styles(names):
    cmap = colormaps["tab20"]
    marks = "os^vDP*Xh<>p"
    return {n: (cmap(i % 20), marks[i % len(marks)]) for i, n in enumerate(names)}


def work_precision(data: ft.WorkPrecision, out_dir: Path) -> Shown:
    """Figure 5: error against RHS evaluations and against wall time, a line per method."""
    style = _styles([line.method for line in data.lines])
    fig = Figure(figsize=(12.5, 5.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2, sharey=True)
    for ax, col, spec in zip(axes, ["evals_per_s", "time_per_s"], data.axes):
        for line in data.lines:
            colour, mark = style[line.method]
            # Bars from the fastest round to the median one (the slowest is often an outlier).
            spread = line.time_median - line.time_per_s if col == "time_per_s" else None
            ax.errorbar(getattr(line, col), line.worst, marker=mark, color=colour, ms=4,
                        lw=1.0, label=line.method,
                        xerr=None if spread is None or not np.isfinite(spread).any() else
                        [np.zeros(len(spread)), np.nan_to_num(spread)], elinewidth=0.8)
        if data.pick is not None:
            ax.axhline(data.tol, color="black", ls=":", lw=1.0)
            ax.plot(getattr(data.pick, col), data.pick.worst, "*", color="black", ms=14,
                    mfc="none")
        ax.set_xlabel(spec.xlabel)
        ax.set_xscale(spec.xscale)
        ax.set_yscale(spec.yscale)
        ax.grid(True, which="major", lw=0.3)
    axes[0].set_ylabel(data.axes[0].ylabel)
    handles, labels = axes[0].get_legend_handles_labels()
    if data.pick is not None:
        handles += [Line2D([], [], color="black", ls=":"),
                    Line2D([], [], marker="*", color="black", ls="", ms=12, mfc="none")]
        labels += [f"tolerance {data.tol:g}{data.unit}", "tuned choice"]
    fig.legend(handles, labels, loc="outside right center", fontsize=8)
    _save(fig, out_dir, data.file)
    return _one(data)


def stable_step(data: ft.StableStep, out_dir: Path) -> Shown:
    """Figure 6: a panel per method, predicted lines and measured markers per colour value."""
    colours = dict(zip(data.values, _shades(len(data.values))))
    fig, axes = _panels(len(data.panels), sharex=True, sharey=True)
    for ax, p in zip(axes, data.panels):
        if p.unlimited:
            ax.text(0.5, 0.5, "no limit predicted\n(A-stable)", ha="center", va="center",
                    transform=ax.transAxes, fontsize=8)
        for c in p.curves:
            colour = colours[c.value]
            finite = np.isfinite(c.pred)
            ax.plot(c.x[finite], c.pred[finite], "-", color=colour, lw=1.2,
                    label=f"{data.cvar}={c.value:.3g}" if data.cvar else "predicted")
            ax.plot(c.x[c.blowup], c.meas[c.blowup], "o", color=colour, ms=4, mfc="none")
            ax.plot(c.x[c.solver], c.meas[c.solver], "X", color=colour, ms=6)
            if c.untried.any():
                ax.plot(c.x[c.untried], np.full(c.untried.sum(), c.h_tried), "^",
                        color=colour, ms=5)
        for vh in p.verdicts:
            ax.axhline(vh, color=VERDICT, ls="-.", lw=1.2,
                       label=ft.verdict_label(p.method, vh))
        _labels(ax, p.method, data.axes[0])
    if axes:
        handles, labels = axes[0].get_legend_handles_labels()
        marks = [("o", "none", "blow-up measured"), ("^", None, "no blow-up up to the "
                 "largest step tried")] + ([("X", None, "a nonlinear solve failed")]
                                          if data.any_failed else [])
        for mark, face, label in marks:
            handles.append(Line2D([], [], marker=mark, color="grey", mfc=face, ls=""))
            labels.append(label)
        axes[0].legend(handles, labels, fontsize=6)
        for ax, p in zip(axes[1:], data.panels[1:]):
            if p.verdicts:
                ax.legend(fontsize=6)
    _save(fig, out_dir, data.file)
    return _one(data)


def _plan_png(m: ft.PlanMap, out_dir: Path) -> str:
    extent = m.extent
    aspect = (extent[3] - extent[2]) / (extent[1] - extent[0])
    fig = Figure(figsize=(7.0, min(max(7.0 * aspect, 3.0), 10.0)), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.imshow(m.occupied, cmap="gray_r", vmin=0, vmax=1, origin="lower", extent=extent,
              interpolation="nearest")
    ax.add_collection(LineCollection(m.tree, colors="blue", linewidths=0.5, label="tree"))
    if m.path is not None:
        ax.plot(m.path[:, 1], m.path[:, 2], color="red", lw=2.0, label="path")
    arrow = 0.04 * (extent[1] - extent[0])          # heading arrows [m], sized to the map
    for pose, marker, label in ((m.start, "o", "start"), (m.goal, "*", "goal")):
        ax.plot(pose[0], pose[1], marker, color="#2ca02c", ms=10, mec="black", label=label)
        ax.arrow(pose[0], pose[1], arrow * math.cos(pose[2]), arrow * math.sin(pose[2]),
                 width=arrow / 12, color="#2ca02c", length_includes_head=True)
    ax.set(xlim=extent[:2], ylim=extent[2:], xlabel=m.axes[0].xlabel, ylabel=m.axes[0].ylabel,
           title=f"{m.name}: {m.status}")
    ax.set_aspect("equal")
    ax.legend(fontsize=8, loc="best")
    return _save(fig, out_dir, m.file)


def plans(data: ft.Plans, out_dir: Path) -> Shown:
    """Figure 7: a PNG per planned scenario, with its sub-caption."""
    return Shown(data.number, data.title, data.caption,
                 [(_plan_png(m, out_dir), m.caption) for m in data.maps])


def tradeoff(data: ft.Tradeoff, out_dir: Path) -> Shown:
    """Figure 8: plan time against replay deviation, a marker per integrator."""
    fig = Figure(figsize=(8.0, 5.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    dev, time = data.deviation_m, data.time_s
    for k, name in enumerate(data.integrator):
        colour = f"C{k % 10}"
        ax.plot([dev[k], data.deviation_max_m[k]], [time[k]] * 2, color=colour, lw=0.8,
                alpha=0.6)
        ax.scatter(dev[k], time[k], s=SIZE_PT2 * data.exact_rate[k], color=colour, alpha=0.8,
                   marker="s" if data.paper[k] else "o",
                   edgecolors="black" if data.tuned[k] else "none", linewidths=2.0)
        ax.annotate(name, (dev[k], time[k]), xytext=(6, 6), textcoords="offset points",
                    fontsize=8)
    front = np.flatnonzero(data.pareto)
    front = front[np.argsort(dev[front])]
    ax.plot(dev[front], time[front], "k--", lw=1.0)
    if data.margin:
        ax.axvline(data.margin, color="black", ls=":", lw=1.0)
    spec = data.axes[0]
    ax.set(xscale=spec.xscale, yscale=spec.yscale, xlabel=spec.xlabel, ylabel=spec.ylabel)
    ax.grid(True, which="major", lw=0.3)
    handles = [Line2D([], [], marker="o", color="grey", ls="", mec="black", mew=2, ms=10),
               Line2D([], [], marker="s", color="grey", ls="", ms=10),
               Line2D([], [], color="black", ls="--")]
    labels = ["tuned choice", "the paper's RK4", "Pareto front"]
    if data.margin:
        handles.append(Line2D([], [], color="black", ls=":"))
        labels.append(f"the planner's margin {data.margin:g} m")
    ax.legend(handles, labels, fontsize=8, loc="best")
    _save(fig, out_dir, data.file)
    return _one(data)


# The renderer of each figure record's type.
RENDER: dict[type, Callable[..., Shown]] = {
          ft.Trajectories: trajectories, ft.Regions: regions, ft.ErrorVsStep: error_vs_step,
          ft.WorkPrecision: work_precision, ft.StableStep: stable_step, ft.Plans: plans,
          ft.Tradeoff: tradeoff}


def draw(data, out_dir: Path) -> Shown:
    """Render the figure record `data` as PNG(s) into out_dir; its Shown record."""
    return RENDER[type(data)](data, Path(out_dir))
