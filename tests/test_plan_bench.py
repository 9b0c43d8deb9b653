"""`stepzoo plan-bench`: the tidy table holds one row per (integrator, query, run) with the
benchmark's measures and a summary per integrator, the OMPL logs go through OMPL's own
ompl_benchmark_statistics into a Planner Arena database with the same numbers, a bench cut
off resumes to the same table, a Dask cluster gives the same table, and no query id, folder
or start pose makes it write where it must not; the shipped street queries are the seeded
generator's output."""
import json
import shutil
import sqlite3
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stepzoo.cli import main
from stepzoo.results_folder import LOCK
from stepzoo.search.plan_bench import folder as bench_folder
from stepzoo.search.plan_bench import engine as bench_plans
from stepzoo.search.world.maps import from_array
from stepzoo.search.plans.path_metrics import distance_to_obstacles
from stepzoo.search.plans.schema import RUN_COLUMNS
from stepzoo.search.world.queries import STREET_QUERIES, load_queries, street_queries

COLUMNS = {"query", "run", "seed", "status", "time_s", "first_solution_s", "solution_s",
           "length_m", "cusps", "clearance_min_m", "clearance_mean_m", "curvature_max",
           "curvature_mean", "smoothness", "expansions", "method", "h", "integrator", "role"}
# Wall-clock measurements: they differ between any two runs of the same plan.
TIMED = ["time_s", "first_solution_s", "solution_s", "replay_s", "tracking_s", "progress"]
TUNED = """method = "rk4"
h = 0.05
[[runners_up]]
method = "ab4"
qualifies = false
reason = "no step qualifies"
[[runners_up]]
method = "heun"
h = 0.025
[[runners_up]]
method = "euler"
h = 0.01
"""
AROUND = {"id": "around", "map": "grid.npy", "cell_size": 0.5, "start": [4, 10, 0],
          "goal": [36, 10, 0]}
