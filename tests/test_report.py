"""`stepzoo report`: built from small synthetic result folders with the sweep, tune and plan
contracts, the page is self-contained (parses, no network address, every image a PNG that
exists, Figures 1-7 present), the tables compute what they claim, and a missing or damaged
input is one line naming it, exit 2."""
import json
import re

import pandas as pd
import pytest

from stepzoo.cli import main as stepzoo
from stepzoo.reports import tables
from stepzoo.reports.load import load_sweep
from helpers import (METHODS, STEPS, check_report, err_of, lam_of, plots,
                     write_plan, write_sweep, write_tuned)



@pytest.fixture
def run_folder(tmp_path):
    """A `stepzoo run`-shaped folder: sweep/, tuned.toml, plans/<one scenario>."""
    write_sweep(tmp_path / "res" / "sweep")
    write_tuned(tmp_path / "res" / "tuned.toml")
    write_plan(tmp_path / "res" / "plans")
    return tmp_path / "res"


def test_report_from_a_sweep_and_one_plan_is_self_contained(tmp_path, capsys):
    sweep = write_sweep(tmp_path / "sweep")
    tuned = write_tuned(tmp_path / "tuned.toml")
    plans = write_plan(tmp_path / "plans")
    out = tmp_path / "report"
    assert stepzoo(["report", str(sweep), "--tuned", str(tuned), "--plans", str(plans),
                    "--out", str(out), "-q"]) == 0
    said = capsys.readouterr()
    assert str(out / "index.html") in said.out and said.err == ""     # -q: no progress lines
    text = check_report(out)
    assert "Tuning decision" in text and "runners-up" in text
    assert "stability limit" in text               # a runner-up's reason reaches the table


def test_run_folder_supplies_tuned_config_and_plans(run_folder, tmp_path, capsys):
    out = tmp_path / "report"
    assert stepzoo(["report", str(run_folder), "--out", str(out), "--format", "json"]) == 0
    said = capsys.readouterr()
    listed = json.loads(said.out)
    lines = [ln for ln in said.err.splitlines() if ln.startswith("stepzoo report: [")]
    assert [ln.split(".")[0] for ln in lines] == [       # a line per figure, so none is silent
        f"stepzoo report: [{i}/7] Figure {i}" for i in range(1, 8)]
    assert listed["index"] == str(out / "index.html")
    assert any(name.startswith("fig7_plan_street") for name in listed["figures"])
    check_report(out)


def test_report_without_tuned_config_or_plans_still_has_every_figure(tmp_path, capsys):
    sweep = write_sweep(tmp_path / "sweep")
    out = tmp_path / "report"
    assert stepzoo(["report", str(sweep), "--out", str(out), "--no-progress"]) == 0
    assert capsys.readouterr().err == ""
    text = check_report(out, n_plans=0)
    assert "No plan folders were given" in text


def test_regions_caption_names_the_methods_stable_at_the_tuned_step(tmp_path):
    from stepzoo.reports.figure_data import stability_regions
    sweep = load_sweep(write_sweep(tmp_path / "sweep"))
    # |lambda| at 2 m/s is 32.5 1/s: h = 0.07 puts h*lambda inside RK4's region (|z| = 2.3,
    # angle 157 deg) but outside forward Euler's disc and AB4's small region.
    shown = stability_regions(sweep, {"method": "rk4", "h": 0.07})
    safe = shown.caption.rsplit(":", 1)[1]
    assert "rk4" in safe and "backward_euler" in safe
    assert "euler," not in safe and " euler" not in safe.replace("backward_euler", "")
    assert "ab4" not in safe


def test_cost_at_tolerance_is_the_largest_safe_step_within_the_margin(tmp_path):
    sweep = load_sweep(write_sweep(tmp_path / "sweep"))
    rows = {r["method"]: r for r in tables.method_summary(sweep, tol=0.1, margin=0.2)}
    for name, (_, stages, c) in METHODS.items():
        cap = 0.8 * 1.01 * c / abs(lam_of(2.0))
        ok = [h for h in STEPS if err_of(name, h) <= 0.1 and h <= cap and h < c / abs(lam_of(2.0))]
        if ok:
            assert rows[name]["h_at_tol"] == max(ok)
            assert rows[name]["evals_at_tol"] == pytest.approx(stages / max(ok))
        else:
            assert rows[name].get("h_at_tol") is None
    assert rows["backward_euler"]["h_at_tol"] == 0.02      # error-bound: 3 h <= 0.1
    assert rows["ab4"]["h_at_tol"] == 0.005                # stability-bound: 0.01 is unstable


def _damage_missing_runs(res):
    (res / "sweep" / "runs.parquet").unlink()


def _damage_corrupt_limits(res):
    (res / "sweep" / "limits.parquet").write_bytes(b"PAR1 this is not parquet")


