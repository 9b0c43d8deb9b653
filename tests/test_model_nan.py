"""A model whose right-hand side is NaN at one of two operating points (sqrt(k - 500) at k = 400
and 600): that point is a result, "model returned NaN at t = 0 s", in the sweep's limits and
printed summary, in verdict and in stability; the other point is swept as ever (its predicted
limit the NumPy eigenvalues' exact one) and the folder completes."""
import json
import math

import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from stepzoo.cli import main as stepzoo
from stepzoo.bench.model.nonfinite import first_times
from stepzoo.integrators import method
from stepzoo.integrators.stability import max_stable_step

MODEL = '''import jax.numpy as jnp


def f(t, x, u, p):
    """A damped oscillator whose stiffness is sqrt(k - 500): NaN for k < 500."""
    return jnp.stack([x[1], -jnp.sqrt(p["k"] - 500.0) * x[0] - 0.5 * x[1]])
'''
CONFIG = '''name = "nan"
horizon = 0.5
methods = ["rk4"]
[model]
rhs = "nanmodel:f"
states = ["x", "v"]
[params]
k = 600.0
[initial]
x = 1.0
[envelope]
k = [400.0, 600.0]
[steps]
h = [0.01, 0.02]
[stability]
rule = "blowup"
steps = 100
'''


def rk4_limit_at(k: float) -> float:
    """rk4's largest stable step on the oscillator's matrix, from NumPy's eigenvalues."""
    a = np.array([[0.0, 1.0], [-math.sqrt(k - 500.0), -0.5]])
    return max_stable_step(method("rk4"), np.linalg.eigvals(a))


@pytest.fixture(scope="module")
def nan_sweep(tmp_path_factory):
    """(config, folder, the sweep's stdout) of the model swept over k = 400, 600."""
    import contextlib
    import io
    folder = tmp_path_factory.mktemp("nan")
    (folder / "nanmodel.py").write_text(MODEL)
    config = folder / "nan.toml"
    config.write_text(CONFIG)
    out = folder / "sweep"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = stepzoo(["sweep", str(config), "--out", str(out), "--no-progress"])
    assert code == 0
    return config, out, printed.getvalue()


def test_the_nan_point_is_a_result_and_the_other_point_is_swept(nan_sweep):
    _, out, printed = nan_sweep
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] and (out / "summary.csv").is_file()
    limits = pd.read_csv(out / "limits.csv").set_index("k")
    nan, fine = limits.loc[400.0], limits.loc[600.0]
    assert nan["limit_cause"] == "model returned NaN at t = 0 s" and nan["model_nan_t"] == 0.0
    assert math.isnan(nan["h_meas"]) and math.isnan(nan["h_pred"])
    assert math.isnan(fine["model_nan_t"]) and fine["limit_cause"] == "unstable"
    assert fine["h_pred"] == pytest.approx(rk4_limit_at(600.0), rel=1e-9)
    assert 0 < fine["h_meas"] < math.inf
    runs = pd.read_parquet(out / "runs.parquet")
    assert set(runs["k"]) == {400.0, 600.0} and not runs[runs["k"] == 400.0]["stable"].any()
    assert ("model returned NaN at 1 of 2 operating points: k = 400 (t = 0 s)" in printed)


def test_verdict_names_the_points_where_the_model_returned_nan(nan_sweep, capsys):
    config, _, _ = nan_sweep
    assert stepzoo(["verdict", str(config), "--method", "rk4", "--h", "0.01",
                    "--format", "json"]) == 0
    v = json.loads(capsys.readouterr().out)["verdicts"][0]
    assert v["model_nan_where"] == "k = 400" and v["unstable_where"] == "nowhere"
    assert v["n_points"] == 2 and v["stable"] == 1
    assert v["h_pred_min"] == pytest.approx(rk4_limit_at(600.0), rel=1e-9)
    # Where the model is NaN at every point, no limit exists: null in JSON, not a traceback.
    only_nan = config.with_name("only_nan.toml")
    only_nan.write_text(CONFIG.replace("k = [400.0, 600.0]", "k = [400.0, 450.0]"))
    assert stepzoo(["verdict", str(only_nan), "--method", "rk4", "--h", "0.01",
                    "--format", "json"]) == 0
    v = json.loads(capsys.readouterr().out)["verdicts"][0]
    assert v["stable"] == 0 and v["h_pred_min"] is None and v["h_meas_min"] is None


def test_stability_says_the_jacobian_is_not_finite_instead_of_no_limit(nan_sweep, capsys):
    config, _, _ = nan_sweep
    assert stepzoo(["stability", str(config)]) == 1
    captured = capsys.readouterr()
    assert "the Jacobian is not finite at this point (model returned NaN at t = 0 s" \
        in captured.out and "rk4" not in captured.out and captured.err == ""
    assert stepzoo(["stability", str(config), "--at", "k=600", "--format", "json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["jacobian_finite"] and out["model_nan_t"] is None
    assert out["methods"]["rk4"]["max_stable_step"] == pytest.approx(rk4_limit_at(600.0),
                                                                    rel=1e-9)


def test_the_first_time_the_model_is_not_finite_is_found_along_a_trajectory():
    """sqrt(0.25 - t) is NaN after t = 0.25: the first sample past it is named; a state that
    is itself NaN (a failed reference) is not the model's doing."""
    f = lambda t, x, u, p: jnp.sqrt(0.25 - t) * x * p["c"]
    ts = np.linspace(0.0, 1.0, 11)
    xs = np.ones((2, 11, 1))
    xs[1, 1:] = np.nan
    jac = np.zeros((2, 11, 1, 1))
    jac[1, 0] = np.inf            # a Jacobian that is not finite counts too
    got = first_times(f, ts, xs, np.zeros((2, 0)), {"c": np.ones(2)}, jac)
    assert got[0] == pytest.approx(0.3) and got[1] == 0.0
    assert np.isnan(first_times(f, ts[:3], xs[:1, :3], np.zeros((1, 0)), {"c": np.ones(1)},
                                np.zeros((1, 3, 1, 1))))[0]