# The goal inside a closed room: no path, proved before any search (walled_off).
WALLED = {"id": "walled", "map": "grid.npy", "cell_size": 0.5, "start": [4, 10, 0],
          "goal": [33, 16.5, 0]}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A map of 40 x 20 m: a 4 x 10 m block between start and goal, and a closed room."""
    folder = tmp_path_factory.mktemp("bench")
    occupied = np.zeros((40, 80), bool)
    occupied[10:30, 36:44] = True
    occupied[26:40, 54:80] = True
    occupied[27:39, 55:79] = False
    np.save(folder / "grid.npy", occupied)
    (folder / "q.json").write_text(json.dumps([AROUND, WALLED]))
    (folder / "tuned.toml").write_text(TUNED)
    return folder


def bench(folder, out, *flags):
    return main(["plan-bench", str(folder / "q.json"), "--integrators-from",
                 str(folder / "tuned.toml"), "--runners-up", "1", "--out", str(out),
                 "--no-progress", *flags])


@pytest.fixture(scope="module")
def benched(folder):
    out = folder / "out"
    assert bench(folder, out, "--runs", "2") == 0
    return out


def untimed(out) -> pd.DataFrame:
    return pd.read_parquet(Path(out) / "runs.parquet").drop(columns=TIMED)


def test_the_table_has_a_row_per_integrator_query_and_run_with_every_measure(benched):
    table = pd.read_parquet(benched / "runs.parquet")
    assert COLUMNS <= set(table.columns) and len(table) == 8
    assert list(table.columns) == list(RUN_COLUMNS)
    # The choice and its first runner-up that qualifies (--runners-up 1), the same seeds.
    assert table["integrator"].tolist() == ["rk4:0.05"] * 4 + ["heun:0.025"] * 4
    assert table["role"].tolist() == ["tuned"] * 4 + ["runner-up"] * 4
    assert table["seed"].tolist() == [0, 1, 0, 1] * 2 and set(table["h"]) == {0.05, 0.025}
    around = table[table["query"] == "around"]
    assert (around["status"] == "exact").all()
    # Around the 4 m block from 16 m before it to 16 m behind: longer than the straight line.
    assert (around["length_m"] > 32).all() and (around["cusps"] == 0).all()
    assert (around["clearance_min_m"] > 0).all()
    assert (around["first_solution_s"] <= around["solution_s"]).all()
    assert (around["solution_s"] <= around["time_s"] + 1e-9).all()
    # Each exact plan replayed through the true models: close to its plan, not colliding.
    assert ((around["max_deviation_m"] > 0) & (around["max_deviation_m"] < 0.1)).all()
    assert (around["final_deviation_m"] <= around["max_deviation_m"]).all()
    assert (around["max_heading_deviation_rad"] > 0).all() and not around["collides"].any()
    assert (around["goal_distance_m"] < 0.1).all() and (around["replay_s"] > 0).all()
    # ... and tracked by the controller on the richer car, as plan.json's tracking block.
    assert (around["tracking_controller"] == "stanley").all()
    # Where it stops is where it strays most on these plans: the two measures computed apart
    # (the scan's distance to the path, the end's to its last row) agree to rounding.
    assert (around["tracking_max_deviation_m"] + 1e-9
            >= around["tracking_final_deviation_m"]).all()
    assert (around["tracking_s"] > 0).all() and around["tracking_collides"].notna().all()
    walled = table[table["query"] == "walled"]
    assert (walled["status"] == "no_path").all() and (walled["cause"] == "walled_off").all()
    assert walled["length_m"].isna().all() and walled["max_deviation_m"].isna().all()
    assert sorted(p.name for p in (benched / "parts").iterdir()) == sorted(
        f"{i:03d}-{q:05d}-{r:04d}.json" for i in range(2) for q in range(2) for r in range(2))


def test_the_summary_has_a_row_per_integrator_from_its_runs(benched):
    table = pd.read_parquet(benched / "runs.parquet")
    summary = pd.read_parquet(benched / "summary.parquet")
    assert summary["integrator"].tolist() == ["rk4:0.05", "heun:0.025"]
    assert summary["exact"].tolist() == [2, 2] and summary["exact_rate"].tolist() == [0.5, 0.5]
    for row in summary.itertuples():
        own = table[table["integrator"] == row.integrator]
        assert row.median_time_s == np.median(own["time_s"])
        assert row.median_length_m == np.median(own["length_m"].dropna())
        exact = own[own["solved"]]
        assert row.median_replay_deviation_m == np.median(exact["max_deviation_m"])
        assert row.max_replay_deviation_m == exact["max_deviation_m"].max()
        assert row.replay_collisions == exact["collides"].sum() == 0
    assert pd.read_csv(benched / "summary.csv")["integrator"].tolist() == \
        summary["integrator"].tolist()
    manifest = json.loads((benched / "manifest.json").read_text())
    assert manifest["written_by"] == "plan-bench" and manifest["complete"] is True


def test_ompl_statistics_script_reads_the_logs_into_a_planner_arena_database(benched):
    script = Path(sys.executable).with_name("ompl_benchmark_statistics")
    db = benched.parent / "bench.db"
    logs = sorted(str(p) for p in (benched / "ompl").glob("*.log"))
    subprocess.run([str(script), *logs, "-d", str(db)], check=True, capture_output=True)
    table = pd.read_parquet(benched / "runs.parquet")
    with sqlite3.connect(db) as con:
        names = [r[0] for r in con.execute("SELECT name FROM experiments ORDER BY id")]
        runs = con.execute("SELECT e.name, p.name, r.solved, r.status, r.time, "
                           "r.solution_length, r.seed FROM runs r JOIN experiments e ON "
                           "r.experimentid = e.id JOIN plannerConfigs p ON r.plannerid = p.id "
                           "ORDER BY r.id").fetchall()
        progress = con.execute("SELECT COUNT(*) FROM progress").fetchone()[0]
    # A planner per integrator in each query's log.
    assert names == ["around", "walled"]
    planners = ["stepzoo_PathFinder[rk4:0.05]"] * 2 + ["stepzoo_PathFinder[heun:0.025]"] * 2
    assert [r[1] for r in runs] == planners * 2
    ordered = table.sort_values(["query", "integrator"], key=lambda c: c.map(
        {"around": 0, "walled": 1, "rk4:0.05": 0, "heun:0.025": 1}), kind="stable")
    assert [r[0] for r in runs] == ordered["query"].tolist()
    assert [r[2] for r in runs] == [1] * 4 + [0] * 4
    assert [r[3] for r in runs] == [6] * 4 + [9] * 4  # OMPL: exact solution, infeasible
    np.testing.assert_allclose([r[4] for r in runs], ordered["time_s"])
    np.testing.assert_allclose([r[5] for r in runs[:4]], ordered["length_m"][:4])
    assert [r[6] for r in runs] == [0, 1] * 4 and progress >= 4


def test_one_integrator_keeps_the_planner_name_and_the_summary_line(folder, tmp_path, capsys):
    out = tmp_path / "one"
    assert main(["plan-bench", str(folder / "q.json"), "--integrator", "heun:0.025", "--out",
                 str(out), "--format", "json", "--no-progress"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["runs"] == 2 and printed["exact"] == 1 and printed["exact_rate"] == 0.5
    assert [i["integrator"] for i in printed["integrators"]] == ["heun:0.025"]
    log = (out / "ompl" / "around.log").read_text().splitlines()
    assert log[log.index("1 planners") + 1] == "stepzoo_PathFinder"


def test_distance_to_obstacles_is_the_brute_force_distance():
    rng = np.random.default_rng(4)
    occupied = rng.random((30, 25)) < 0.1
    omap = from_array(occupied, 1.5, (3.0, -2.0))
    xmin, xmax, ymin, ymax = omap.bounds()
    xy = rng.uniform([xmin, ymin], [xmax, ymax], (3000, 2))
    u, v = (xy[:, 0] - 3.0) / 1.5, (xy[:, 1] + 2.0) / 1.5
    truth = np.minimum.reduce([u, 25 - u, v, 30 - v])
    for r, c in np.argwhere(occupied):
        du = np.maximum.reduce([c - u, u - c - 1, 0 * u])
        dv = np.maximum.reduce([r - v, v - r - 1, 0 * v])
        truth = np.minimum(truth, np.hypot(du, dv))
    np.testing.assert_allclose(distance_to_obstacles(omap, xy), truth * 1.5, atol=1e-12)


def test_the_shipped_street_queries_are_the_seeded_generator_output():
    queries = json.loads(STREET_QUERIES.read_text())
    assert street_queries() == queries and len(load_queries(STREET_QUERIES)) == 48
    for q in queries:
        gap = np.hypot(*np.subtract(q["goal"][:2], q["start"][:2]))
        assert 30 <= gap <= 300


@pytest.mark.parametrize("text, complaint", [
    ("[]", "non-empty JSON list"), ("{", "cannot read"), ('[{"map": "x"}]', "map, start and goal"),
    ('[{"map": "x.npy", "cell_size": -1, "start": [0, 0, 0], "goal": [1, 1, 0]}]', "cell_size"),
    ('[{"map": "x.npy", "cell_size": 1, "start": [0, 0], "goal": [1, 1, 0]}]', "start of"),
    ('[{"map": "x.npy", "cell_size": 1, "start": [0, 0, 0], "goal": [1, 1, 0]}]', "not found"),
])
def test_bad_query_files_are_one_line_and_exit_status_two(tmp_path, capsys, text, complaint):
    (tmp_path / "q.json").write_text(text)
    assert main(["plan-bench", str(tmp_path / "q.json"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert complaint in err and err.count("\n") == 1 and not (tmp_path / "o").exists()


def one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("qid", ["../../x/pwned", "/tmp/stepzoo-pwned", "a\u0000b", "..",
                                 ".hidden", "a\\b", "", "a\u0085b", "a\u2028b"])
def test_a_query_id_that_cannot_name_a_file_inside_out_is_refused_before_planning(
        folder, tmp_path, capsys, qid):
    (tmp_path / "grid.npy").write_bytes((folder / "grid.npy").read_bytes())
    (tmp_path / "q.json").write_text(json.dumps([{**AROUND, "id": qid}]))
    out = tmp_path / "a" / "b" / "out"
    assert main(["plan-bench", str(tmp_path / "q.json"), "--out", str(out)]) == 2
    assert "id" in one_line(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grid.npy", "q.json"]
    assert not Path("/tmp/stepzoo-pwned.log").exists()


@pytest.mark.parametrize("pose", ["start", "goal"])
def test_a_pose_in_collision_is_refused_as_plan_refuses_it(folder, tmp_path, capsys, pose):
    (tmp_path / "q.json").write_text(json.dumps([
        AROUND, {**AROUND, "id": "in_block", pose: [20, 10, 0]}]))    # inside the block
    (tmp_path / "grid.npy").write_bytes((folder / "grid.npy").read_bytes())
    assert main(["plan-bench", str(tmp_path / "q.json"), "--out", str(tmp_path / "o")]) == 2
    err = one_line(capsys)
    assert f"query in_block: {pose} pose (20, 10, 0) is in collision" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("flags, complaint", [
    (["--integrator", "rk4"], "METHOD:H"), (["--integrator", "nope:0.1"], "unknown method"),
    (["--integrator", "rk4:-1"], "step"), (["--runners-up", "1"], "--integrators-from"),
    (["--max-hours", "1e-6"], "2 plans (2 queries x 1 integrators x 1 runs) of at most 20 s"),
    (["--resume"], "no plan-bench to continue"), (["--resume", "--overwrite"], "contradict"),
])
def test_bad_flags_are_one_line_and_exit_status_two(folder, tmp_path, capsys, flags, complaint):
    out = tmp_path / "o"
    assert main(["plan-bench", str(folder / "q.json"), "--out", str(out), *flags]) == 2
    assert complaint in one_line(capsys)
    assert not out.exists() or [p.name for p in out.iterdir()] == [LOCK]


@pytest.mark.parametrize("files, complaint, overwrite", [
    ({"chunks/x": "", "runs.parquet": "a sweep's"}, "results of `stepzoo sweep` (chunks)",
     "refused"),
    ({"manifest.json": '{"written_by": "sweep"}', "runs.parquet": "x"},
     "results of `stepzoo sweep` (runs.parquet)", "refused"),
    ({"manifest.json": '{"mine": 1}', "summary.csv": "a,b\n"},
     "did not write (manifest.json, summary.csv); give an empty or new --out, or pass "
     "--overwrite", "allowed"),
    ({"notes.txt": "mine"}, "did not write (notes.txt)", "allowed"),
])
def test_a_folder_holding_what_plan_bench_did_not_write_is_refused_and_kept(
        folder, tmp_path, capsys, files, complaint, overwrite):
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text(text)
    for flags in ([], ["--resume"], ["--overwrite"] * (overwrite == "refused")):
        assert bench(folder, tmp_path, *flags) == 2
        assert complaint in one_line(capsys)
    assert {str(p.relative_to(tmp_path)): p.read_text() for p in tmp_path.rglob("*")
            if p.is_file()} == files


def test_an_empty_out_is_refused(folder, capsys):
    assert main(["plan-bench", str(folder / "q.json"), "--out", ""]) == 2
    assert "--out is empty" in one_line(capsys)


def test_a_finished_bench_is_kept_unless_resumed_or_overwritten(folder, benched, capsys):
    def files():
        return {p: p.stat().st_mtime_ns for p in benched.rglob("*")
                if p.is_file() and p.name != LOCK}
    before = files()
    assert bench(folder, benched, "--runs", "2") == 2
    assert "--resume to continue it or --overwrite" in one_line(capsys)
    # Resumed with other settings: refused, nothing touched.
    assert bench(folder, benched, "--runs", "3", "--resume") == 2
    assert "other queries, integrators, runs" in one_line(capsys)
    assert files() == before


def test_resuming_after_the_map_file_was_replaced_is_refused(folder, benched, tmp_path,
                                                              capsys):
    """The same queries file naming a map file of other obstacles is another bench: --resume
    names the map in one line and touches nothing."""
    for name in ("q.json", "tuned.toml"):
        (tmp_path / name).write_bytes((folder / name).read_bytes())
    occupied = np.load(folder / "grid.npy")
    occupied[0:4, 60:64] = True             # a post in a corner, away from every pose
    np.save(tmp_path / "grid.npy", occupied)
    shutil.copytree(benched, tmp_path / "out")
    before = sorted((p.relative_to(tmp_path), p.read_bytes()) for p in
                    (tmp_path / "out").rglob("*") if p.is_file() and p.name != LOCK)
    assert bench(tmp_path, tmp_path / "out", "--runs", "2", "--resume") == 2
    assert "the map file grid.npy is not the one" in one_line(capsys)
    assert before == sorted((p.relative_to(tmp_path), p.read_bytes()) for p in
                            (tmp_path / "out").rglob("*") if p.is_file() and p.name != LOCK)


def test_a_second_bench_into_a_folder_in_use_is_refused(folder, tmp_path, capsys):
    import fcntl
    tmp_path.joinpath("o").mkdir()
    with open(tmp_path / "o" / LOCK, "w") as held:      # as a running plan-bench holds it
        fcntl.flock(held, fcntl.LOCK_EX)
        assert bench(folder, tmp_path / "o") == 2
        assert "in use by another stepzoo command" in one_line(capsys)
    assert [p.name for p in (tmp_path / "o").iterdir()] == [LOCK]


def test_overwrite_discards_a_bench_and_keeps_what_plan_bench_did_not_write(
        folder, benched, tmp_path):
    import shutil
    out = tmp_path / "o"
    shutil.copytree(benched, out)
    (out / "notes.txt").write_text("mine")
    (out / "parts" / "999-99999-9999.json").write_text("{}")   # not of this bench
    assert bench(folder, out, "--overwrite") == 0
    assert (out / "notes.txt").read_text() == "mine" and len(list((out / "parts").iterdir())) == 4


def test_a_bench_cut_off_resumes_to_the_same_table(folder, benched, tmp_path, monkeypatch,
                                                   capsys):
    saved, save = [], bench_folder.save

    def save_two_then_stop(out, name, row):
        save(out, name, row)
        saved.append(name)
        if len(saved) == 2:
            raise KeyboardInterrupt         # as Ctrl-C between two runs
    monkeypatch.setattr(bench_folder, "save", save_two_then_stop)
    out = tmp_path / "o"
    assert bench(folder, out) == 130
    assert "resume with --resume" in one_line(capsys)
    kept = {p.name: p.stat().st_ino for p in (out / "parts").iterdir()}
    # Interleaved: the first query with each integrator before the second query.
    assert sorted(kept) == ["000-00000-0000.json", "001-00000-0000.json"]
    assert not (out / "runs.parquet").exists()
    assert not json.loads((out / "manifest.json").read_text())["complete"]
    monkeypatch.setattr(bench_folder, "save", save)
    assert bench(folder, out, "--resume") == 0
    # The finished runs were kept, not planned again, and the table is the one a bench
    # without the cut writes (the first run of each of the whole bench's).
    assert {n: (out / "parts" / n).stat().st_ino for n in kept} == kept
    whole = untimed(benched)
    pd.testing.assert_frame_equal(untimed(out), whole[whole["run"] == 0].reset_index(drop=True))


def test_a_damaged_saved_run_or_summary_is_one_line(folder, benched, tiny_sweep, tmp_path,
                                                    capsys):
    """A part file that is not a saved run stops --resume in one line naming it, and a
    damaged or foreign summary stops the report's Figure 8 in one line: no traceback."""
    out = tmp_path / "o"
    shutil.copytree(benched, out)
    (out / "parts" / "000-00000-0000.json").write_text("[" * 50000)
    assert bench(folder, out, "--runs", "2", "--resume") == 2
    assert "000-00000-0000.json is not a run plan-bench saved" in one_line(capsys)
    summary = tmp_path / "s"
    shutil.copytree(benched, summary)
    (summary / "summary.parquet").write_bytes(b"not parquet")
    assert main(["report", str(tiny_sweep[1]), "--plan-bench", str(summary), "--out",
                 str(tmp_path / "r"), "--no-progress"]) == 2
    assert "summary.parquet is damaged" in one_line(capsys)
    pd.DataFrame({"integrator": ["rk4:0.05"]}).to_parquet(summary / "summary.parquet")
    assert main(["report", str(tiny_sweep[1]), "--plan-bench", str(summary), "--out",
                 str(tmp_path / "r"), "--no-progress"]) == 2
    assert "summary.parquet lacks method, h" in one_line(capsys)
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("change, words", [
    (lambda row: {}, "(it lacks query, map, cell_size and more)"),
    (lambda row: {**row, "time_s": "fast"}, "(its time_s must be a number, got 'fast')"),
    (lambda row: {**row, "solved": 1}, "(its solved must be true or false, got 1)"),
    (lambda row: {**row, "query": 3}, "(its query must be a string, got 3)"),
], ids=["empty object", "string for a number", "number for a flag", "number for a string"])
def test_a_saved_run_of_other_columns_or_kinds_stops_resume_in_one_line(folder, benched,
                                                                        tmp_path, capsys,
                                                                        change, words):
    """The third battery's tracebacks: a part file that is an empty object, or holds a
    string where a number belongs, passed as a run and failed in the tables."""
    out = tmp_path / "o"
    shutil.copytree(benched, out)
    part = out / "parts" / "000-00000-0000.json"
    part.write_text(json.dumps(change(json.loads(part.read_text()))))
    assert bench(folder, out, "--runs", "2", "--resume") == 2
    assert one_line(capsys).strip() == (
        f"stepzoo plan-bench: error: --resume: {part} is not a run plan-bench saved {words}; "
        "remove it to plan that run again")


