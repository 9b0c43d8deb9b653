"""A failed nonlinear solve is a result of the sweep, told apart from instability: on Van der
Pol with mu = 1000 (dynamics/problems/stiff.py) from (1.5, 0), backward Euler's Newton solves converge
through the 50 stability steps of 1 s but fail at 10 s steps (A-stable: no step limit is
predicted, so the limit measured is the solver's); explicit Euler blows up instead."""
import numpy as np
import pytest

from stepzoo.bench.sweep.engine import run_sweep
from stepzoo.bench.sweep.config import load
from stepzoo.reports import tables
from stepzoo.reports.load import load_sweep
from helpers import SOLVER_FAILURE_CONFIG as CONFIG



@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    folder = tmp_path_factory.mktemp("vdp")
    (folder / "vdp.toml").write_text(CONFIG)
    run_sweep(load(folder / "vdp.toml"), folder / "out", progress=False)
    return load_sweep(folder / "out")


def test_a_failed_solve_is_never_stable(sweep):
    be = sweep.runs[sweep.runs["method"] == "backward_euler"].set_index("h")
    assert bool(be.loc[1.0, "converged"]) and bool(be.loc[1.0, "stable"])
    assert not bool(be.loc[10.0, "converged"]) and not bool(be.loc[10.0, "stable"])


def test_the_limit_says_the_solver_failed_not_the_method(sweep):
    lim = sweep.limits.set_index("method")
    be = lim.loc["backward_euler"]
    # A-stable: no step limit predicted; the measured one is where Newton stops converging.
    assert np.isinf(be["h_pred"]) and 1.0 <= be["h_meas"] < 10.0
    assert be["limit_cause"] == "solver failed"
    assert lim.loc["euler", "limit_cause"] == "unstable" and lim.loc["euler", "h_meas"] < 1.0


def test_summary_and_report_count_failed_solves_apart_from_blow_ups(sweep):
    summary = sweep.summary.set_index("method")
    assert summary.loc["backward_euler", "solver_failures"] >= 1
    assert summary.loc["euler", "solver_failures"] == 0
    euler_runs = sweep.runs[sweep.runs["method"] == "euler"]
    assert not euler_runs["stable"].any() and euler_runs["converged"].all()
    rows = {r["method"]: r for r in tables.method_summary(sweep, tol=0.1, margin=0.2,
                                                          error="err")}
    assert rows["backward_euler"]["solver_failures"] >= 1
    assert rows["euler"]["solver_failures"] == 0
