"""The report's figure data (reports/figure_data.py) on the tiny sweep: each plotted series is
the result tables' own numbers, a region's boundary is where |R(z)| = 1, and the two
renderers draw those numbers and nothing they compute themselves."""
import ast
from pathlib import Path

import numpy as np
import pytest

from stepzoo.integrators import METHODS
from stepzoo.integrators.stability import amplification_theory
from stepzoo.reports import figure_data, figures, interactive
from stepzoo.reports.load import load_sweep

TUNED = {"method": "heun", "h": 0.01, "pos_tol_m": 0.05, "margin": 0.2}
REPORTS = Path(figure_data.__file__).parent


@pytest.fixture(scope="module")
def sweep(tiny_sweep):
    return load_sweep(tiny_sweep[1])


def test_figure_4_plots_each_steps_worst_error_over_the_points(sweep):
    """Per method, h and err are runs.parquet's steps stable at both points and the largest
    error norm over them; the dashed line rises with the declared order's slope."""
    data = figure_data.error_vs_step(sweep, [("heun", 0.05)])
    runs = sweep.runs
    assert [p.method for p in data.panels] == ["euler", "heun"]
    for p in data.panels:
        mine = runs[runs["method"] == p.method]
        ok = mine.groupby("h")["stable"].all()
        worst = mine.groupby("h")["err"].max()[ok]
        np.testing.assert_array_equal(p.h, worst.index.to_numpy())
        np.testing.assert_array_equal(p.err, worst.to_numpy())
        hh, yy, order = p.slope
        assert order == {"euler": 1, "heun": 2}[p.method]
        assert np.log(yy[1] / yy[0]) / np.log(hh[1] / hh[0]) == pytest.approx(order)
    assert [p.verdicts for p in data.panels] == [[], [0.05]]
    # The interactive renderer draws those very numbers.
    traces = {t.name.split(" ")[0]: t for t in interactive.draw(data)[0].data if t.mode ==
              "lines+markers"}
    for p in data.panels:
        np.testing.assert_array_equal(np.asarray(traces[p.method].y), p.err)


def test_figure_6_plots_the_limits_table(sweep):
    """Per method and delta, x, predicted and measured limits are limits.parquet's rows by
    vx; each point is a blow-up, a failed solve, or untried, never two."""
    data = figure_data.stable_step_vs_speed(sweep)
    assert data.xvar == "vx" and data.cvar == "delta" and data.values == [0.3]
    for p in data.panels:
        rows = sweep.limits[sweep.limits["method"] == p.method].sort_values("vx")
        (c,) = p.curves
        np.testing.assert_array_equal(c.x, rows["vx"].to_numpy(float))
        np.testing.assert_array_equal(c.pred, rows["h_pred"].to_numpy(float))
        np.testing.assert_array_equal(c.meas, rows["h_meas"].to_numpy(float))
        assert (c.blowup.astype(int) + c.solver + c.untried == 1).all()
        assert c.h_tried == 0.1
        assert not p.unlimited                     # both are explicit: a finite limit


def test_figures_1_2_plot_the_trajectories_table(sweep):
    """Every sampled run and the reference are trajectories.parquet's rows in time order;
    a run is past its limit exactly where the sweep marked it."""
    traj = sweep.trajectories
    one, two = figure_data.yaw_rate(sweep, tuned=TUNED), figure_data.xy_paths(sweep)
    ref = traj[traj["method"] == "reference"].sort_values("t")
    np.testing.assert_array_equal(one.reference[1], ref["r"].to_numpy())
    np.testing.assert_array_equal(two.reference[0], ref["X"].to_numpy())
    assert one.tuned == "heun" and two.equal and not one.equal
    for p in one.panels:
        for run in p.runs:
            rows = traj[(traj["method"] == p.method) & (traj["h"] == run.h)].sort_values("t")
            np.testing.assert_array_equal(run.x, rows["t"].to_numpy())
            np.testing.assert_array_equal(run.y, rows["r"].to_numpy())
            assert run.past == bool(rows["past_limit"].any())
        stable = [ref["r"].to_numpy()] + [r.y for r in p.runs if not r.past]
        assert p.hi[1] == max(np.nanmax(y[np.isfinite(y)]) for y in stable)


def test_figure_5_picks_the_tuned_point_of_its_lines(sweep):
    """The tuned star is heun's point at h = 0.01 s, whose worst position error is the
    largest err_pos over the points; the costs are the medians the tables use."""
    data = figure_data.work_precision(sweep, TUNED)
    runs = sweep.runs[(sweep.runs["method"] == "heun") & (sweep.runs["h"] == 0.01)]
    assert list(data.pick.h) == [0.01] and data.tol == 0.05
    assert data.pick.worst[0] == runs["err_pos"].max()
    assert data.pick.evals_per_s[0] == runs["evals_per_s"].median()
    assert data.pick.time_per_s[0] == pytest.approx(runs["time_per_step_s"].median() / 0.01)
    heun = next(line for line in data.lines if line.method == "heun")
    assert 0.01 in heun.h and data.file == "fig5_work_precision.png"


