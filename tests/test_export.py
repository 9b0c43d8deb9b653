"""`stepzoo export` takes the tuned (method, h) where it is used: acados' settings reproduce the
tuned step with acados' own tableau of the same method, the diffrax snippet runs and equals
stepzoo's fixed step, the step schedule is the largest step that qualifies per envelope value;
mistakes are one line and exit 2."""
import ast
import contextlib
import importlib.util
import io
import json
import tomllib

import numpy as np
import pandas as pd
import pytest

from stepzoo.bench.tune import export
from stepzoo.cli import main as stepzoo
from stepzoo.errors import NoAnswer
from stepzoo.integrators import integrate
from stepzoo.integrators.methods import TABLEAUS

POS_TOL = 1.0       # [m] loose: on the tiny sweep, euler qualifies (the choice) and heun too


@pytest.fixture(scope="module")
def tuned(tiny_sweep, tmp_path_factory):
    """(tuned file, its content, the sweep folder) of the tiny sweep, tuned in RHS
    evaluations: in time, heun's measured cost on a loaded machine beat euler's at times,
    and the tests below, which need euler as the choice, failed on the load."""
    _, sweep = tiny_sweep
    out = tmp_path_factory.mktemp("export") / "tuned.toml"
    assert stepzoo(["tune", str(sweep), "--pos-tol", str(POS_TOL), "--cost", "evals", "--out",
                    str(out)]) == 0
    return out, tomllib.loads(out.read_text()), sweep


@pytest.fixture(scope="module")
def exported(tuned, tmp_path_factory):
    """The JSON of `export --to json --interval 0.095 --out DIR`, and DIR."""
    path, _, _ = tuned
    folder = tmp_path_factory.mktemp("exported")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert stepzoo(["export", str(path), "--to", "json", "--interval", "0.095", "--out",
                        str(folder)]) == 0
    return json.loads(buf.getvalue()), folder


def test_tuned_config_records_its_sweep_folder(tuned):
    _, t, sweep = tuned
    assert t["sweep"] == str(sweep.resolve()) and export.sweep_of(t) == sweep.resolve()


@pytest.mark.parametrize("interval", ["whole", 0.095])
def test_acados_steps_reproduce_the_tuned_step(tuned, interval):
    """S a whole number of h: S / num_steps is h; otherwise the largest step below h that
    divides S (one step fewer would be longer than h)."""
    _, t, _ = tuned
    h = t["h"]
    S = 8 * h if interval == "whole" else interval
    a = export.acados(t, S)
    n = a["sim_method_num_steps"]
    assert a["method"] == t["method"] and a["h_tuned_s"] == h
    if interval == "whole":
        assert n == 8 and S / n == pytest.approx(h, rel=1e-15)
    else:
        assert S / n <= h < S / (n - 1)
    assert a["step_s"] == S / n


# acados' explicit tableaus (acados/sim/sim_erk_integrator.c, get_explicit_butcher_tableau):
# (A rows, b) for 1 to 4 stages.
ACADOS_ERK = {1: ([[0]], [1]), 2: ([[0, 0], [0.5, 0]], [0, 1]),
              3: ([[0, 0, 0], [0.5, 0, 0], [-1, 2, 0]], [1 / 6, 2 / 3, 1 / 6]),
              4: ([[0, 0, 0, 0], [0.5, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 1, 0]],
                  [1 / 6, 1 / 3, 1 / 3, 1 / 6])}


def _collocation(c):
    """The collocation tableau on nodes c: a_ij = integral of the j-th Lagrange basis
    polynomial from 0 to c_i, b_j the same to 1."""
    s = len(c)
    A, b = np.zeros((s, s)), np.zeros(s)
    for j in range(s):
        basis = np.poly1d([1.0])
        for k in range(s):
            if k != j:
                basis *= np.poly1d([1.0, -c[k]]) / (c[j] - c[k])
        integral = basis.integ()
        A[:, j] = integral(np.asarray(c)) - integral(0.0)
        b[j] = integral(1.0) - integral(0.0)
    return A, b


def _nodes(kind, s):
    if kind == "GAUSS_LEGENDRE":          # roots of the Legendre polynomial on [0, 1]
        return (np.polynomial.legendre.leggauss(s)[0] + 1) / 2
    # Radau IIA: the roots of P_s - P_{s-1} on [-1, 1] (its right end included), on [0, 1]
    coef = np.zeros(s + 1)
    coef[s], coef[s - 1] = 1.0, -1.0
    return (np.sort(np.polynomial.legendre.legroots(coef)) + 1) / 2


