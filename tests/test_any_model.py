"""A user's own model, in a folder of its own and named in a TOML, goes through the sweep,
tune and report like a built-in: for a linear model the frozen-Jacobian prediction is exact
(h_pred from eigenvalues computed independently by NumPy, h_meas within 3% of it for every
explicit method); bad model configs are one line and exit status 2."""
import dataclasses
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stepzoo.cli import main as stepzoo
from stepzoo.bench.sweep.engine import compute_chunk
from stepzoo.bench.sweep.config import load
from stepzoo.integrators import METHODS, method
from stepzoo.integrators.stability import max_stable_step

CHAIN = Path(__file__).resolve().parent / "user_model" / "chain.toml"
EXPLICIT = [n for n, m in METHODS.items() if not m.implicit]


def chain_matrix(k, c, m):
    """d/dt [x1, x2, v1, v2] = A [x1, x2, v1, v2] + b, written out by hand."""
    return np.array([[0, 0, 1, 0], [0, 0, 0, 1],
                     [-2 * k / m, k / m, -2 * c / m, c / m],
                     [k / m, -k / m, c / m, -c / m]])


@pytest.fixture(scope="module")
def chain():
    """The user's chain at its softest and stiffest spring, no force."""
    cfg = load(CHAIN)
    spec = dataclasses.replace(cfg.spec, envelope=(("k", (100.0, 1000.0)), ("F", (0.0,))))
    return cfg.changed(spec=spec, methods=tuple(EXPLICIT), steps={"h": (0.002, 0.008, 0.032)},
                       timing={"rounds": 1})


@pytest.fixture(scope="module")
def chain_limits(chain):
    cache = {}
    return pd.concat([compute_chunk(chain, f"{name}-b000", cache)["limits"]
                      for name in chain.methods], ignore_index=True)


@pytest.mark.parametrize("name", EXPLICIT)
def test_linear_model_prediction_is_the_numpy_eigenvalues_limit(chain, chain_limits, name):
    p = dict(chain.spec.params)
    rows = chain_limits[chain_limits["method"] == name]
    for _, row in rows.iterrows():
        lam = np.linalg.eigvals(chain_matrix(row["k"], p["c"], p["m"]))
        assert row["h_pred"] == pytest.approx(max_stable_step(method(name), lam), rel=1e-9)


@pytest.mark.parametrize("name", EXPLICIT)
def test_linear_model_measured_limit_within_3pct_of_predicted(chain_limits, name):
    rows = chain_limits[chain_limits["method"] == name]
    assert len(rows) == 2 and (rows["limit_cause"] == "unstable").all()
    assert np.all(np.abs(rows["ratio"] - 1) <= 0.03), rows[["k", "ratio"]]


def test_limit_binds_at_a_named_time_and_eigenvalue(chain_limits):
    row = chain_limits.iloc[0]
    assert row["t_bind"] >= 0 and math.isfinite(row["lam_re_bind"]) and row["lam_re_bind"] < 0
    assert {"bind_x1", "bind_v2"} <= set(chain_limits.columns)


@pytest.fixture(scope="module")
def user_run(tmp_path_factory):
    """`stepzoo sweep`, `tune --tol` and `report` on the user's model, as
    docs/your-model.md shows."""
    folder = tmp_path_factory.mktemp("user")
    text = CHAIN.read_text()
    head, _, tail = text.partition("[model]")
    cut = head.split("methods = ")[0] + 'methods = ["rk4", "trapezoidal"]\n\n[model]' + tail
    cut = cut.replace("num = 8", "num = 4").replace("steps = 2000", "steps = 500")
    config = folder / "config" / "chain.toml"
    config.parent.mkdir()
    config.write_text(cut.replace('path = "."', f'path = "{CHAIN.parent}"'))
    out = folder / "sweep"
    assert stepzoo(["sweep", str(config), "--out", str(out), "--no-progress"]) == 0
    assert stepzoo(["tune", str(out), "--tol", "0.01", "--out", str(folder / "tuned.toml")]) == 0
    return folder


