"""`stepzoo plan-bench`: the tidy table holds one row per run with the benchmark's measures,
the OMPL logs go through OMPL's own ompl_benchmark_statistics into a Planner Arena database
with the same numbers, and the shipped street queries are the seeded generator's output."""
import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stepzoo.bench.cli import main
from stepzoo.search.maps import from_array
from stepzoo.search.path_metrics import distance_to_obstacles
from stepzoo.search.queries import STREET_QUERIES, load_queries, street_queries

COLUMNS = {"query", "run", "seed", "status", "time_s", "first_solution_s", "solution_s",
           "length_m", "cusps", "clearance_min_m", "clearance_mean_m", "curvature_max",
           "curvature_mean", "smoothness", "expansions", "method", "h"}


@pytest.fixture(scope="module")
def benched(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bench")
    occupied = np.zeros((40, 80), bool)
    occupied[10:30, 36:44] = True  # a block between start and goal
    np.save(folder / "grid.npy", occupied)
    queries = [{"id": "around", "map": "grid.npy", "cell_size": 0.5, "start": [4, 10, 0],
                "goal": [36, 10, 0]},
               {"id": "blocked", "map": "grid.npy", "cell_size": 0.5, "start": [20, 10, 0],  # in the block
                "goal": [36, 10, 0]}]
    (folder / "q.json").write_text(json.dumps(queries))
    out = folder / "out"
    assert main(["plan-bench", str(folder / "q.json"), "--runs", "2", "--out", str(out)]) == 0
    return out


def test_the_table_has_a_row_per_run_with_every_measure(benched):
    table = pd.read_parquet(benched / "runs.parquet")
    assert COLUMNS <= set(table.columns) and len(table) == 4
    assert table["seed"].tolist() == [0, 1, 0, 1]
    around = table[table["query"] == "around"]
    assert (around["status"] == "exact").all()
    # Around the 4 m block from 16 m before it to 16 m behind: longer than the straight line.
    assert (around["length_m"] > 32).all() and (around["cusps"] == 0).all()
    assert (around["clearance_min_m"] > 0).all()
    assert (around["first_solution_s"] <= around["solution_s"]).all()
    assert (around["solution_s"] <= around["time_s"] + 1e-9).all()
    blocked = table[table["query"] == "blocked"]
    assert (blocked["status"] == "no_path").all() and blocked["length_m"].isna().all()


def test_ompl_statistics_script_reads_the_logs_into_a_planner_arena_database(benched):
    script = Path(sys.executable).with_name("ompl_benchmark_statistics")
    db = benched / "bench.db"
    logs = sorted(str(p) for p in (benched / "ompl").glob("*.log"))
    subprocess.run([str(script), *logs, "-d", str(db)], check=True, capture_output=True)
    table = pd.read_parquet(benched / "runs.parquet")
    with sqlite3.connect(db) as con:
        names = [r[0] for r in con.execute("SELECT name FROM experiments ORDER BY id")]
        runs = con.execute("SELECT e.name, r.solved, r.status, r.time, r.solution_length, "
                           "r.solution_cusps, r.seed FROM runs r JOIN experiments e ON "
                           "r.experimentid = e.id ORDER BY r.id").fetchall()
        planners = [r[0] for r in con.execute("SELECT name FROM plannerConfigs")]
        progress = con.execute("SELECT COUNT(*) FROM progress").fetchone()[0]
        best = con.execute("SELECT avg_solved FROM bestPlannerConfigs").fetchall()
    assert names == ["around", "blocked"] and planners == ["stepzoo_PathFinder"]
    assert [r[0] for r in runs] == table["query"].tolist()
    assert [r[1] for r in runs] == [1, 1, 0, 0]
    assert [r[2] for r in runs] == [6, 6, 1, 1]   # OMPL: exact solution, invalid start
    np.testing.assert_allclose([r[3] for r in runs], table["time_s"])
    np.testing.assert_allclose([r[4] for r in runs[:2]], table["length_m"][:2])
    assert [r[4] for r in runs[2:]] == [None, None] and [r[6] for r in runs] == [0, 1, 0, 1]
    assert progress >= 2 and best == [(0.5,)]


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
