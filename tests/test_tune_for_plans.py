"""`stepzoo tune SWEEP --for-plans QUERIES`: the sweep's qualifying candidates plan the queries
and the written choice is the one the [plans] evidence says (the smallest median plan time of
those at the best exact rate whose replays stay below the tolerance, by default the planner
config's collision margin); a tolerance below a candidate's measured deviation excludes it;
mistakes are one line, exit 2, and write nothing."""
import hashlib
import json
import shutil
import tomllib

import numpy as np
import pytest

from stepzoo.cli import main as stepzoo
from helpers import block_query

POS_TOL, MARGIN = "1", "0.2"      # on the tiny sweep: euler and heun qualify at h = 0.01 s
# A collision margin that is no parameter's default, so the test sees where the tol comes from.
PLANNER = """method = "heun"
h = 0.01
[planner]
margin = 0.12
improve_expansions = 0
max_seconds = 10.0
"""


@pytest.fixture(scope="module")
def setup(tiny_sweep, tmp_path_factory):
    """(folder, sweep copy, queries file, planner config): one query around a 4 x 10 m block
    on a 40 x 20 m map, at cell 0.5 m."""
    folder = tmp_path_factory.mktemp("for_plans")
    shutil.copytree(tiny_sweep[1], folder / "sweep")
    block_query(folder)
    (folder / "planner.toml").write_text(PLANNER)
    return folder


def tune(folder, out, *flags) -> int:
    return stepzoo(["tune", str(folder / "sweep"), "--pos-tol", POS_TOL, "--margin", MARGIN,
                    "--rounds", "1", "--for-plans", str(folder / "q.json"), "--planner-config",
                    str(folder / "planner.toml"), "--out", str(out), "--no-progress", *flags])


@pytest.fixture(scope="module")
def tuned(setup):
    out = setup / "tuned.toml"
    assert tune(setup, out) == 0
    return tomllib.loads(out.read_text())


def test_the_choice_is_the_fastest_planner_within_the_margin_at_the_best_exact_rate(setup,
                                                                                    tuned):
    plans = tuned["plans"]
    assert plans["replay_tol_m"] == 0.12 and "margin" in plans["replay_tol_from"]
    assert plans["queries_sha256"] == hashlib.sha256((setup / "q.json").read_bytes()).hexdigest()
    assert plans["runs"] == 1 and plans["seeds"] == [0]
    rows = plans["candidates"]
    assert {r["method"] for r in rows} == {"euler", "heun"} and all(r["h"] == 0.01 for r in rows)
    best = max(r["exact"] for r in rows)
    assert best == 1
    ok = [r for r in rows if r["exact"] == best and r["max_replay_deviation_m"] < 0.12]
    won = min(ok, key=lambda r: r["median_time_s"])
    assert (tuned["method"], tuned["h"]) == (won["method"], won["h"])
    assert plans["chosen"] == won["integrator"] and plans["why"].startswith("chosen")
    assert [r["within_tol"] for r in rows] == [r in ok for r in rows]
    # The other candidate is the runner-up, and the file is a planner config as tune writes.
    assert [r["method"] for r in tuned["runners_up"]] == [r["method"] for r in rows
                                                         if r is not won]
    assert tuned["cost"] == "time" and tuned["err_pos_max_m"] <= float(POS_TOL)
    # A planner reading the file plans as the evidence did: the given planner config's
    # settings (its margin among them) go with the choice.
    from stepzoo.search.planner.config import load_config
    assert load_config(setup / "tuned.toml").params.model_dump() == plans["planner"]
    assert tuned["planner"]["margin"] == 0.12


def test_a_tolerance_below_a_candidates_deviation_excludes_it(setup, tuned, capsys):
    rows = {r["method"]: r for r in tuned["plans"]["candidates"]}
    # Euler strays farther from its plans than heun at the same step (first order vs second).
    assert rows["euler"]["max_replay_deviation_m"] > 10 * rows["heun"]["max_replay_deviation_m"]
    tol = float(np.sqrt(rows["euler"]["max_replay_deviation_m"]
                        * rows["heun"]["max_replay_deviation_m"]))
    out = setup / "tight.toml"
    assert tune(setup, out, "--replay-tol", repr(tol)) == 0
    tight = tomllib.loads(out.read_text())
    again = {r["method"]: r for r in tight["plans"]["candidates"]}
    assert again["euler"]["max_replay_deviation_m"] > tol and not again["euler"]["within_tol"]
    assert "strayed" in again["euler"]["verdict"]
    assert tight["method"] == "heun" and tight["plans"]["replay_tol_m"] == tol
    assert tight["plans"]["replay_tol_from"] == "--replay-tol"
    # Below every deviation: no answer, one line, exit 1, nothing written.
    capsys.readouterr()
    none = setup / "none.toml"
    assert tune(setup, none, "--replay-tol", "1e-12") == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "loosen --replay-tol" in err and not none.exists()


@pytest.mark.parametrize("flags,message", [
    (["--for-plans", "missing.json"], "--for-plans missing.json: no such file"),
    (["--for-plans", "q.json", "--replay-tol", "-0.1"], "--replay-tol must be"),
    (["--for-plans", "q.json", "--runs", "0"], "--runs must be >= 1"),
    (["--replay-tol", "0.1"], "--replay-tol only work with --for-plans"),
    # 1e5 runs of planning at the shipped budget: refused with its estimate before tuning.
    (["--for-plans", "q.json", "--runs", "100000"], "100000 plans (1 queries x 1 "
     "integrators x 100000 runs)"),
    (["--for-plans", "q.json", "--max-hours", "0"], "--max-hours must be a number > 0"),
])
def test_bad_for_plans_input_is_one_line_exit_2_and_nothing_written(setup, tmp_path, capsys,
                                                                    monkeypatch, flags, message):
    monkeypatch.chdir(setup)
    out = tmp_path / "t.toml"
    assert stepzoo(["tune", "sweep", "--pos-tol", POS_TOL, "--out", str(out), *flags]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and not out.exists()


def test_for_plans_refuses_a_sweep_of_another_model_than_the_planner_s_car(setup, tmp_path,
                                                                           capsys):
    """The planner plans with the dynamic bicycle: a (method, h) tuned on another model's
    sweep is refused in one line, before tuning, and nothing is written."""
    shutil.copytree(setup / "sweep", tmp_path / "sweep")
    manifest = json.loads((tmp_path / "sweep" / "manifest.json").read_text())
    (tmp_path / "sweep" / "manifest.json").write_text(json.dumps(dict(manifest,
                                                                      model="kinematic")))
    out = tmp_path / "t.toml"
    assert stepzoo(["tune", str(tmp_path / "sweep"), "--pos-tol", POS_TOL, "--for-plans",
                    str(setup / "q.json"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a sweep of 'kinematic'" in err and not out.exists()