def test_user_sweep_names_its_columns_after_the_model(user_run):
    runs = pd.read_parquet(user_run / "sweep" / "runs.parquet")
    limits = pd.read_parquet(user_run / "sweep" / "limits.parquet")
    traj = pd.read_parquet(user_run / "sweep" / "trajectories.parquet")
    assert {"k", "F", "err_x1", "err_v2", "err", "converged"} <= set(runs.columns)
    assert "err_pos" not in runs and {"k", "F", "h_pred", "h_meas"} <= set(limits.columns)
    assert {"x1", "x2", "v1", "v2"} <= set(traj.columns)
    manifest = json.loads((user_run / "sweep" / "manifest.json").read_text())
    assert manifest["model"] == "springs:chain"
    assert manifest["model_spec"]["variables"] == ["k", "F"]


def test_user_tune_meets_the_error_norm_tolerance_everywhere(user_run):
    tuned = tomllib.loads((user_run / "tuned.toml").read_text())
    runs = pd.read_parquet(user_run / "sweep" / "runs.parquet")
    mine = runs[(runs["method"] == tuned["method"]) & np.isclose(runs["h"], tuned["h"])]
    assert tuned["tol"] == 0.01 and mine["stable"].all() and (mine["err"] <= 0.01).all()
    assert set(tuned["envelope"]) == {"k", "F", "points"}
    assert stepzoo(["tune", str(user_run / "sweep"), "--pos-tol", "0.01", "--out",
                    str(user_run / "pos.toml")]) == 2


def test_user_report_names_axes_after_the_envelope(user_run):
    out = user_run / "report"
    assert stepzoo(["report", str(user_run / "sweep"), "--tuned", str(user_run / "tuned.toml"),
                    "--out", str(out)]) == 0
    summary = (out / "summary.md").read_text()
    assert "against k" in summary and "x1 against time" in summary


BAD = [
    ('rhs = "springs:chain"', 'rhs = "nowhere:chain"', "names module 'nowhere'"),
    ('rhs = "springs:chain"', 'rhs = "springs:chains"', "has no function 'chains'"),
    ('rhs = "springs:chain"', 'rhs = "springs:MASSES"', "springs.MASSES is 'int', not a"),
    ('states = ["x1", "x2", "v1", "v2"]', 'states = ["x1", "x2", "v1"]',
     "fails on its initial state of 3 states"),
    ('F = { values = [0.0, 1.0] }', 'G = { values = [0.0, 1.0] }', "envelope.G is not a"),
    ('states = ["x1", "x2"]\nscales', 'states = ["x9"]\nscales', "error.states must be"),
    ('[initial]\nx1 = 0.1', '[initial]\ny1 = 0.1', "initial.y1 is not a state"),
    ('name = "chain"', 'name = "chain"\ntyre = "pacejka"', "tyre is an option"),
]