@pytest.mark.parametrize("name", sorted(export.ACADOS))
def test_each_acados_setting_is_the_same_tableau_as_the_method(name):
    kind, stages, collocation = export.ACADOS[name]
    t = TABLEAUS[name]
    if kind == "ERK":
        A, b = ACADOS_ERK[stages]
    else:
        A, b = _collocation(_nodes(collocation, stages))
    np.testing.assert_allclose(t.a, A, atol=1e-14)
    np.testing.assert_allclose(t.b, b, atol=1e-14)


def test_a_choice_acados_lacks_goes_to_the_cheapest_qualifying_method_it_has():
    t = {"method": "heun", "h": 0.01, "runners_up": [
        {"method": "ab2", "h": 0.005, "qualifies": True},
        {"method": "rk4", "qualifies": False, "reason": "too inaccurate"},
        {"method": "midpoint", "h": 0.0125, "qualifies": True},
        {"method": "rk3", "h": 0.016, "qualifies": True}]}
    a = export.acados(t, 0.1)
    assert a["method"] == "midpoint"
    assert (a["integrator_type"], a["sim_method_num_stages"]) == ("ERK", 2)
    assert a["sim_method_num_steps"] == 8 and "rank 3" in a["why"]
    with pytest.raises(NoAnswer):
        export.acados({"method": "heun", "h": 0.01, "runners_up": t["runners_up"][:2]}, 0.1)


def test_an_implicit_choice_takes_the_sweep_s_newton_solve_to_acados(tiny_sweep):
    """acados' IRK runs 3 Newton iterations and no stopping test by default; the sweep solved
    each step to its [newton] tolerance. The export carries the sweep's: its atol as acados'
    residual tolerance, its full-Newton limit (acados' Newton takes a fresh Jacobian each
    iteration), and the simplified limit where the sweep had no full-Newton retry."""
    t = {"method": "radau_iia5", "h": 0.01, "runners_up": []}
    given = {"rtol": 1e-6, "atol": 1e-8, "res_tol": 1.0, "max_iter": 7, "max_iter_full": 25}
    a = export.acados(t, 0.1, given)
    assert (a["sim_method_newton_iter"], a["sim_method_newton_tol"]) == (25, 1e-8)
    assert export.acados(t, 0.1, {**given, "max_iter_full": 0})["sim_method_newton_iter"] == 7
    text = export.acados_text(a)
    assert "ocp.solver_options.sim_method_newton_iter = 25\n" in text
    assert "ocp.solver_options.sim_method_newton_tol = 1e-08\n" in text
    # The tiny sweep records the default options; an explicit method has no Newton solve.
    recorded = export.sweep_newton(tiny_sweep[1])
    assert recorded == {"rtol": 1e-10, "atol": 1e-10, "res_tol": 1.0, "max_iter": 10,
                        "max_iter_full": 40}
    assert export.acados(t, 0.1, None)["sim_method_newton_iter"] == 40
    explicit = export.acados({"method": "rk4", "h": 0.01, "runners_up": []}, 0.1, recorded)
    assert not any(k.startswith("sim_method_newton") for k in explicit)


