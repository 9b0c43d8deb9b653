"""What the measured limit means beyond linear models. With saturating tyres the blow-up test
agrees with the frozen-Jacobian prediction when its perturbation stays small (the default),
and not when it reaches the tyres' peak; from a state that is no equilibrium, a step past the
prediction can settle on a spurious steady state of the method, which the test calls stable;
a growing exact solution sets the measured limit through the run's length; the observed
order reads every converged accuracy run, whatever the blow-up test says."""
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from stepzoo.bench.sweep import metrics
from stepzoo.bench.model.frozen_jacobian import predicted_limit
from stepzoo.bench.sweep.block import Block
from stepzoo.bench.sweep.engine import compute_chunk
from stepzoo.bench.sweep.config import validate
from stepzoo.integrators import method
from stepzoo.integrators.stability import max_stable_step

TYRE_LAWS = Path(__file__).resolve().parents[1] / "bench" / "configs" / "tyre_laws.toml"


@pytest.fixture(scope="module")
def pacejka():
    """The BMW 320i with Pacejka tyres at 2 m/s from rest, straight and steered 0.1 rad: rk4
    over a grid that straddles its linearised limit (0.026 s) and a step 4 times past it."""
    raw = tomllib.loads(TYRE_LAWS.read_text())
    raw.pop("problem")
    raw.update(tyre="pacejka", methods=["rk4"], horizon=2.0)
    raw["envelope"] = {"vx": {"values": [2.0]}, "delta": {"values": [0.0, 0.1]},
                       "x0": [0.0] * 5}
    raw["steps"] = {"h": {"values": [0.02, 0.05, 0.1]}}
    raw["timing"] = {"rounds": 1}
    raw["stability"]["steps"] = 1000
    raw["trajectories"] = {"vx": 2.0, "delta": 0.0}
    return validate(raw, str(TYRE_LAWS))


@pytest.fixture(scope="module")
def chunk(pacejka):
    return compute_chunk(pacejka, "rk4-b000")


def test_saturating_tyre_limit_is_the_linearised_one_for_a_small_perturbation(pacejka, chunk):
    """Straight running is an equilibrium: the default perturbation measures h_pred within
    rel_tol. One of 0.1 (a slip of 0.05 rad, a third of the way to the tyre's peak) grows
    until the tyres saturate, which caps its growth below 100: at 1.9 h_pred, where the small
    one grows past 100, the blow-up test calls the step stable (the whole grid then was, and
    with 2000 steps h_meas came out 67 times h_pred)."""
    lim = chunk["limits"].set_index("delta").loc[0.0]
    assert lim["ratio"] == pytest.approx(1.0, abs=2 * pacejka.stability.rel_tol)
    assert lim["limit_cause"] == "unstable"
    h = [[0.05], [0.05]]
    small = Block(pacejka, 0, {}).stable(method("rk4"), h)[0]
    large = Block(pacejka.changed(stability={"perturbation": 0.1}), 0, {}).stable(
        method("rk4"), h)[0]
    assert 0.05 > 1.9 * lim["h_pred"] and not small[0, 0] and large[0, 0]