@pytest.mark.parametrize("old,new,message", BAD)
def test_a_bad_model_config_is_one_line_and_exit_2(tmp_path, capsys, old, new, message):
    text = CHAIN.read_text()
    assert old in text
    config = tmp_path / "chain.toml"
    config.write_text(text.replace(old, new).replace('path = "."', f'path = "{CHAIN.parent}"'))
    assert stepzoo(["sweep", str(config), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "out").exists()


def test_verdict_names_the_region_past_the_predicted_limit(tmp_path, capsys):
    """rk4 between its limits at the stiff and the soft spring: unstable exactly where the
    spring is stiff, stable elsewhere."""
    config = tmp_path / "chain.toml"
    config.write_text(CHAIN.read_text().replace('path = "."', f'path = "{CHAIN.parent}"')
                      .replace("steps = 2000", "steps = 500"))
    p = dict(load(config).spec.params)
    stiff, soft = (max_stable_step(method("rk4"), np.linalg.eigvals(chain_matrix(k, p["c"],
                                                                              p["m"])))
                   for k in (1000.0, 100.0))
    h = 0.5 * (stiff + min(soft, 1.2 * stiff))
    assert stepzoo(["verdict", str(config), "--method", "rk4", "--h", repr(float(h)), "--tol", "10",
                    "--format", "json"]) == 0
    v = json.loads(capsys.readouterr().out)["verdicts"][0]
    assert len(v["points"]) == v["n_points"] == 6 and v["stable"] == 4
    # Past its limit the run grows, but stays finite over the horizon: its error is finite.
    assert v["unstable_where"].startswith("k = 1000") and v["worst_cause"] == "unstable"
    assert v["worst_error"] is not None and v["worst_error"] > 10
    assert v["worst_at"]["k"] == 1000.0


def user_config(folder: Path, module: str, code: str, params: str = "k = 600.0\n",
                envelope: str = "k = [400.0, 600.0]\n") -> Path:
    """A one-method sweep config of the model `module:f` whose source is `code`, in `folder`."""
    (folder / f"{module}.py").write_text(code)
    config = folder / f"{module}.toml"
    config.write_text(f'name = "m"\nhorizon = 0.5\nmethods = ["rk4"]\n[model]\n'
                      f'rhs = "{module}:f"\nstates = ["x", "v"]\npath = "{folder}"\n'
                      f"[params]\n{params}[initial]\nx = 1.0\n[envelope]\n{envelope}"
                      "[steps]\nh = [0.01, 0.02]\n[stability]\nrule = \"blowup\"\nsteps = 100\n")
    return config


OSCILLATOR = "import jax.numpy as jnp\n\n\ndef f(t, x, u, p):\n    return {}\n"


@pytest.mark.parametrize("module, code, params, message", [
    ("complex_model", OSCILLATOR.format('jnp.stack([x[1], -p["k"] * x[0]]) * (1 + 1j)'), None,
     "returns complex values (complex128)"),
    ("clash_model", OSCILLATOR.format('jnp.stack([x[1], -p["k"] * x[0]])'),
     "k = 600.0\nv = 2.0\n", "params.v has the name of a state"),
    ("exiting_model", "import sys\nsys.exit(0)\n", None,
     "the model module 'exiting_model' exited during import (SystemExit 0)"),
    ("json", "def f(t, x, u, p):\n    return x\n", None,
     "is shadowed by Python's standard module 'json'"),
])
def test_a_model_that_cannot_be_swept_as_written_is_one_line_and_exit_2(
        tmp_path, capsys, module, code, params, message):
    config = user_config(tmp_path, module, code, *([params] if params else []))
    assert stepzoo(["sweep", str(config), "--out", str(tmp_path / "out")]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.count("\n") == 1, captured.err
    assert message in captured.err and "Traceback" not in captured.err
    assert not (tmp_path / "out").exists()


def test_prints_of_a_model_leave_json_alone_and_an_unread_parameter_is_a_warning(tmp_path,
                                                                                 capsys):
    """A model that prints and never reads k, its envelope over k: stability's JSON on
    stdout parses, the prints and one warning line naming k are on stderr."""
    code = ('import jax.numpy as jnp\n\n\ndef f(t, x, u, p):\n    print("tracing f")\n'
            '    return jnp.stack([x[1], -100.0 * x[0] + 0.0 * p["c"]])\n')
    config = user_config(tmp_path, "printing_model", code, "k = 600.0\nc = 1.0\n",
                         "k = [400.0, 600.0]\nc = [1.0, 2.0]\n")
    assert stepzoo(["stability", str(config), "--format", "json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["model"] == "printing_model:f"
    warnings = [line for line in captured.err.splitlines() if "warning" in line]
    assert len(warnings) == 1 and "params.k, which model printing_model:f never reads" \
        in warnings[0], captured.err
    assert "tracing f" in captured.err


def test_threads_tracing_a_printing_model_leave_stdout_where_it_was(capsys):
    """Two threads trace the user's model side by side (a sweep compiles its methods so) and
    leave in the other order than they came: the command's stdout is stdout again after
    both, not stderr (stdout pointing at stderr lost a sweep's summary from stdout)."""
    import sys
    import threading
    from stepzoo.output import prints_to_stderr
    stdout = sys.stdout
    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()

    def first():
        with prints_to_stderr():
            print("first traces")
            a_in.set()
            b_in.wait(5)
        a_out.set()

    def second():
        a_in.wait(5)
        with prints_to_stderr():
            b_in.set()
            a_out.wait(5)
            print("second traces")

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(10)
    assert a_out.is_set() and sys.stdout is stdout
    print("the command's output")
    captured = capsys.readouterr()
    assert captured.out == "the command's output\n"
    assert captured.err == "first traces\nsecond traces\n"


def test_a_batch_parameter_of_the_wrong_length_is_named():
    from stepzoo.integrators import integrate_batch
    f = lambda t, x, u, p: -p["k"] * x
    with pytest.raises(ValueError, match=r"p\['k'\] has shape \(2,\), not one value per "
                                         r"trajectory \(3, \.\.\.\)"):
        integrate_batch("rk4", f, np.ones((3, 1)), p={"k": np.array([1.0, 2.0])}, h=0.01,
                        n_steps=10)
    x = integrate_batch("rk4", f, np.ones((3, 1)), p={"k": np.array([1.0, 2.0, 3.0])}, h=0.01,
                        n_steps=10).x
    assert x.shape == (3, 11, 1)


WHEEL = Path(__file__).resolve().parent / "user_model" / "quarter_wheel.toml"


def _wheel_config(tmp_path, old: str = "", new: str = "") -> Path:
    """The quarter wheel's config in tmp_path (its model folder made absolute), edited."""
    text = WHEEL.read_text().replace('rhs = "quarter_wheel:wheel"',
                                     f'rhs = "quarter_wheel:wheel"\npath = "{WHEEL.parent}"')
    config = tmp_path / "wheel.toml"
    config.write_text(text.replace(old, new))
    return config


@pytest.mark.parametrize("omega", ['"vx / wheel.r_w"', '"quarter_wheel:free_rolling"'])
def test_an_initial_state_given_by_expression_or_hook_is_evaluated_at_every_point(
        tmp_path, omega):
    """omega rolls without slip at every operating point, vx / r_w, with vx and the nested
    parameter wheel.r_w both varied by the envelope: as an expression and as a hook."""
    config = _wheel_config(tmp_path, 'omega = "vx / wheel.r_w"', f"omega = {omega}")
    config.write_text(config.read_text().replace(
        "T = [200.0]", 'T = [200.0]\n"wheel.r_w" = [0.25, 0.3, 0.35]'))
    spec = load(config).spec
    x0, _, p = spec.arrays(spec.points)
    vx, r = np.array([pt[0] for pt in spec.points]), np.array([pt[2] for pt in spec.points])
    assert len(spec.points) == 6 and set(r) == {0.25, 0.3, 0.35}
    np.testing.assert_array_equal(p["wheel.r_w"], r)
    np.testing.assert_allclose(x0[:, 1], vx / r, rtol=1e-15)
    np.testing.assert_array_equal(x0[:, 0], vx)


def test_nested_params_are_dotted_names_and_the_model_reads_them_nested(tmp_path):
    """[params.tyre] etc. become tyre.B etc. in the spec; the model reads p["tyre"]["B"]:
    its f equals the Pacejka force written here in NumPy, at a slipping state."""
    spec = load(_wheel_config(tmp_path)).spec
    p = dict(spec.params)
    assert {"body.m", "wheel.r_w", "wheel.J", "tyre.B", "tyre.C", "tyre.D", "tyre.Fz"} == set(p)
    x, u = np.array([10.0, 35.0]), np.array([200.0])
    slip = (35.0 * p["wheel.r_w"] - 10.0) / 10.0
    fx = p["tyre.D"] * p["tyre.Fz"] * np.sin(p["tyre.C"] * np.arctan(p["tyre.B"] * slip))
    want = [fx / p["body.m"], (200.0 - fx * p["wheel.r_w"]) / p["wheel.J"]]
    np.testing.assert_allclose(np.asarray(spec.rhs(0.0, x, u, p)), want, rtol=1e-12)


@pytest.mark.parametrize("new,message", [
    ('omega = "__import__(\'os\').getcwd()"', "may hold numbers, names"),
    ('omega = "vx.real"', "names vx.real, not a state"),
    ('omega = "vx / wheel.r"', "names wheel.r, not a state"),
    ('omega = "vx / (wheel.r_w - 0.3)"', "is not finite at vx = 10, T = 200"),
    ('omega = "quarter_wheel:nothing"', "quarter_wheel has no function 'nothing'"),
    ('omega = "omega + 1"', "reads omega, computed at or after it"),
])
def test_a_bad_initial_expression_is_one_line_and_exit_2(tmp_path, capsys, new, message):
    config = _wheel_config(tmp_path, 'omega = "vx / wheel.r_w"', new)
    assert stepzoo(["sweep", str(config), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "out").exists()