def test_figure_3_boundary_is_where_the_amplification_is_one(sweep):
    """Every point of each drawn boundary has |R(z)| = 1 to the grid's interpolation, and
    RK4-like heun's crosses the real axis at -2 (|1 + z + z^2/2| = 1)."""
    data = figure_data.stability_regions(sweep, TUNED)
    assert [p.method for p in data.panels] == ["euler", "heun"]
    for p in data.panels:
        x, y = p.boundary
        z = (x + 1j * y)[np.isfinite(x)]
        amp = amplification_theory(METHODS[p.method], z)
        assert np.abs(amp - 1.0).max() < 0.02
        on_axis = z[np.abs(z.imag) < 1e-9].real
        assert on_axis.min() == pytest.approx(-2.0, abs=0.01)
    # h*lambda of the envelope sits inside both regions at the tuned step.
    assert data.z.size and not data.outside.any()
    assert "euler, heun." in data.caption


def test_the_png_renderer_writes_each_figures_file_and_caption(sweep, tmp_path):
    for data in (figure_data.error_vs_step(sweep), figure_data.plans([])):
        shown = figures.draw(data, tmp_path)
        assert shown.caption == data.caption and shown.number == data.number
    assert (tmp_path / "fig4_error_vs_step.png").read_bytes()[:4] == b"\x89PNG"
    assert shown.images == []                       # no plan, no scenario image


def test_the_renderers_import_only_the_figure_records():
    """Neither renderer computes from the tables nor reaches into the other: of stepzoo
    they import only figure_types (and output, to write a file)."""
    for name in ("figures.py", "interactive.py"):
        tree = ast.parse((REPORTS / name).read_text())
        imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        imported |= {f"{n.module}.{a.name}" for n in ast.walk(tree)
                     if isinstance(n, ast.ImportFrom) for a in n.names}
        imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import)
                     for a in n.names}
        ours = {m for m in imported if m and m.startswith("stepzoo")}
        assert ours <= {"stepzoo.reports", "stepzoo.reports.figure_types", "stepzoo.output",
                        "stepzoo.output.atomic_write"}, (name, ours)
        assert "pandas" not in imported and not any("figure_data" in m for m in ours)


STIFFENING = '''import jax.numpy as jnp


def f(t, x, u, p):
    """x' = -(1 + a min(t, 1)) x: its one eigenvalue stiffens from -1 1/s at t = 0 to
    -(1 + a) at t = 1 s, and stays there (the stability runs go on past the horizon)."""
    return jnp.stack([-(1.0 + p["a"] * jnp.minimum(t, 1.0)) * x[0]])
'''


def test_figure_3_judges_stability_along_the_trajectory(tmp_path):
    """x' = -(1 + 50 min(t, 1)) x over 1 s: at the initial state h lambda = -0.05 at h = 0.05 s, inside
    Euler's disc; at t = 1 s it is -2.55, outside. Figure 3 draws the binding eigenvalue and
    calls Euler stable on the envelope only where it is along the trajectory (rk4's -2.55 is
    inside its region, to -2.785)."""
    from stepzoo.bench.sweep.engine import run_sweep
    from stepzoo.bench.sweep.config import load
    (tmp_path / "stiffening.py").write_text(STIFFENING)
    config = tmp_path / "s.toml"
    config.write_text(f'name = "s"\nhorizon = 1.0\nmethods = ["euler", "rk4"]\n[model]\n'
                      f'rhs = "stiffening:f"\nstates = ["x"]\npath = "{tmp_path}"\n'
                      "[params]\na = 50.0\n[initial]\nx = 1.0\n[envelope]\na = [50.0]\n"
                      "[steps]\nh = [0.01, 0.02]\n[stability]\nrule = \"blowup\"\nsteps = 100\n")
    run_sweep(load(config), tmp_path / "out", progress=False)
    sweep = load_sweep(tmp_path / "out")
    data = figure_data.stability_regions(sweep, {"method": "euler", "h": 0.05})
    # The binding eigenvalue is the last sample's, -(1 + 50 x 1 s), NumPy's own.
    assert np.min(data.z.real) == pytest.approx(0.05 * -(1.0 + 50.0), rel=1e-9)
    assert data.outside.any()
    safe = data.caption.rsplit(":", 1)[1]
    assert "rk4" in safe and "euler" not in safe
