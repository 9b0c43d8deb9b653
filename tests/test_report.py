"""`stepzoo report`: built from small synthetic result folders with the sweep, tune and plan
contracts, the page is self-contained (parses, no network address, every image a PNG that
exists, Figures 1-7 present), the tables compute what they claim, and a missing or damaged
input is one line naming it, exit 2."""
import base64
import gzip
import json
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from plotly.offline import get_plotlyjs

from stepzoo.cli import main as stepzoo
from stepzoo.bench.sweep_config import load
from stepzoo.reports import tables
from stepzoo.reports.load import load_sweep

PNG = b"\x89PNG\r\n\x1a\n"
# Synthetic methods: (order, stages, limit constant c in h_max = c / |lambda| scale).
METHODS = {"euler": (1, 1, 2.0), "rk4": (4, 4, 2.785), "ab4": (4, 1, 0.3),
           "backward_euler": (1, 1, np.inf)}
STEPS = [0.005, 0.01, 0.02, 0.05, 0.1]
POINTS = [(2.0, 0.1), (2.0, 0.785), (15.0, 0.1), (15.0, 0.785)]      # (vx m/s, delta rad)


def lam_of(vx):
    """A stand-in lateral eigenvalue [1/s] that scales like 1/vx, as the real ones do."""
    return complex(-60.0 / vx, 25.0 / vx)


def err_of(method, h):
    p = METHODS[method][0]
    return 3.0 * h ** p


def write_sweep(folder):
    """A finished sweep folder: its config implies exactly the rows written below."""
    folder.mkdir(parents=True)
    (folder / "config.toml").write_text(
        'horizon = 1.0\nmethods = ["euler", "rk4", "ab4", "backward_euler"]\n'
        f"[envelope]\nvx = [2.0, 15.0]\ndelta = [0.1, 0.785]\n[steps]\nh = {STEPS}\n"
        # The point of the synthetic trajectories below, named: the report draws them.
        "[trajectories]\nvx = 15.0\ndelta = 0.785\n")
    (folder / "manifest.json").write_text(json.dumps(
        {"config_sha256": load(folder / "config.toml").sha256, "complete": True,
         "timing": {"repeats": 3}, "blowup_rule": "|x| > 1e6",
         "trajectory_point": {"vx": 15.0, "delta": 0.785}}))
    runs, limits = [], []
    for name, (p, stages, c) in METHODS.items():
        for i, (vx, delta) in enumerate(POINTS):
            h_max = c / abs(lam_of(vx))
            for h in STEPS:
                stable = h < h_max
                e = err_of(name, h) if stable else np.nan
                runs.append(dict(method=name, h=h, point=i, vx=vx, delta=delta, stable=stable,
                                 blowup_t=np.nan if stable else 1.0, err_X=e, err_Y=e,
                                 err_psi=e, err_vy=e, err_r=e, err_pos=e, err_final=e,
                                 evals_per_s=stages / h, time_per_step_s=1e-6 * stages))
            limits.append(dict(method=name, point=i, vx=vx, delta=delta, h_pred=h_max,
                               h_meas=h_max * 1.01 if np.isfinite(h_max) else np.nan,
                               ratio=1.01, order_declared=p, order_fit=p + 0.02))
    pd.DataFrame(runs).to_parquet(folder / "runs.parquet")
    pd.DataFrame(limits).to_parquet(folder / "limits.parquet")
    pd.DataFrame(limits).to_csv(folder / "limits.csv", index=False)
    summary = [dict(method=n, family="explicit RK", order_declared=p, order_fit_median=p + 0.02,
                    real_interval=c, imag_interval=0.0,
                    h_meas_min=1.01 * c / abs(lam_of(2.0)), h_pred_min=c / abs(lam_of(2.0)),
                    worst_ratio=1.01) for n, (p, _, c) in METHODS.items()]
    pd.DataFrame(summary).to_csv(folder / "summary.csv", index=False)
    pd.DataFrame([dict(point=i, vx=vx, delta=d, lam_re=lam_of(vx).real, lam_im=s * lam_of(vx).imag)
                  for i, (vx, d) in enumerate(POINTS) for s in (1, -1)]
                 ).to_parquet(folder / "eigenvalues.parquet")
    traj = []
    t = np.linspace(0.0, 2.0, 201)
    r_ref = 0.5 * (1 - np.exp(-3 * t))
    for name, h, growth in [("reference", 0.0, 0.0), ("euler", 0.01, 0.0), ("euler", 0.2, 6.0),
                            ("rk4", 0.05, 0.0), ("rk4", 0.3, 8.0)]:
        r = r_ref * (1 + 0.02 * h) + (np.expm1(growth * t) if growth else 0.0)
        psi = np.cumsum(r) * (t[1] - t[0])
        traj += [dict(method=name, h=h, t=ti, X=15 * np.cos(pi), Y=15 * np.sin(pi), psi=pi,
                      vy=-0.1 * ri, r=ri) for ti, ri, pi in zip(t, r, psi)]
    pd.DataFrame(traj).to_parquet(folder / "trajectories.parquet")
    return folder


