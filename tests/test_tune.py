"""The tuned (method, h) is the cheapest that the sweep shows stable with the margin and within
the tolerance everywhere: in calibrated time (the default; a tie within the measured spread
to fewer RHS evaluations) or in RHS evaluations (--cost evals). It holds at 20 seeded
operating points the sweep never saw, and the file carries what the planner reads; mistakes
are one line, exit 2."""
import tomllib
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from stepzoo import dynamics
from stepzoo.cli import main as stepzoo
from stepzoo.bench.sweep.config import load
from stepzoo.bench.tune.cheapest import candidates
from stepzoo.dynamics.linear import lateral_eigenvalues
from stepzoo.integrators import integrate_batch, method
from stepzoo.integrators.reference import reference
from stepzoo.integrators.stability import max_stable_step

SMALL = Path(__file__).resolve().parents[1] / "bench" / "configs" / "small.toml"
POS_TOL, MARGIN = 0.01, 0.1        # [m], fraction


@pytest.fixture(scope="module")
def tuned_both(tmp_path_factory, small_toml_sweep):
    """(sweep folder, {cost: tuned TOML}, the folder of the tuned files tuned_COST.toml) of
    the small sweep (conftest), tuned by time and by evals."""
    folder = tmp_path_factory.mktemp("tune")
    files = {}
    for cost in ("time", "evals"):
        out = folder / f"tuned_{cost}.toml"
        flag = [] if cost == "time" else ["--cost", "evals"]      # time is the default
        assert stepzoo(["tune", str(small_toml_sweep), "--pos-tol", str(POS_TOL), "--margin",
                        str(MARGIN), "--out", str(out), *flag]) == 0
        files[cost] = tomllib.loads(out.read_text())
    return small_toml_sweep, files, folder


@pytest.fixture(scope="module")
def tuned(tuned_both):
    sweep, files, _ = tuned_both
    return sweep, files["time"]


def test_tuned_file_says_what_why_and_from_which_sweep(tuned):
    sweep, t = tuned
    manifest = (sweep / "manifest.json").read_text()
    assert t["sweep_config_sha256"] in manifest and t["pos_tol_m"] == POS_TOL
    for key in ("method", "h", "why", "margin", "cost_evals_per_s", "cost_time_per_s",
                "envelope", "runners_up", "provenance"):
        assert key in t
    assert t["method"] in t["why"] and "\n" not in t["why"]
    assert {r["method"] for r in t["runners_up"]} | {t["method"]} == set(load(SMALL).methods)


def test_a_rerun_keeps_the_choice_made_from_the_same_sweep_and_arguments(tuned_both, tmp_path):
    """`stepzoo run` run again keeps its tuned file (a new timing could break a near tie
    otherwise, and every plan with it) only where that file was tuned by time from this very
    sweep with this tolerance and margin: another tolerance, margin or cost, a sweep made
    again (its creation time) or one elsewhere is tuned anew."""
    import json
    import shutil
    from stepzoo.workflows.tune import kept
    sweep, files, folder = tuned_both
    out = folder / "tuned_time.toml"
    assert kept(out, sweep, POS_TOL, MARGIN) == files["time"]
    assert kept(out, sweep, POS_TOL * 2, MARGIN) is None
    assert kept(out, sweep, POS_TOL, MARGIN * 2) is None
    assert kept(folder / "tuned_evals.toml", sweep, POS_TOL, MARGIN) is None
    assert kept(tmp_path / "missing.toml", sweep, POS_TOL, MARGIN) is None
    again = tmp_path / "sweep"
    shutil.copytree(sweep, again)
    assert kept(out, again, POS_TOL, MARGIN) is None             # a sweep elsewhere
    manifest = json.loads((sweep / "manifest.json").read_text())
    moved = tmp_path / "renewed.toml"
    moved.write_text(out.read_text().replace(str(sweep.resolve()), str(again.resolve())))
    renewed = kept(moved, again, POS_TOL, MARGIN)
    assert renewed is not None and (renewed["method"], renewed["h"]) == (
        files["time"]["method"], files["time"]["h"])
    (again / "manifest.json").write_text(json.dumps({**manifest, "created": "later"}))
    assert kept(moved, again, POS_TOL, MARGIN) is None            # the sweep made again


