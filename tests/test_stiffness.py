"""Stiffness named (bench/model/stiffness.py): on the saturating quarter wheel (a user model with
nested parameters), tune says the model is stiff, names the wheel-spin mode by its eigenvalue
(closed form) and the state that takes the largest part in it (participation factors, closed
form), and ranks implicit and Rosenbrock methods with the explicit ones by measured time; on
the tiny bicycle sweep it says the model is not stiff."""
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stepzoo.bench.model.stiffness import STIFF_RATIO, participation
from stepzoo.bench.sweep.engine import run_sweep
from stepzoo.bench.sweep.config import load
from stepzoo.cli import main as stepzoo
from stepzoo.integrators import METHODS

WHEEL = Path(__file__).resolve().parent / "user_model" / "quarter_wheel.toml"
# B C D Fz [N]: the tyre's slip stiffness; the mode relaxes it through the wheel (r^2 / J)
# and the body (1 / m), over the speed.
SLIP = 10.0 * 1.9 * 1.0 * 4000.0
WHEEL_PART, BODY_PART = SLIP * 0.3 ** 2 / 1.2, SLIP / 400.0


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """(sweep folder, tuned TOML at --tol 0.1) of the quarter wheel."""
    base = tmp_path_factory.mktemp("wheel")
    config = base / "wheel.toml"
    config.write_text(WHEEL.read_text().replace(
        'rhs = "quarter_wheel:wheel"', f'rhs = "quarter_wheel:wheel"\npath = "{WHEEL.parent}"'))
    run_sweep(load(config), base / "sweep", progress=False)
    assert stepzoo(["tune", str(base / "sweep"), "--tol", "0.1", "--out",
                    str(base / "t.toml")]) == 0
    return base / "sweep", tomllib.loads((base / "t.toml").read_text())


def test_participation_of_a_two_state_mode_is_its_closed_form():
    """J = [[-a, a], [b, -b]] (a body and a wheel tied by one slip): the mode -(a + b) has
    participation a / (a + b) in the first state and b / (a + b) in the second."""
    a, b = 19.0, 570.0
    share = participation(np.array([[-a, a], [b, -b]]), -(a + b))
    np.testing.assert_allclose(share, [a / (a + b), b / (a + b)], rtol=1e-12)


def test_the_quarter_wheel_is_named_stiff_with_its_wheel_spin_mode(wheel):
    folder, tuned = wheel
    s = tuned["stiffness"]
    assert tuned["stiff"] and s["stiff"] and s["ratio"] >= STIFF_RATIO
    mode = s["mode"]
    # Slowest speed, t = 0 (free rolling, linear slip): lambda = -(wheel + body) / vx.
    assert mode["point"]["vx"] == 10.0 and mode["t_s"] == 0.0
    assert mode["lambda_re_per_s"] == pytest.approx(-(WHEEL_PART + BODY_PART) / 10.0, rel=1e-9)
    assert mode["state"] == "omega"
    assert mode["participation"] == pytest.approx(WHEEL_PART / (WHEEL_PART + BODY_PART),
                                                  rel=1e-9)
    # The explicit bound is the best explicit method's smallest limit over the points.
    limits = pd.read_parquet(folder / "limits.parquet")
    explicit = limits[[not METHODS[m].implicit for m in limits["method"]]]
    best = np.fmin(explicit["h_pred"], explicit["h_meas"]).groupby(explicit["method"]).min()
    assert s["h_explicit_max_s"] == pytest.approx(best.max(), rel=1e-12)
    assert "the model is stiff" in tuned["why"] and "omega" in tuned["why"]


def test_implicit_methods_rank_with_explicit_ones_by_time(wheel):
    """Every qualifying method, implicit or not, is calibrated and ranked by measured time."""
    _, tuned = wheel
    rows = [{"method": tuned["method"], "t": tuned["cost_time_per_s"]}] + [
        {"method": r["method"], "t": r["cost_time_per_s"]} for r in tuned["runners_up"]
        if r["qualifies"]]
    assert {r["method"] for r in rows} >= {"ros2", "rk4"}
    assert set(tuned["calibration"]["methods"]) == {r["method"] for r in rows}
    later = [r["t"] for r in rows[1:]]
    assert later == sorted(later)


def test_the_tiny_bicycle_is_not_stiff(tiny_sweep, tmp_path):
    _, folder = tiny_sweep
    assert stepzoo(["tune", str(folder), "--tol", "0.05", "--out", str(tmp_path / "t.toml")]) == 0
    tuned = tomllib.loads((tmp_path / "t.toml").read_text())
    assert not tuned["stiff"] and tuned["stiffness"]["ratio"] < STIFF_RATIO