def write_tuned(path, h=0.02):
    path.write_text(
        f'method = "rk4"\nh = {h}\nwhy = "cheapest under the tolerance"\npos_tol_m = 0.1\n'
        'margin = 0.2\ncost_evals_per_s = 200.0\ncost_time_per_s = 0.0002\n'
        'sweep_config_sha256 = "abc123"\nprovenance = "test"\n\n'
        '[envelope]\nvx = [2.0, 15.0]\npoints = 4\n\n[[runners_up]]\nmethod = "ab4"\nh = 0.005\ncost_evals_per_s = 200.0\n'
        'cost_time_per_s = 0.0002\nreason = "stability limit"\n')
    return path


def write_plan(folder, name="street"):
    plan = folder / name
    plan.mkdir(parents=True)
    grid = np.zeros((40, 60), bool)
    grid[:10, 20:25] = True                         # an obstacle near the bottom (row 0)
    np.save(plan / "map.npy", grid)
    path = [[0.1 * i, 2.0 + 0.5 * i, 2.0 + 0.3 * i, 0.5] for i in range(40)]
    record = {"scenario": name, "status": "exact", "reason": "reached the goal",
              "path": path, "vehicle": {"length": 4.5, "width": 1.8},
              "stats": {"expansions": 12, "nodes": 40, "search_s": 0.3, "connect_s": 0.1,
                        "path_length_m": 23.0, "connect_tf_s": 2.0, "seed": 0,
                        "method": "rk4", "h": 0.02},
              "start": [2.0, 2.0, 0.0], "goal": [22.0, 14.0, 0.5],
              "tree": [[[2.0, 2.0], [4.0, 3.0], [6.0, 3.5]], [[2.0, 2.0], [4.0, 1.0]]],
              "map": {"file": "map.npy", "resolution": 0.5, "origin": [0.0, 0.0]}}
    (plan / "plan.json").write_text(json.dumps(record))
    return plan


@pytest.fixture
def run_folder(tmp_path):
    """A `stepzoo run`-shaped folder: sweep/, tuned.toml, plans/<one scenario>."""
    write_sweep(tmp_path / "res" / "sweep")
    write_tuned(tmp_path / "res" / "tuned.toml")
    write_plan(tmp_path / "res" / "plans")
    return tmp_path / "res"


class _Page(HTMLParser):
    """Collects ids, image sources and every attribute value that could address a resource."""
    def __init__(self):
        super().__init__()
        self.ids, self.imgs, self.refs = set(), [], []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if "id" in attrs:
            self.ids.add(attrs["id"])
        if tag == "img":
            self.imgs.append(attrs.get("src", ""))
        self.refs += [v for k, v in attrs.items() if k in ("src", "href", "srcset") and v]


def plots(text) -> dict:
    """The page's interactive figures, unpacked: {plot id: {"data", "layout", "config"}}."""
    found = re.findall(r'<script type="application/octet-stream" class="plot-spec" '
                       r'data-for="([^"]+)">([^<]*)</script>', text)
    return {key: json.loads(gzip.decompress(base64.b64decode(packed)))
            for key, packed in found}


def check_report(out, n_plans=1):
    """Assert the report in `out` is a self-contained page with Figures 1-7, each interactive
    with a static copy, plotly.js inlined once, the environment appendix, and no path of
    this machine; return its text."""
    text = (out / "index.html").read_text()
    page = _Page()
    page.feed(text)
    page.close()
    assert text.lstrip().startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    assert '<meta name="viewport" content="width=device-width' in text
    # The library's own text names websites (licences, map styles it never loads here): the
    # page around it must name none, and nothing may load from one (browser test).
    tag = '<script id="plotly-js" type="application/octet-stream">'
    head, js, rest = re.split(f'{tag}|</script>\n</head>', text, maxsplit=2)
    # Packed (gzip, base64), it is the whole library, once.
    assert gzip.decompress(base64.b64decode(js)).decode() == get_plotlyjs()
    assert text.count(tag) == 1
    assert "http://" not in head + rest and "https://" not in head + rest
    assert str(out.parent) not in text and str(Path.home()) + "/" not in text
    assert not [r for r in page.refs if r.startswith("//") or ":" in r.split("#")[0]]
    assert {f"fig{i}" for i in range(1, 8)} <= page.ids
    assert {f"plot{i}-1" for i in range(1, 7)} <= page.ids
    assert {f"plot7-{i + 1}" for i in range(n_plans)} <= page.ids
    assert set(plots(text)) == {f"plot{i}-1" for i in range(1, 7)} | {
        f"plot7-{i + 1}" for i in range(n_plans)}          # each plot with its figure
    assert "appendix" in page.ids and "float precision" in rest
    assert len(page.imgs) == 6 + n_plans
    for src in page.imgs:
        assert (out / src).is_file(), src
        assert (out / src).read_bytes()[:8] == PNG, src
    md = (out / "summary.md").read_text()
    for i in range(1, 8):
        assert f"## Figure {i}." in md
    return text


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
    for name, (p, stages, c) in METHODS.items():
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
    assert "stable, within 13% of the limit" in section
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