def test_cost_evals_chooses_the_fewest_evaluations_that_qualify(tuned_both):
    sweep, files, _ = tuned_both
    t = files["evals"]
    assert t["cost"] == "evals" and files["time"]["cost"] == "time"
    runs = pd.read_parquet(sweep / "runs.parquet")
    limits = pd.read_parquet(sweep / "limits.parquet")
    rows = runs.merge(limits[["method", "point", "h_meas"]], on=["method", "point"])
    mine = rows[(rows["method"] == t["method"]) & np.isclose(rows["h"], t["h"])]
    assert mine["stable"].all() and (mine["h"] <= (1 - MARGIN) * mine["h_meas"]).all()
    assert (mine["err_pos"] <= POS_TOL).all()
    table = candidates(runs, limits, POS_TOL, MARGIN)
    assert table[table["ok"]]["cost_evals_per_s"].min() == pytest.approx(t["cost_evals_per_s"])


def test_the_calibration_defaults_are_the_planners_call():
    from stepzoo.bench.timing.calibrate import PLANNER_BATCH, PLANNER_INTERVAL_S
    from stepzoo.workflows.tune import planner_call
    assert planner_call() == (PLANNER_BATCH, PLANNER_INTERVAL_S)


def test_the_reports_tuning_table_says_which_cost_chose(tuned_both):
    from stepzoo.reports.tables import tuning_caption, tuning_rows
    _, files, _ = tuned_both
    assert "ranked by measured wall time" in tuning_caption(files["time"])
    assert "ranked by RHS evaluations" in tuning_caption(files["evals"])
    rows = tuning_rows(files["time"])
    assert rows[0]["method"] == files["time"]["method"] and rows[1]["cost_time_per_s"] > 0


def _qualifying(t) -> list[dict]:
    return [{k: t[k] for k in ("method", "h", "cost_time_per_s", "cost_evals_per_s")},
            *[r for r in t["runners_up"] if r["qualifies"]]]


def test_cost_time_chooses_the_fastest_within_the_measured_spread(tuned):
    """Behaviour, not speed: each qualifying method's best step (its largest qualifying h) is
    priced as steps per second x its calibrated time per step, and the choice is the argmin of
    those prices up to the spread (never more than 10% slower), where fewer evaluations win."""
    sweep, t = tuned
    runs = pd.read_parquet(sweep / "runs.parquet")
    limits = pd.read_parquet(sweep / "limits.parquet")
    table = candidates(runs, limits, POS_TOL, MARGIN)
    largest = table[table["ok"]].groupby("method")["h"].max()
    cal, tie_max = t["calibration"]["methods"], t["calibration"]["tie_max"]
    rows = _qualifying(t)
    assert {r["method"]: r["h"] for r in rows} == pytest.approx(largest.to_dict())
    assert set(cal) == set(largest.index) and t["calibration"]["batch"] == 40
    for r in rows:
        c = cal[r["method"]]
        assert c["n_steps"] == round(t["calibration"]["interval_s"] / r["h"])
        assert r["cost_time_per_s"] == pytest.approx(c["per_step_s"] / r["h"], rel=1e-12)
    fastest = min(rows, key=lambda r: r["cost_time_per_s"])
    rel = lambda r: cal[r["method"]]["spread_s"] / cal[r["method"]]["per_step_s"]
    window = lambda r: min(max(rel(r), rel(fastest)), tie_max)
    best = fastest["cost_time_per_s"]
    tied = [r for r in rows if r["cost_time_per_s"] <= best * (1 + window(r))]
    assert t["method"] in {r["method"] for r in tied}
    assert t["cost_time_per_s"] <= 1.1 * best
    assert t["cost_evals_per_s"] == min(r["cost_evals_per_s"] for r in tied)
    later = [r["cost_time_per_s"] for r in rows[1:]]
    assert later == sorted(later)