def _damage_plan_key(res):
    path = res / "plans" / "street" / "plan.json"
    record = json.loads(path.read_text())
    del record["tree"]
    path.write_text(json.dumps(record))


def _damage_plan_map(res):
    (res / "plans" / "street" / "map.npy").unlink()


def _damage_summary_column(res):
    path = res / "sweep" / "summary.csv"
    pd.read_csv(path).drop(columns=["h_meas_min"]).to_csv(path, index=False)


def _damage_unfinished(res):
    path = res / "sweep" / "manifest.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), "complete": False}))


def _damage_tuned(res):
    (res / "tuned.toml").write_text('method = "rk4"\nh = 0.02\n')


def _damage_tuned_model(res):
    """A run folder mixing models: the tuned config of a user's model beside a bicycle's
    sweep (the third battery's case: drawn silently)."""
    path = res / "tuned.toml"
    path.write_text('model = "springs:chain"\n' + path.read_text())


def _damage_tuned_error(res):
    """The sweep of a model without a position, a tuned config bounding the position error
    (the third battery's case: a KeyError on err_pos)."""
    path = res / "sweep" / "runs.parquet"
    pd.read_parquet(path).drop(columns=["err_pos"]).to_parquet(path)


@pytest.mark.parametrize("damage, named", [
    (_damage_tuned_model, "is of the model springs:chain, the sweep"),
    (_damage_tuned_error, "bounds the position error (pos_tol_m), which the sweep"),
    (_damage_missing_runs, "runs.parquet"),
    (_damage_corrupt_limits, "limits.parquet"),
    (_damage_plan_key, "tree"),
    (_damage_plan_map, "map.npy"),
    (_damage_summary_column, "h_meas_min"),
    (_damage_tuned, "pos_tol_m"),
    (_damage_unfinished, "unfinished"),
])
def test_damaged_input_is_one_line_naming_it(run_folder, tmp_path, capsys, damage, named):
    damage(run_folder)
    out = tmp_path / "report"
    assert stepzoo(["report", str(run_folder), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and named in err and "Traceback" not in err
    assert not (out / "index.html").exists()


def test_missing_folders_are_named(tmp_path, capsys):
    sweep = write_sweep(tmp_path / "sweep")
    for args, named in [([str(tmp_path / "nope")], "nope"),
                        ([str(sweep), "--plans", str(tmp_path / "noplans")], "noplans"),
                        ([str(sweep), "--tuned", str(tmp_path / "t.toml")], "t.toml")]:
        assert stepzoo(["report", *args, "--out", str(tmp_path / "r")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and named in err


def test_verdict_adds_its_rows_and_draws_its_step(tiny_sweep, tmp_path, capsys):
    """--verdict euler:0.05 on the tiny sweep: a section whose rows are the sweep's own
    stability and position error at that step, point by point, and the step on Figures 4 and
    6 (static and interactive); a bad METHOD:H is one line, exit 2, nothing written."""
    _, folder = tiny_sweep
    out = tmp_path / "report"
    assert stepzoo(["report", str(folder), "--out", str(out), "--verdict", "euler:0.05",
                    "-q"]) == 0
    md = (out / "summary.md").read_text()
    section = md[md.index("## Verdict: euler at h = 0.05 s"):md.index("## Figure 1.")]
    rows = [ln.split(" | ") for ln in section.splitlines() if re.match(r"\| (6|20) \|", ln)]
    runs = pd.read_parquet(folder / "runs.parquet")
    runs = runs[(runs["method"] == "euler") & (runs["h"] == 0.05)].set_index("vx")
    assert len(rows) == len(runs) == 2
    for cells in rows:
        run = runs.loc[float(cells[0].strip("| "))]
        assert cells[3] == ("yes" if run["stable"] else "no")
        assert float(cells[4]) == pytest.approx(run["err_pos"], rel=1e-3)     # 4 digits
    assert "stable, within 12% of the limit" in section     # of the predicted one
    for n in (4, 6):
        caption = md[md.index(f"## Figure {n}."):].split("\n\n")[1]
        assert "--verdict are" in caption and "euler at 0.05 s" in caption
    drawn = plots((out / "index.html").read_text())
    for plot in ("plot4-1", "plot6-1"):
        names = [t.get("name") for t in drawn[plot]["data"]]
        assert "euler at h = 0.05 s (verdict)" in names, plot
    for bad, said in (("euler", "give METHOD:H"), ("rk4:0.01", "not a method of the sweep"),
                      ("euler:-1", "--verdict")):
        assert stepzoo(["report", str(folder), "--out", str(tmp_path / "bad"), "--verdict",
                        bad]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and said in err, err
        assert not (tmp_path / "bad").exists()