def test_the_sweep_summary_names_the_binding_mode(wheel, capsys):
    """`stepzoo sweep` prints the finding at the report's default tolerance (the error norm's
    1e-3: there rk4 at 1 ms is what accuracy needs, so not stiff) with the mode, and its JSON
    has it as `stiffness`."""
    import json

    from stepzoo.workflows.sweep import show
    folder, _ = wheel
    manifest = json.loads((folder / "manifest.json").read_text())
    show(manifest, folder)
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("at err"))
    assert line.startswith("at err <= 0.001 (the report's default): not stiff")
    assert "lambda = -589 1/s (mostly omega" in line
    show(manifest, folder, "json")
    got = json.loads(capsys.readouterr().out)["stiffness"]
    assert got["mode"]["state"] == "omega" and got["tolerance"] == {"err": 0.001}


def test_tune_json_of_an_a_stable_choice_has_null_limits(wheel, tmp_path, capsys):
    """ros2 (the fewest evaluations: 50 per simulated second at 0.1 s) is A-stable, with no
    finite limit: JSON (which has no inf) says null, as the TOML says inf."""
    import json
    folder, _ = wheel
    out = tmp_path / "t.toml"
    assert stepzoo(["tune", str(folder), "--tol", "0.1", "--cost", "evals", "--out", str(out),
                    "--format", "json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["method"] == "ros2" and got["h_pred_min_s"] is None and got["stiff"]
    assert tomllib.loads(out.read_text())["h_pred_min_s"] == float("inf")


def _wheel_numpy(x, T):
    """The quarter wheel's f, written again in NumPy (tests/user_model/quarter_wheel.py)."""
    vx, omega = x
    slip = (omega * 0.3 - vx) / max(abs(vx), 0.1)
    fx = 1.0 * 4000.0 * np.sin(1.9 * np.arctan(10.0 * slip))
    return np.array([fx / 400.0, (T - fx * 0.3) / 1.2])


def _backward_euler_error(vx0, T, h, horizon=0.5):
    """The largest |vx - vx_ref| / 0.01 (the config's error norm) of backward Euler in plain
    NumPy (Newton with a finite-difference Jacobian) at step h [s], against SciPy's Radau at
    rtol 1e-10."""
    from scipy.integrate import solve_ivp
    x0 = np.array([vx0, vx0 / 0.3])
    n = round(horizon / h)
    ts = h * np.arange(n + 1)
    ref = solve_ivp(lambda t, x: _wheel_numpy(x, T), (0, horizon), x0, method="Radau",
                    rtol=1e-10, atol=1e-10, t_eval=ts).y.T
    x, worst = x0.copy(), 0.0
    for k in range(n):
        y = x.copy()
        for _ in range(50):
            g = y - x - h * _wheel_numpy(y, T)
            J = np.eye(2) - h * np.column_stack([
                (_wheel_numpy(y + e, T) - _wheel_numpy(y - e, T)) / (2 * e.sum())
                for e in np.eye(2) * 1e-6])
            dy = np.linalg.solve(J, -g)
            y += dy
            if np.abs(dy).max() < 1e-12:
                break
        x = y
        worst = max(worst, abs(x[0] - ref[k + 1, 0]) / 0.01)
    return worst


def test_the_quarter_wheel_is_stiff_at_its_point_against_independent_numbers(wheel):
    """At the point the answer names, the explicit bound is at most the largest swept explicit
    method's exact stability polynomial limit on the closed-form slip mode, and the accurate
    step is at least the largest grid step at which backward Euler (L-stable), run in plain NumPy
    against SciPy's Radau, meets the tolerance there: that pair alone is STIFF_RATIO apart."""
    from stepzoo.integrators import method
    from stepzoo.integrators.stability import max_stable_step
    _, tuned = wheel
    s = tuned["stiffness"]
    vx = s["mode"]["point"]["vx"]
    lam = -(WHEEL_PART + BODY_PART) / vx
    poly = max(max_stable_step(method(m), [lam]) for m in ("euler", "rk4"))
    assert s["h_explicit_max_s"] <= poly * (1 + 1e-9)
    hs = [0.001, 0.002, 0.005, 0.01, 0.025, 0.05, 0.1]
    oracle = max(h for h in hs if _backward_euler_error(vx, 200.0, h) <= 0.1)
    assert s["h_accurate_max_s"] >= oracle and oracle / poly >= STIFF_RATIO
    assert s["stiff_points"] >= 1 and s["points"] == 2