def test_tuned_step_holds_at_20_unseen_operating_points(tuned):
    _, t = tuned
    cfg = load(SMALL)
    rng = np.random.default_rng(20240601)
    vx = rng.uniform(min(cfg.values("vx")), max(cfg.values("vx")), 20)
    delta = rng.uniform(min(cfg.values("delta")), max(cfg.values("delta")), 20)
    seen = {(round(a, 9), round(b, 9)) for a, b in cfg.points}
    assert not any((round(a, 9), round(b, 9)) in seen for a, b in zip(vx, delta))
    model, meth, h = dynamics.model(cfg.spec.name), method(t["method"]), t["h"]
    n = round(cfg.horizon / h)
    ps = [model.params(cfg.vehicle, v) for v in vx]
    p = {k: jnp.asarray([q[k] for q in ps]) for k in ps[0]}
    x0 = jnp.zeros((20, 5))
    u = jnp.asarray(delta)[:, None]
    x = np.asarray(integrate_batch(meth, model.rhs, x0, u, p, h, n).x)
    ts = h * jnp.arange(n + 1)
    ref = jax.vmap(lambda a, b, c: reference(model.rhs, a, b, c, ts).x)(x0, u, p)
    err_pos = np.hypot(*(x[:, :, :2] - np.asarray(ref)[:, :, :2]).transpose(2, 0, 1)).max(axis=1)
    assert np.all(err_pos <= POS_TOL), err_pos
    phys = dynamics.physical(cfg.vehicle)
    limit = [max_stable_step(meth, np.asarray(lateral_eigenvalues(a, b, phys)))
             for a, b in zip(vx, delta)]
    assert np.all(h <= (1 - MARGIN / 2) * np.asarray(limit))


def test_an_impossible_tolerance_is_no_answer_one_line_and_exit_1(tuned, tmp_path, capsys):
    sweep, _ = tuned
    assert stepzoo(["tune", str(sweep), "--pos-tol", "1e-12", "--out",
                    str(tmp_path / "t.toml")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "loosen --pos-tol" in err
    assert not (tmp_path / "t.toml").exists()


@pytest.mark.parametrize("args,message", [
    (["--pos-tol", "0.1", "--margin", "1.5"], "--margin must be a stability margin"),
    (["--pos-tol", "-1"], "--pos-tol must be a position tolerance"),
    (["--pos-tol", "0.1", "--rounds", "0"], "--rounds must be a number of timed rounds"),
])
def test_bad_flags_are_one_line_and_exit_2(tuned, tmp_path, capsys, args, message):
    sweep, _ = tuned
    assert stepzoo(["tune", str(sweep), *args, "--out", str(tmp_path / "t.toml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def test_a_folder_that_is_no_sweep_is_one_line_and_exit_2(tmp_path, capsys):
    assert stepzoo(["tune", str(tmp_path), "--pos-tol", "0.1", "--out",
                    str(tmp_path / "t.toml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a finished sweep folder" in err


def _missed_by_measurement(tiny_sweep, tmp_path, factor: float = 4.0):
    """A copy of the tiny sweep whose euler predictions lie `factor` x below its measured
    limits, as on a saturating model whose chatter the measurement misses."""
    import shutil
    _, whole = tiny_sweep
    folder = tmp_path / "sweep"
    shutil.copytree(whole, folder)
    limits = pd.read_parquet(folder / "limits.parquet")
    euler = limits["method"] == "euler"
    limits.loc[euler, "h_pred"] = limits.loc[euler, "h_meas"] / factor
    limits.to_parquet(folder / "limits.parquet", index=False)
    return folder, limits


def test_tune_never_picks_a_step_beyond_its_predicted_limit(tiny_sweep, tmp_path):
    """Predictions 4x below the measured limits: euler at 0.05 s is inside a 10% margin
    below its measured limit and well past its predicted one. Tune keeps 0.9 x the smaller
    limit at every point; only the flag that names the risk lets it past, and the file says
    so."""
    folder, limits = _missed_by_measurement(tiny_sweep, tmp_path)
    got = {}
    for flag in ([], ["--allow-beyond-predicted-limit"]):
        out = tmp_path / f"t{len(flag)}.toml"
        assert stepzoo(["tune", str(folder), "--tol", "10", "--margin", "0.1", "--cost",
                        "evals", "--out", str(out), *flag]) == 0
        got[bool(flag)] = tomllib.loads(out.read_text())
    kept = got[False]
    pred = limits[limits["method"] == kept["method"]]["h_pred"]
    assert kept["h"] <= 1.1 * pred.min()
    assert kept["h_over_h_pred_max"] <= 0.9 and not kept["allow_beyond_predicted_limit"]
    risky = got[True]
    assert (risky["method"], risky["h"]) == ("euler", 0.05)
    assert risky["allow_beyond_predicted_limit"] and risky["h_over_h_pred_max"] > 1.1
    assert "--allow-beyond-predicted-limit" in risky["why"]
