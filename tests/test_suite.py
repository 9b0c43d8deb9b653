"""Suites: the standard test problems in one sweep. Observed orders on DETEST match the declared
ones within 0.2 on the asymptotic range the fit picks itself; a suite config sweeps each
problem into a folder of its own (an ordinary sweep folder) and writes their tables together
with a `problem` column and the orders table; commands that read one problem refuse a suite
in one line."""
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stepzoo.bench.sweep import metrics
from stepzoo.bench.sweep import tables as schema
from stepzoo.cli import main as stepzoo
from stepzoo.bench.sweep.suite import load, run_suite
from stepzoo.bench.tune.cheapest import tune
from stepzoo.dynamics import model
from stepzoo.dynamics.solutions import solve
from stepzoo.errors import UsageError
from stepzoo.integrators import integrate_batch, method

CONFIGS = Path(__file__).resolve().parents[1] / "bench" / "configs"
SUBSET = ["detest_a1", "detest_b1", "detest_d1", "detest_e1"]
METHODS = ["euler", "rk4", "ab3", "trapezoidal"]
FINEST = 20 * 2 ** 12        # steps over [0, 20] of the finest grid step


def test_the_shipped_suites_cover_the_standard_sets():
    """Every config in bench/configs loads; DETEST A, B, D, E and the stiff set run whole, the
    dynamic bicycle with each tyre law, each over its published interval."""
    for path in CONFIGS.glob("*.toml"):
        load(path)
    detest = load(CONFIGS / "detest.toml")
    assert {f"detest_{c}{i}" for c in "abde" for i in range(1, 6)} <= set(detest.labels)
    assert all(cfg.horizon == 20.0 for _, cfg, _ in detest.problems)
    stiff = load(CONFIGS / "stiff.toml")
    assert {"robertson", "vdp1000", "hires", "stiff_linear"} <= set(stiff.labels)
    horizons = {label: cfg.horizon for label, cfg, _ in stiff.problems}
    vdp = horizons.pop("vdp1000")       # its slow branch: the first jump comes at 0.807 mu
    assert vdp < (1.5 - np.log(2)) * model("vdp1000").params()["mu"]
    assert horizons.pop("vdp1000-explicit") == vdp
    # Past the initial layer: each model's own solution at t = 1 s, run to the same end.
    for name, end in (("robertson", 40.0), ("vdp1000", vdp)):
        slow = stiff.problems[stiff.labels.index(f"{name}-slow")][1]
        assert horizons.pop(f"{name}-slow") == end - 1.0
        m = model(name)
        at_1s = solve(m.rhs, m.x0, np.zeros(0), m.params(), [0.0, 1.0], stiff=True,
                      method="Radau", rtol=1e-10, atol=1e-14)[-1]
        assert slow.spec.arrays(slow.points)[0][0] == pytest.approx(at_1s, rel=1e-7)
    assert horizons == {label: model(cfg.spec.name).t_span[1] for label, cfg, _ in stiff.problems
                        if label in horizons}
    # Each model's methods: the A(alpha)-stable ones on the model, the rest on its fine grid.
    for label in ("robertson", "vdp1000", "hires", "stiff_linear"):
        ran = set(stiff.problems[stiff.labels.index(label)][1].methods)
        fine = set(stiff.problems[stiff.labels.index(f"{label}-explicit")][1].methods)
        assert not ran & fine and ran | fine == set(stiff.methods)
    tyres = load(CONFIGS / "tyre_laws.toml")
    assert [cfg.spec.tyre for _, cfg, _ in tyres.problems] == ["linear", "pacejka", "fiala"]