_THREADS = []                     # the thread each task of the Dask test ran on
_ON_WORKER = bench_plans._plan_on_worker


def _spied_on_worker(task):
    """bench_plans._plan_on_worker, noting its thread (module-level: a task is pickled by name)."""
    _THREADS.append(threading.current_thread().name)
    return _ON_WORKER(task)


@pytest.mark.e2e       # a Dask cluster: make test-e2e
def test_a_bench_on_a_dask_cluster_gives_the_in_process_table(folder, benched, tmp_path,
                                                               monkeypatch):
    distributed = pytest.importorskip("dask.distributed")
    monkeypatch.setattr(bench_plans, "_plan_on_worker", _spied_on_worker)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        assert bench(folder, tmp_path / "o", "--runs", "2", "--scheduler",
                     cluster.scheduler_address) == 0
    pd.testing.assert_frame_equal(untimed(tmp_path / "o"), untimed(benched))
    # Every run was a task on the worker's thread, none planned here.
    assert len(_THREADS) == 8 and threading.current_thread().name not in _THREADS


def test_the_pareto_front_holds_the_points_no_other_beats_in_both():
    from stepzoo.reports.tradeoff import pareto
    x = [1.0, 2.0, 3.0, 5.0, np.nan, 2.0]
    y = [5.0, 2.0, 3.0, 1.0, 0.5, 2.0]
    # (3, 3) is beaten by (2, 2); a tie is on the front twice; NaN never is.
    assert pareto(x, y).tolist() == [True, True, False, True, False, True]


def test_the_report_draws_the_tradeoff_of_a_plan_bench_folder(tiny_sweep, benched, tmp_path):
    from stepzoo.reports.tradeoff import load_bench_summary, tradeoff_points
    points = tradeoff_points(load_bench_summary(benched))
    assert points["integrator"].tolist() == ["rk4:0.05", "heun:0.025"]
    assert points["tuned"].tolist() == [True, False] and points["paper"].tolist() == [True, False]
    assert points.attrs["margin_m"] == 0.1          # the planner's default margin
    faster = points["median_time_s"].idxmin()
    closer = points["median_replay_deviation_m"].idxmin()
    assert points["pareto"][faster] and points["pareto"][closer]
    out = tmp_path / "report"
    assert main(["report", str(tiny_sweep[1]), "--plan-bench", str(benched), "--out", str(out),
                 "--no-progress"]) == 0
    assert (out / "fig8_plan_tradeoff.png").stat().st_size > 0
    assert "fig8_plan_tradeoff.png" in (out / "index.html").read_text()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["plan_bench"] and "fig8_plan_tradeoff.png" in manifest["files"]