def test_past_the_limit_a_turn_settles_on_a_spurious_steady_state(pacejka, chunk):
    """Steered from rest, the exact solution settles at (vy, r) = (0.109, 0.078) with
    eigenvalues -107.4 +- 0.56i, so h_pred = 0.026 s. rk4 at 0.1 s starts from a state that
    is no equilibrium and settles on a fixed point of its own map, not of the ODE (vy of the
    other sign); a perturbed run settles there too, so the blow-up test calls 0.1 s stable while
    0.05 s is not: the stable steps are no interval, and h_meas is where the grid first fails."""
    lim = chunk["limits"].set_index("delta").loc[0.1]
    assert lim["h_pred"] == pytest.approx(max_stable_step(method("rk4"), [-107.39 + 0.555j]),
                                          rel=1e-3)
    runs = chunk["runs"][chunk["runs"]["delta"] == 0.1].set_index("h")
    assert list(runs["stable"]) == [True, False, True]
    assert runs.loc[0.1, "err"] > 2.0 * 0.109                 # a wrong answer, yet stable
    work = Block(pacejka, 0, {})                # both lanes: the chunk's compiled program
    pts = work.points
    x = work.run(method("rk4"), pts.x0, pts.u, pts.p, 0.1, pacejka.stability.steps).x
    end = x[1, -1]
    assert np.allclose(x[1, -2, 3:], end[3:], atol=1e-12)     # a fixed point of the map
    f = np.asarray(pacejka.spec.rhs(0.0, end, pts.u[1], {k: v[1] for k, v in pts.p.items()}))
    assert end[3] < -0.2 and np.abs(f[3:]).max() > 1.0         # and not of the ODE


GROWTH = '''
def grow(t, x, u, p):
    """dy/dt = a y [1/s]: every perturbation grows like the solution."""
    return p["a"] * x
'''


def test_a_growing_solution_sets_the_limit_by_run_length_and_keeps_its_order(tmp_path):
    """dy/dt = y: Euler's perturbed run grows (1 + h)^n whatever the step, so the blow-up test
    fails once (1 + h)^steps passes `growth` (h = growth^(1/steps) - 1, the length of the run,
    not the method's stability, sets h_meas: the spin-out of a saturated bicycle measures the
    same way), and calls every grid step unstable; the order is still fitted, from the
    accuracy runs, and is Euler's."""
    (tmp_path / "growth.py").write_text(GROWTH)
    raw = {"name": "growth", "horizon": 1.0, "methods": ["euler"],
           "model": {"rhs": "growth:grow", "path": str(tmp_path), "states": ["y"],
                     "inputs": []},
           "params": {"a": 1.0}, "initial": {"y": 1.0},
           "envelope": {"a": {"values": [1.0]}},
           "steps": {"h": {"min": 0.0125, "max": 0.1, "num": 4}},
           "reference": {"rtol": 1e-12, "atol": 1e-14},
           "stability": {"rule": "blowup", "steps": 500, "rel_tol": 1e-3},
           "timing": {"rounds": 1}}
    cfg = validate(raw, str(tmp_path / "growth.toml"))
    chunk = compute_chunk(cfg, "euler-b000")
    assert not chunk["runs"]["stable"].any()
    lim = chunk["limits"].iloc[0]
    assert math.isinf(lim["h_pred"])                           # a growing mode bounds nothing
    h_growth = cfg.stability.growth ** (1 / cfg.stability.steps) - 1
    assert h_growth / (1 + cfg.stability.rel_tol) <= lim["h_meas"] <= h_growth * (1 + 1e-9)
    assert lim["order_note"] == "asymptotic" and lim["order_points"] == 4
    assert lim["order_fit"] == pytest.approx(1.0, abs=metrics.ORDER_TOL)


@pytest.mark.parametrize("name", ["euler", "heun", "rk4", "ab2"])
def test_a_weakly_damped_mode_does_not_hide_the_binding_one(name):
    """Fiala tyres at 20.7 m/s, steer 0.1: the lateral pair at t = 0, and at 0.8 s, both axles
    sliding, a pair 7e-6 left of the imaginary axis. The prediction over the trajectory is the
    smallest limit of them all (ranking rays by a rounded angle once put that pair on the
    axis's other side and reported rk4's 268 s instead of 0.284 s)."""
    lam = np.array([[-5.685 + 7.321j, -5.685 - 7.321j], [-7e-6 + 0.0106j, -7e-6 - 0.0106j]])
    m = method(name)
    h, k, _ = predicted_limit(m, lam)
    assert h == pytest.approx(max_stable_step(m, lam.ravel()), rel=1e-12)
    if name == "rk4":
        assert h == pytest.approx(0.2843, abs=1e-4) and k == 0
