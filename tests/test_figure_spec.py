"""One figure spec: each report figure's axes (labels with units, scales) and series live in
its figure record, and the PNG and the interactive renderer both draw exactly those: the same
axis labels and scales, and every series the record names, in each figure of the report."""
import numpy as np
import pandas as pd
import pytest

from helpers import write_plan
from stepzoo.reports import figure_data, figures, interactive
from stepzoo.reports import figure_types as ft
from stepzoo.reports.load import load_plans, load_sweep
from stepzoo.reports.tradeoff import tradeoff, tradeoff_points

TUNED = {"method": "heun", "h": 0.01, "pos_tol_m": 0.05, "margin": 0.2}


def _tradeoff_record():
    rows = pd.DataFrame({
        "integrator": ["rk4:0.02", "euler:0.01", "heun:0.01"], "method": ["rk4", "euler", "heun"],
        "h": [0.02, 0.01, 0.01], "role": ["given", "given", "tuned"],
        "median_time_s": [1.0, 0.6, 0.8], "median_replay_deviation_m": [0.001, 0.2, 0.01],
        "max_replay_deviation_m": [0.002, 0.4, 0.03], "exact_rate": [1.0, 0.5, 1.0]})
    rows.attrs["margin_m"] = 0.1
    return tradeoff(tradeoff_points(rows))


@pytest.fixture(scope="module")
def records(tiny_sweep, tmp_path_factory):
    sweep = load_sweep(tiny_sweep[1])
    plans = tmp_path_factory.mktemp("plans")
    write_plan(plans)
    return {
        "trajectories": figure_data.xy_paths(sweep, tuned=TUNED),
        "yaw rate": figure_data.yaw_rate(sweep, tuned=TUNED),
        "regions": figure_data.stability_regions(sweep, TUNED),
        "error": figure_data.error_vs_step(sweep, [("heun", 0.05)]),
        "work": figure_data.work_precision(sweep, TUNED),
        "limits": figure_data.stable_step_vs_speed(sweep, [("heun", 0.05)]),
        "plans": figure_data.plans(load_plans(plans)),
    }


def _png_figures(record, tmp_path, monkeypatch) -> list:
    drawn = []

    def keep(fig, out_dir, name):
        drawn.append(fig)
        return name
    monkeypatch.setattr(figures, "_save", keep)
    figures.draw(record, tmp_path)
    return drawn


def _png_axes(fig) -> set:
    labelled = [ax for ax in fig.axes if ax.get_xlabel() or ax.get_ylabel()]
    # A shared y label is written beside the first panel only.
    ylabel = next((ax.get_ylabel() for ax in labelled if ax.get_ylabel()), "")
    return {(ax.get_xlabel(), ax.get_ylabel() or ylabel, ax.get_xscale(), ax.get_yscale())
            for ax in labelled}


def _png_texts(fig) -> set:
    texts = {ax.get_title() for ax in fig.axes} | {t.get_text() for ax in fig.axes
                                                   for t in ax.texts}
    for legend in [*fig.legends, *(ax.get_legend() for ax in fig.axes)]:
        if legend is not None:
            texts |= {t.get_text() for t in legend.get_texts()}
    return texts


def _plotly_axes(fig) -> set:
    lay = fig.layout
    xs = [lay[k] for k in lay if k.startswith("xaxis")]
    ys = [lay[k] for k in lay if k.startswith("yaxis")]
    # A shared y title is written on the first y axis only.
    ytitle = next(y.title.text for y in ys if y.title.text)
    return {(x.title.text, y.title.text or ytitle, x.type, y.type) for x, y in zip(xs, ys)}


def _plotly_texts(fig) -> set:
    return {str(t) for tr in fig.data for t in (tr.name, tr.legendgroup, tr.meta) if t} | \
        {fig.layout.title.text or ""}


def _expected_axes(record) -> set:
    return {(a.xlabel, a.ylabel, a.xscale, a.yscale) for a in record.axes}


def _named(series: str, texts: set) -> bool:
    return any(t == series or t.startswith(series + " ") or t.startswith(series + ":")
               or t.startswith(series + ",") for t in texts)


def _check(record, tmp_path, monkeypatch):
    parts = record.maps if isinstance(record, ft.Plans) else [record]
    pngs = _png_figures(record, tmp_path, monkeypatch)
    htmls = interactive.draw(record)
    assert len(pngs) == len(htmls) == len(parts)
    for part, png, html in zip(parts, pngs, htmls):
        want = _expected_axes(part)
        assert _png_axes(png) == want
        assert _plotly_axes(html) == want
        for series in part.series:
            assert _named(series, _png_texts(png)), (series, _png_texts(png))
            assert _named(series, _plotly_texts(html)), (series, _plotly_texts(html))


@pytest.mark.parametrize("name", ["trajectories", "yaw rate", "regions", "error", "work",
                                  "limits", "plans"])
def test_png_and_interactive_figure_carry_the_records_labels_scales_and_series(
        records, name, tmp_path, monkeypatch):
    _check(records[name], tmp_path, monkeypatch)


def test_tradeoff_figure_carries_the_records_labels_scales_and_series(tmp_path, monkeypatch):
    _check(_tradeoff_record(), tmp_path, monkeypatch)


def test_the_labels_a_renderer_writes_come_from_the_figure_types_module():
    """No axis label is spelled inside a renderer: each comes from the record."""
    import inspect
    for module in (figures, interactive):
        source = inspect.getsource(module)
        for label in (ft.H_LABEL, ft.LIMIT_LABEL, ft.EVALS_LABEL, ft.TIME_LABEL,
                      ft.DEVIATION_LABEL, ft.PLAN_TIME_LABEL, "[s]\"", "X [m]"):
            assert label not in source, (module.__name__, label)
    assert np.all([isinstance(a, ft.Axes) for a in _tradeoff_record().axes])