@pytest.mark.parametrize("problem", SUBSET)
def test_observed_orders_on_detest_are_the_declared_ones(problem):
    """Every grid step in one batch (each lane its own h, all run FINEST steps; the error is
    read over each lane's first 20 s), against the problem's truth on the finest grid."""
    m = model(problem)
    ns = 20 * 2 ** np.arange(1, 13)
    hs = 20.0 / ns
    truth = m.solution(hs[-1] * np.arange(FINEST + 1))
    scale = np.abs(truth).max()
    x0 = np.tile(np.asarray(m.x0), (len(hs), 1))
    for name in METHODS:
        x = np.asarray(integrate_batch(name, m.rhs, x0, None, m.params(), hs, FINEST).x)
        with np.errstate(invalid="ignore", over="ignore"):
            err = [np.abs(x[k, : n + 1] - truth[:: FINEST // n]).max()
                   for k, n in enumerate(ns)]
        fit = metrics.order_fit(hs, err, 1e-14, 1e-16, scale)
        assert fit.note == "asymptotic", (name, fit)
        assert abs(fit.order - method(name).order) <= metrics.ORDER_TOL, (name, fit)
        assert metrics.order_status(fit.order, method(name).order, fit.note) == "matches"


def test_order_fit_takes_the_asymptotic_range_between_pre_asymptotic_and_floor():
    """err = h^3 (1 + 40 h^2) + 1e-12: the h^2 term bends the coarse steps, the floor the
    finest; the fit keeps the steps in between and finds 3."""
    hs = 0.8 / 2 ** np.arange(14)
    err = hs ** 3 * (1 + 40 * hs ** 2) + 1e-12
    fit = metrics.order_fit(hs, err, 1e-12, 1e-14, 1.0)
    assert fit.note == "asymptotic"
    assert fit.order == pytest.approx(3.0, abs=0.02)
    assert fit.h_max < 0.1 and fit.h_min > hs[-1]          # neither end of the grid
    assert fit.points >= 3
    # Round-off growing as 1/h (the number of steps) below h = 0.01: slopes of -1 agree too.
    rising = metrics.order_fit(hs, hs ** 3 + 1e-8 / hs, 1e-30, 1e-30, 1.0)
    assert rising.note == "asymptotic"
    assert rising.order == pytest.approx(3.0, abs=0.05) and rising.h_min > 0.02
    sinking = metrics.order_fit(hs, 10.0 ** -np.arange(14.0) * (1 + (np.arange(14) % 2)),
                                1e-30, 1e-30, 1.0)            # local slopes alternate
    assert sinking.note.startswith("no asymptotic range")
    assert metrics.order_status(sinking.order, 3, sinking.note) == "no asymptotic range"
    # An order off the declared one where even the finest step of the fit has h rho > 1 is
    # the stiff range's; the same below h rho = 1 is below declared.
    assert metrics.order_status(1.0, 5, "asymptotic", 2 * metrics.STIFF_H_RHO) == "stiff range"
    assert metrics.order_status(1.0, 5, "asymptotic", metrics.STIFF_H_RHO / 2) == \
        "below declared"
    assert metrics.order_status(5.1, 5, "asymptotic", 100.0) == "matches"
    none = metrics.order_fit([], [], 1e-12, 1e-14, 1.0)
    assert np.isnan(none.order) and none.note == "unstable at every step"
    assert metrics.order_status(none.order, 1, none.note) == "not observable"


SUITE = """
name = "mini"
methods = ["rk4", "trapezoidal"]
[steps]
h = { min = 0.05, max = 0.4, num = 4 }
[reference]
rtol = 1e-12
atol = 1e-14
[stability]
rule = "blowup"
steps = 100
h_probe_max = 20.0
rel_tol = 0.01
[timing]
rounds = 1
[[problem]]
model = "detest_a1"
reference.exact = true
[[problem]]
name = "b2_short"
model = "detest_b2"
horizon = 4.0
methods = ["rk4"]
reference.solver = "DOP853"
error.estimate = "final"
steps.h = { min = 0.02, max = 0.2, num = 4 }
"""


@pytest.fixture(scope="module")
def suite(tmp_path_factory):
    folder = tmp_path_factory.mktemp("suite")
    (folder / "mini.toml").write_text(SUITE)
    cfg = load(folder / "mini.toml")
    manifest = run_suite(cfg, folder / "out", progress=False)
    return cfg, folder / "out", manifest


def test_each_problem_is_an_ordinary_sweep_with_its_own_settings(suite):
    cfg, out, manifest = suite
    assert manifest["complete"] and manifest["problems"] == ["detest_a1", "b2_short"]
    a1, b2 = cfg.problems[0][1], cfg.problems[1][1]
    assert (a1.horizon, b2.horizon) == (20.0, 4.0)      # the published interval; its own
    assert b2.hs[0] == pytest.approx(0.02) and a1.hs[0] == pytest.approx(0.05)
    assert a1.spec.envelope == (("y1", (1.0,)),)        # the published initial value
    for label, problem, _ in cfg.problems:
        sub = json.loads((out / label / "manifest.json").read_text())
        assert sub["complete"] and sub["config_sha256"] == problem.sha256
        assert sub["config_sha256"] == manifest["problem_sha256"][label]
    tuned = tune(out / "b2_short", None, 0.2, tol=1e-3)
    assert tuned["method"] in ("rk4", "trapezoidal")


def test_an_exact_reference_is_the_closed_form(suite):
    """A1 (y' = -y) against exp(-t) itself: the sweep's rk4 error at each step is the one
    computed here from the closed form; B2's reference is SciPy's DOP853 (reference.solver)."""
    _, out, _ = suite
    kinds = {p: json.loads((out / p / "manifest.json").read_text())["reference"]
             for p in ("detest_a1", "b2_short")}
    assert kinds["detest_a1"].startswith("the model's closed form")
    assert kinds["b2_short"].startswith("SciPy's DOP853")
    runs = pd.read_parquet(out / "detest_a1" / "runs.parquet")
    rk4 = runs[runs["method"] == "rk4"].sort_values("h")
    ns = rk4["n_steps"].to_numpy()
    x = np.asarray(integrate_batch("rk4", model("detest_a1").rhs, np.ones((len(ns), 1)), None,
                                   {}, rk4["h"].to_numpy(), int(ns.max())).x)[..., 0]
    err = [np.abs(x[k, : n + 1] - np.exp(-h * np.arange(n + 1))).max()
           for k, (n, h) in enumerate(zip(ns, rk4["h"]))]
    assert rk4["err"].to_numpy() == pytest.approx(err, rel=1e-9, abs=1e-16)


def test_a_final_error_estimate_is_the_error_at_the_horizon(suite):
    """B2 with error.estimate = "final": each rk4 run's err is its distance from B2's closed
    form at t = 4 s (the reference's own error, 1e-12, is far below rk4's)."""
    _, out, _ = suite
    manifest = json.loads((out / "b2_short" / "manifest.json").read_text())
    assert manifest["error_estimate"].startswith("the scaled error at the end")
    runs = pd.read_parquet(out / "b2_short" / "runs.parquet")
    rk4 = runs[runs["method"] == "rk4"].sort_values("h")
    b2 = model("detest_b2")
    ns = rk4["n_steps"].to_numpy()
    x = np.asarray(integrate_batch("rk4", b2.rhs, np.tile(b2.x0, (len(ns), 1)), None, {},
                                   rk4["h"].to_numpy(), int(ns.max())).x)
    final = [np.abs(x[k, n] - b2.exact(np.array([0.0, 4.0]))[-1]).max()
             for k, n in enumerate(ns)]
    assert rk4["err"].to_numpy() == pytest.approx(final, rel=1e-4)
    assert (rk4["err"] < rk4[["err_y1", "err_y2", "err_y3"]].max(axis=1)).all()
    from stepzoo.reports.load import load_sweep
    assert load_sweep(out / "b2_short").view.error_label.startswith("error at the end")
    assert load_sweep(out / "detest_a1").view.error_label.startswith("error (error states")


def test_figure_4_says_which_error_it_draws(suite, tmp_path):
    """Its caption gives the error at the end of the run where the sweep's estimate is
    "final", and the largest over the run otherwise."""
    from stepzoo.reports.figure_data import error_vs_step
    from stepzoo.reports.load import load_sweep
    _, out, _ = suite
    final = error_vs_step(load_sweep(out / "b2_short")).caption
    largest = error_vs_step(load_sweep(out / "detest_a1")).caption
    assert "at the end of the run" in final and "over the run" not in final
    assert "over the run" in largest and "at the end of the run" not in largest


def test_the_verdict_s_error_is_the_sweep_s_on_a_final_error_config(suite):
    """The verdict takes a run's error as the sweep does: on b2_short (error.estimate =
    "final") rk4's verdict err at the finest step is the sweep's err of that run, the error
    at the horizon, not the larger maximum over the run."""
    from stepzoo.bench.tune.verdict import verdict
    cfg, out, _ = suite
    b2 = dict((label, c) for label, c, _ in cfg.problems)["b2_short"]
    runs = pd.read_parquet(out / "b2_short" / "runs.parquet")
    run = runs[(runs["method"] == "rk4") & (runs["h"] == min(b2.hs))].iloc[0]
    table = verdict(b2, "rk4", float(run["h"]))
    assert bool(table["stable"].iloc[0])
    assert table["err"].iloc[0] == pytest.approx(run["err"], rel=1e-12)
    assert run["err"] < run[["err_y1", "err_y2", "err_y3"]].max()


def test_suite_tables_are_the_problems_tables_with_a_problem_column(suite):
    cfg, out, _ = suite
    for name in schema.PARQUET:
        whole = pd.read_parquet(out / f"{name}.parquet")
        assert whole.columns[0] == "problem"
        for label in cfg.labels:
            part = whole[whole["problem"] == label].drop(columns="problem")
            own = pd.read_parquet(out / label / f"{name}.parquet")
            part = part[own.columns].reset_index(drop=True)
            pd.testing.assert_frame_equal(part, own, check_dtype=False)
    summary = pd.read_csv(out / "summary.csv")
    orders = pd.read_csv(out / "orders.csv").set_index("method")
    assert list(orders.columns) == ["order_declared", "detest_a1", "b2_short"]
    for _, row in summary.iterrows():
        assert orders.loc[row["method"], row["problem"]] == pytest.approx(
            row["order_fit_median"], nan_ok=True)
    a1 = summary[summary["problem"] == "detest_a1"].set_index("method")
    assert a1.loc["trapezoidal", "order_status"] == "matches"
    # b2_short runs rk4 alone: the suite's methods are every problem's, each once.
    assert list(summary[summary["problem"] == "b2_short"]["method"]) == ["rk4"]
    assert np.isnan(orders.loc["trapezoidal", "b2_short"])
    assert cfg.methods == ("rk4", "trapezoidal")
    limits = pd.read_parquet(out / "limits.parquet")
    assert {"order_h_min", "order_h_max", "order_points", "order_note"} <= set(limits)
    # rho_max: A1's Jacobian is -1; B2's matrix [[-1, 1, 0], [1, -2, 1], [0, 1, -1]] has
    # eigenvalues 0, -1 and -3 (Hull et al. 1972): spectral radii 1 and 3 s^-1.
    rho = limits.groupby("problem")["rho_max"].agg(["min", "max"])
    assert rho.loc["detest_a1"].tolist() == pytest.approx([1.0, 1.0], rel=1e-12)
    assert rho.loc["b2_short"].tolist() == pytest.approx([3.0, 3.0], rel=1e-12)
    assert np.allclose(limits["order_h_rho"], limits["order_h_min"] * limits["rho_max"],
                       equal_nan=True)
    runs = pd.read_parquet(out / "runs.parquet")
    assert np.allclose(runs["time_s"], runs["time_per_step_s"] * runs["n_steps"])


def test_a_suite_is_refused_where_one_problem_is_read(suite, capsys):
    cfg, out, _ = suite
    with pytest.raises(UsageError, match="suite of 2 problems .* such as .*detest_a1"):
        tune(out, None, 0.2, tol=1e-3)
    assert stepzoo(["verdict", str(out / "config.toml"), "--method", "rk4", "--h",
                    "0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "suite of 2 problems" in err
    assert stepzoo(["sweep", cfg.source, "--out", str(out)]) == 2      # it holds a sweep
    assert "--resume" in capsys.readouterr().err
    assert stepzoo(["run", "--config", cfg.source, "--out", str(out.parent / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "suite of 2 problems" in err


def test_a_resumed_suite_computes_nothing_again(suite):
    cfg, out, _ = suite
    before = {p: p.stat().st_mtime_ns for p in out.glob("*/chunks/*")}
    again = run_suite(cfg, out, resume=True, progress=False)
    assert again["complete"]
    assert {p: p.stat().st_mtime_ns for p in out.glob("*/chunks/*")} == before


def test_the_suite_output_counts_each_methods_matching_problems(suite, capsys):
    """The text output's by-method table: per method, the problems whose summary says
    "matches", and every other problem with its observed order and status."""
    cfg, out, _ = suite
    assert stepzoo(["sweep", cfg.source, "--out", str(out), "--resume", "-q"]) == 0
    text = capsys.readouterr().out
    table = text.split("by method:")[1].splitlines()[2:2 + len(cfg.methods)]
    summary = pd.read_csv(out / "summary.csv")
    for line, (name, own) in zip(table, summary.groupby("method")):
        matching = (own["order_status"] == "matches").sum()
        assert line.split()[:3] == [name, str(own["order_declared"].iloc[0]),
                                    f"{matching}/{len(own)}"]
        for r in own[own["order_status"] != "matches"].itertuples():
            assert f"{r.problem} {r.order_fit_median:.2f} {r.order_status}" in line


def test_a_problem_with_no_eigenvalue_to_list_keeps_the_tables_columns(tmp_path, monkeypatch):
    """DETEST A5's Jacobian is 0 at its initial state, so its eigenvalues table has no row;
    the table still has its columns, and the report reads the folder (a config without a
    name: the folder's copy names the sweep as the file's stem did). A figure run keeps at
    most TRAJ_ROWS states, spread from its first to its last, each the run's own state."""
    from stepzoo.bench.sweep.runs import figure_runs as trajectory_runs
    from stepzoo.bench.sweep.engine import run_sweep
    monkeypatch.setattr(trajectory_runs, "TRAJ_ROWS", 6)
    from stepzoo.bench.sweep.config import load as load_config
    from stepzoo.reports.load import load_sweep
    (tmp_path / "a5.toml").write_text(
        'model = "detest_a5"\nhorizon = 20.0\nmethods = ["euler"]\n'
        '[envelope]\ny1 = { values = [4.0] }\n[steps]\nh = [1.0, 2.0]\n'
        '[stability]\nrule = \"blowup\"\nsteps = 50\nh_probe_max = 4.0\n[timing]\nrounds = 1\n')
    run_sweep(load_config(tmp_path / "a5.toml"), tmp_path / "a5", progress=False)
    eig = pd.read_parquet(tmp_path / "a5" / "eigenvalues.parquet")
    assert len(eig) == 0 and {"point", "lam_re", "lam_im"} <= set(eig.columns)
    assert len(load_sweep(tmp_path / "a5").runs) == 2
    traj = pd.read_parquet(tmp_path / "a5" / "trajectories.parquet")
    a5 = model("detest_a5")
    # (Two of the figure runs share h = 1 s, the grid's smallest; the table sorts on t.)
    for h, run in traj[traj["method"] == "euler"].groupby("h"):
        run = run.drop_duplicates("t")
        n = int(np.floor(20.0 / h + 1e-9))
        assert len(run) == min(n + 1, 6) and run["t"].iloc[0] == 0.0
        assert run["t"].iloc[-1] == pytest.approx(n * h)
        full = np.asarray(integrate_batch("euler", a5.rhs, np.array([[4.0]]), None, {},
                                          np.array([h]), n).x)[0, :, 0]
        assert run["y1"].to_numpy() == pytest.approx(full[np.rint(run["t"] / h).astype(int)],
                                                     rel=1e-12)


@pytest.mark.parametrize("edit, message", [
    ('name = "detest_a1"\nmodel = "detest_a2"', "two problems are named 'detest_a1'"),
    ('model = "detest_a2"\nmethods = "stiff"', "methods must be one of 'all', 'explicit'"),
    ('model = "detest_a2"\nhorizon = -1.0', "[problem detest_a2]: horizon"),
    ('name = "a b"\nmodel = "detest_a2"', "name 'a b' must be letters"),
    ('model = "detest_b1"\nreference.exact = true', "closed form; detest_b1 has none"),
    ('model = "detest_b1"\nerror.estimate = "l2"', "error.estimate must be one of 'max', "),
    ('model = "detest_b1"\nreference.solver = "rk45"', "reference.solver must be one of"),
    ('model = "detest_b1"\nnewton = { tol = 1e-12 }',
     "unknown key newton.tol; known: atol, max_iter, max_iter_full, res_tol, rtol"),
    ('model = "detest_b1"\nnewton.max_iter = 2.5', "newton.max_iter must be an iteration limit"),
    ('model = "detest_b1"\nnewton = { rtol = 0.0, atol = 0.0 }',
     "newton.rtol and newton.atol are both 0"),
    ('model = "detest_a2"\nreference.exact = true\nenvelope.y1 = { values = [2.0] }',
     "keep [envelope], [initial] and [params] at its published values"),
])
def test_a_bad_problem_is_one_line_naming_it(tmp_path, capsys, edit, message):
    (tmp_path / "bad.toml").write_text(SUITE + "[[problem]]\n" + edit + "\n")
    assert stepzoo(["sweep", str(tmp_path / "bad.toml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_suite_report_gives_the_orders_and_work_precision_per_problem(suite, tmp_path):
    from stepzoo.workflows.report import build
    cfg, out, _ = suite
    index, md, shown = build(out, tmp_path / "report")
    assert [s.title for s in shown] == [f"Work-precision: {p}" for p in cfg.labels]
    assert all((tmp_path / "report" / name).is_file() for s in shown for name, _ in s.images)
    text = md.read_text()
    summary = pd.read_csv(out / "summary.csv")
    for _, row in summary.iterrows():
        assert f"| {row['problem']} | {row['method']} | {row['order_declared']} |" in text
    with pytest.raises(UsageError, match="suite of problems; --tuned"):
        build(out, tmp_path / "other", tuned_path=tmp_path / "tuned.toml")
    with pytest.raises(UsageError, match="suite of problems; .*--plan-bench belong"):
        build(out, tmp_path / "other", bench_dir=tmp_path)
    assert not (tmp_path / "other").exists()


def test_method_selectors_follow_the_stability_theory():
    """`methods = "bounded"`: explicit methods and Adams-Moulton 3 and 4 (Dahlquist's second
    barrier: no A-stable linear multistep method has order above 2); "unbounded": the A- and
    A(alpha)-stable rest (BDF3-5 have the whole negative real axis)."""
    from stepzoo.bench.sweep.config import selected
    explicit = selected("explicit")
    assert selected("bounded") == [m for m in selected("all") if m in explicit or
                                   m in ("am3", "am4")]
    assert sorted(selected("bounded") + selected("unbounded")) == sorted(selected("all"))
    assert {"bdf3", "bdf4", "bdf5", "radau_iia5", "trapezoidal"} <= set(selected("unbounded"))
    assert sorted(explicit + selected("implicit")) == sorted(selected("all"))


def test_naming_the_default_reference_solver_keeps_the_sha256(tmp_path):
    """reference.solver at the model's default (dopri5; LSODA for a stiff test problem) gives
    the same results, so the same sha256; another solver is another config."""
    from stepzoo.bench.sweep.config import load as load_config
    shas = {}
    for model_name, solver in (("detest_b1", ""), ("detest_b1", "dopri5"), ("detest_b1", "Radau"),
                               ("robertson", ""), ("robertson", "LSODA")):
        extra = f'\n[reference]\nsolver = "{solver}"\n' if solver else "\n"
        path = tmp_path / f"{model_name}-{solver}.toml"
        path.write_text(f'name = "s"\nmodel = "{model_name}"\nhorizon = 4.0\nmethods = ["rk4"]\n'
                        f'[envelope]\ny1 = {{ values = [1.0] }}\n[steps]\nh = [0.5, 1.0]\n'
                        f'[stability]\nh_probe_max = 4.0{extra}')
        shas[model_name, solver] = load_config(path).sha256
    assert shas["detest_b1", ""] == shas["detest_b1", "dopri5"] != shas["detest_b1", "Radau"]
    assert shas["robertson", ""] == shas["robertson", "LSODA"]