def test_an_export_of_another_method_than_the_tuned_one_says_so_on_stderr(tuned, tmp_path,
                                                                        capsys):
    """heun tuned (acados has no Heun), euler a qualifying runner-up: acados gets euler, and
    the terminal is told in one line, not only the comment atop stdout (which a user
    redirects into a file)."""
    import tomli_w
    _, t, _ = tuned
    t = json.loads(json.dumps(t))
    assert (t["method"], t["runners_up"][0]["method"]) == ("euler", "heun")
    t["method"], t["runners_up"][0]["method"] = "heun", "euler"
    t["h"], t["runners_up"][0]["h"] = t["runners_up"][0]["h"], t["h"]
    path = tmp_path / "heun.toml"
    path.write_text(tomli_w.dumps(t))
    assert stepzoo(["export", str(path), "--to", "acados", "--interval", "0.1"]) == 0
    captured = capsys.readouterr()
    said = f"heun, the tuned choice, has no equivalent in acados; euler at h = {t['h']:g} s " \
        "is the cheapest qualifying method that acados has (rank 2 of the tuning)"
    assert captured.err == f"stepzoo export: {said}\n"
    assert said in captured.out and 'integrator_type = "ERK"' in captured.out
    # The tuned choice itself: nothing on stderr.
    assert stepzoo(["export", str(tuned[0]), "--to", "acados", "--interval", "0.1"]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.skipif(importlib.util.find_spec("diffrax") is None,
                    reason="diffrax is not installed (pip install stepzoo[bench])")
@pytest.mark.parametrize("method", ["choice", "rk4"])
def test_diffrax_snippet_runs_and_equals_stepzoos_fixed_step(tuned, method):
    """The tuned choice (a solver of diffrax's own) and rk4 (written from stepzoo's tableau)."""
    _, t, sweep = tuned
    if method != "choice":
        t = dict(t, method=method, h=0.05)
    code = export.diffrax_snippet(t, sweep, 0.3)
    scope = {}
    with contextlib.redirect_stdout(io.StringIO()) as printed:
        exec(compile(code, "diffrax_snippet.py", "exec"), scope)
    assert "X" in printed.getvalue()
    d = export.diffrax_settings(t, 0.3)
    assert d["n_steps"] * d["dt0"] == pytest.approx(0.3) and d["dt0"] <= t["h"]
    spec = scope["spec"]
    point = json.loads((sweep / "manifest.json").read_text())["trajectory_point"]
    x0, u, p = spec.arrays([tuple(point.values())])
    ours = integrate(t["method"], spec.rhs, x0[0], u[0], {k: v[0] for k, v in p.items()},
                     d["dt0"], d["n_steps"])
    np.testing.assert_allclose(scope["x_end"], np.asarray(ours.x[-1]), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", ['C:\\New', 'quote"""s', "it's"])
def test_the_diffrax_snippet_of_a_sweep_folder_with_backslashes_or_quotes_is_python(
        tuned, tmp_path, name):
    """The folder's name holds what a string literal escapes: the snippet still compiles,
    and names the folder exactly."""
    _, t, sweep = tuned
    odd = tmp_path / name
    odd.mkdir()
    (odd / "manifest.json").write_text((sweep / "manifest.json").read_text())
    code = export.diffrax_snippet(t, odd, 0.3)
    tree = compile(code, "diffrax_snippet.py", "exec", flags=ast.PyCF_ONLY_AST)
    named = [n.value.value for n in tree.body if isinstance(n, ast.Assign)
             and getattr(n.targets[0], "id", None) == "SWEEP"]
    assert named == [str(odd)]


def test_step_schedule_is_the_largest_qualifying_step_per_envelope_value(tuned, exported):
    _, t, sweep = tuned
    data, folder = exported
    csv = pd.read_csv(folder / "schedule.csv")
    assert json.loads((folder / "export.json").read_text()) == data
    runs = pd.read_parquet(sweep / "runs.parquet")
    limits = pd.read_parquet(sweep / "limits.parquet")
    rows = runs[runs["method"] == t["method"]].merge(
        limits[["method", "point", "h_meas"]], on=["method", "point"])
    rows["ok"] = (rows["stable"] & (rows["h"] <= (1 - t["margin"]) * rows["h_meas"])
                  & (rows["err_pos"] <= POS_TOL))
    for var in ("vx", "delta"):
        values = sorted(runs[var].unique())
        assert [r["value"] for r in data["schedule"][var]] == values
        for r in data["schedule"][var]:
            ok = rows[rows[var] == r["value"]].groupby("h")["ok"].all()
            assert r["h_safe_s"] == ok[ok].index.max()
            line = csv[(csv["variable"] == var) & np.isclose(csv["value"], r["value"])]
            assert line["h_safe_s"].item() == r["h_safe_s"]
    assert min(r["h_safe_s"] for r in data["schedule"]["vx"]) >= t["h"]
    a = data["acados"]
    assert a["interval_s"] == 0.095 and a["integrator_type"] == "ERK"
    assert data["diffrax"]["method"] == t["method"]


@pytest.mark.parametrize("args,words", [
    (["--to", "json"], "not found"),
    (["--to", "acados"], "needs --interval"),
    (["--to", "acados", "--interval", "0"], "--interval must be"),
    (["--to", "acados", "--interval", "-1"], "--interval must be"),
    (["--to", "json", "--interval", "nan"], "--interval must be"),
])
def test_bad_input_is_one_line_and_exit_2(tuned, tmp_path, capsys, args, words):
    path, _, _ = tuned
    target = str(tmp_path / "missing.toml") if words == "not found" else str(path)
    assert stepzoo(["export", target, *args]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1 and words in captured.err


@pytest.mark.parametrize("args", [["--to", "casadi"], ["--to", "json", "--interval", "abc"]])
def test_unknown_target_or_a_word_for_the_interval_is_one_line_and_exit_2(tuned, capsys,
                                                                         args):
    path, _, _ = tuned
    with pytest.raises(SystemExit) as exit_:
        stepzoo(["export", str(path), *args])
    assert exit_.value.code == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_a_file_that_is_no_tuned_config_is_one_line_and_exit_2(tiny_sweep, capsys):
    config, _ = tiny_sweep
    assert stepzoo(["export", str(config), "--to", "json"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a tuned config" in err


def test_a_tuned_config_without_its_sweep_needs_sweep_and_says_so(tuned, tmp_path, capsys):
    import tomli_w
    _, t, sweep = tuned
    old = tmp_path / "old.toml"
    old.write_text(tomli_w.dumps({k: v for k, v in t.items() if k != "sweep"}))
    assert stepzoo(["export", str(old), "--to", "json"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--sweep DIR" in err
    assert stepzoo(["export", str(old), "--to", "json", "--sweep", str(sweep)]) == 0


def _method_gone(t):
    t["method"] = "nosuch"


def _runner_gone(t):
    t["runners_up"][0]["method"] = "nosuch"


def _runner_stepless(t):
    t["runners_up"][0].pop("h")


@pytest.mark.parametrize("change, to, words", [
    (_method_gone, "json", "names method 'nosuch', which is not in the zoo"),
    (_runner_gone, "acados", "names method 'nosuch', which is not in the zoo"),
    (_runner_stepless, "json", "runner-up heun qualifies but has no h"),
    (lambda t: t.update(horizon_s=float("nan")), "diffrax", "records no sweep horizon "
     "(horizon_s absent or NaN, as tune writes for a sweep without one); give --interval S"),
    (lambda t: t.pop("margin"), "json", "lacks margin, which the step schedule needs"),
    (lambda t: t.pop("pos_tol_m"), "diffrax", "lacks pos_tol_m or tol"),
    (lambda t: t.pop("sweep_config_sha256"), "json", "lacks sweep_config_sha256"),
    (lambda t: t.update(method="rk4"), "acados", "names rk4 at h = 0.01 s, which the sweep"),
    (lambda t: t.update(h=0.03), "json", "names euler at h = 0.03 s, which the sweep"),
], ids=["method", "runner-up", "runner-up's h", "horizon", "margin", "tolerance", "sha256",
        "method not swept", "step not swept"])
def test_a_tuned_config_export_cannot_use_is_one_line(tuned, tmp_path, capsys, change, to,
                                                      words):
    """The third battery's tracebacks (KeyError, ValueError): a tuned file whose method is not
    in the zoo, whose runner-up is unknown or has no h, with horizon_s = nan or a removed
    key. And NaN horizon (tune's record of a sweep without one) is no error for --to json.
    A (method, h) the sweep never ran (rk4 was exported to acados, exit 0, with an empty
    step schedule) is refused too: nothing measured it."""
    import tomli_w
    _, t, _ = tuned
    t = json.loads(json.dumps(t))
    change(t)
    path = tmp_path / "changed.toml"
    path.write_text(tomli_w.dumps(t))
    interval = ["--interval", "0.1"] if to == "acados" else []
    assert stepzoo(["export", str(path), "--to", to, *interval]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1 and words in captured.err
    if "horizon" in words:
        with contextlib.redirect_stdout(io.StringIO()) as out:
            assert stepzoo(["export", str(path), "--to", "json"]) == 0
        assert "give --interval S" in json.loads(out.getvalue())["diffrax"]["error"]


def test_a_sweep_of_an_older_version_is_one_line(tuned, tmp_path, capsys):
    """A --sweep folder whose manifest predates models as data (no model_spec, no
    trajectory_point): the schedule had no variables and ended in a KeyError."""
    import shutil
    path, _, sweep = tuned
    old = tmp_path / "old"
    shutil.copytree(sweep, old)
    manifest = json.loads((old / "manifest.json").read_text())
    for key in ("model_spec", "trajectory_point"):
        manifest.pop(key)
    (old / "manifest.json").write_text(json.dumps(manifest))
    for to in ("json", "diffrax"):
        assert stepzoo(["export", str(path), "--to", to, "--sweep", str(old)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "lacks model_spec, trajectory_point: the sweep was " \
            "written by an older `stepzoo sweep`" in err
