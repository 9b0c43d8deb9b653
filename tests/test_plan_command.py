"""`stepzoo plan`: the files and keys other modules read (plan.json, plan.png, map.npy, the
--all summary), scenario files and map queries, the planner config, and one clear line with
exit status 2 and nothing written for every bad input."""
import csv
import json

import numpy as np
import pytest
from PIL import Image

from stepzoo.cli import main
from stepzoo.errors import UsageError
from stepzoo.search.planner.config import DEFAULT_CONFIG, PlannerParams, load_config
from stepzoo.search.world.scenarios import builtin_names, load_scenario

STATS = {"expansions", "nodes", "search_s", "connect_s", "path_length_m", "connect_tf_s",
         "seed", "method", "h"}
SUMMARY = ["scenario", "status", "expansions", "nodes", "search_s", "connect_s",
           "path_length_m", "connect_tf_s", "max_deviation_m", "drivable"]


def run(*argv):
    return main(["plan", *map(str, argv)])


def read(folder):
    return json.loads((folder / "plan.json").read_text())


def grid_files(tmp_path):
    """A 40 x 20 m grid at 0.5 m with a block in the middle, and a scenario file using it."""
    occupied = np.zeros((40, 80), bool)
    occupied[10:30, 36:44] = True  # x 18..22 m, y 5..15 m
    np.save(tmp_path / "grid.npy", occupied)
    (tmp_path / "query.toml").write_text(
        'map = "grid.npy"\ncell_size = 0.5\nvehicle = "ge2021"\nspeed = 4.0\n'
        "start = [4.0, 10.0, 0.0]\ngoal = [36.0, 10.0, 0.0, 2.0]\n")
    return tmp_path / "grid.npy", tmp_path / "query.toml"


@pytest.fixture(scope="module")
def unclocked(tmp_path_factory):
    """The shipped planner config with a budget the clock never cuts (a few anytime
    improvements, up to 10 minutes): its plans are the same on a loaded machine."""
    shipped = load_config()
    config = tmp_path_factory.mktemp("config") / "tuned.toml"
    config.write_text(f'method = "{shipped.method}"\nh = {shipped.h!r}\nwhy = "a test"\n'
                      "pos_tol_m = 0.1\n[planner]\nimprove_expansions = 30\n"
                      "max_seconds = 600.0\n")
    return config


@pytest.fixture(scope="module")
def planned(tmp_path_factory, unclocked):
    out = tmp_path_factory.mktemp("plan")
    assert run("obstacles_between", "--config", unclocked, "--out", out) == 0
    return out


def test_plan_json_holds_the_contract(planned):
    record = read(planned)
    scenario = load_scenario("obstacles_between")
    assert record["status"] == "exact" and record["reason"]
    assert STATS <= set(record["stats"]) and record["stats"]["seed"] == 0
    shipped = load_config()
    assert (record["stats"]["method"], record["stats"]["h"]) == (shipped.method, shipped.h)
    assert record["vehicle"]["length"] == 4.508 and record["vehicle"]["width"] == 1.61
    assert record["start"] == list(scenario.start) and record["goal"] == list(scenario.goal)
    assert set(record["params"]) == set(PlannerParams.model_fields)
    path = np.array(record["path"])
    assert path.shape[1] == 4
    assert np.hypot(*np.diff(path[:, 1:3], axis=0).T).max() <= 0.1
    assert np.all(np.diff(path[:, 0]) >= 0) and path[0, 0] == 0.0
    np.testing.assert_allclose(path[0, 1:], scenario.start, atol=1e-12)
    np.testing.assert_allclose(path[-1, 1:3], scenario.goal[:2], atol=1e-5)
    length = np.hypot(*np.diff(path[:, 1:3], axis=0).T).sum()
    assert length == pytest.approx(record["stats"]["path_length_m"], rel=1e-3)
    assert record["stats"]["connect_tf_s"] > 0
    assert record["tree"] and all(len(pt) == 2 for edge in record["tree"] for pt in edge)


def test_map_npy_is_the_grid_with_row_zero_at_the_bottom(planned):
    record = read(planned)
    grid = np.load(planned / record["map"]["file"])
    assert grid.dtype == bool
    np.testing.assert_array_equal(grid, load_scenario("obstacles_between").omap.occupied)
    res, (x0, y0) = record["map"]["resolution"], record["map"]["origin"]

    def cell(x, y):
        return grid[int((y - y0) // res), int((x - x0) // res)]
    # The blocks at x = 44..47 m span y = 6..17 and 24..34 m: not mirror images about the
    # middle, so a flipped grid reads y = 16.5 m as free.
    assert cell(45.5, 16.5) and not cell(45.5, 23.5)


def test_plan_png_shows_black_obstacles_a_blue_tree_and_a_red_path(planned):
    pixels = np.asarray(Image.open(planned / "plan.png").convert("RGB")).astype(int)
    r, g, b = pixels[..., 0], pixels[..., 1], pixels[..., 2]
    assert np.sum((r > 200) & (g < 60) & (b < 60)) > 200     # red path
    assert np.sum((b > 200) & (r < 60) & (g < 60)) > 200     # blue tree
    assert np.sum((r < 30) & (g < 30) & (b < 30)) > 2000     # black obstacles


def test_the_same_command_gives_the_same_path(planned, unclocked, tmp_path):
    assert run("obstacles_between", "--config", unclocked, "--out", tmp_path) == 0
    assert read(tmp_path)["stats"]["budget_bound"] is None
    assert read(tmp_path)["path"] == read(planned)["path"]
    assert read(tmp_path)["tree"] == read(planned)["tree"]


@pytest.mark.e2e       # every built-in scenario planned: make test-e2e
def test_all_plans_every_scenario_and_writes_the_summary(tmp_path, capsys):
    assert run("--all", "--out", tmp_path) == 0
    printed = capsys.readouterr().out
    with open(tmp_path / "summary.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == SUMMARY
    assert [r["scenario"] for r in rows] == builtin_names()
    assert json.loads((tmp_path / "summary.json").read_text())[0]["scenario"] == rows[0]["scenario"]
    for row in rows:
        folder = tmp_path / row["scenario"]
        assert {p.name for p in folder.iterdir()} == {"plan.json", "plan.png", "map.npy"}
        assert row["status"] == read(folder)["status"] == "exact"
        assert float(row["search_s"]) > 0 and float(row["connect_s"]) > 0
        assert float(row["max_deviation_m"]) == read(folder)["replay"]["max_deviation_m"]
        assert row["scenario"] in printed


def test_a_scenario_file_names_its_map_vehicle_and_goal_speed(tmp_path):
    _, toml = grid_files(tmp_path)
    assert run(toml, "--out", tmp_path / "out") == 0
    record = read(tmp_path / "out")
    assert record["status"] == "exact"
    assert record["vehicle"]["name"] == "ge2021" and record["goal_speed"] == 2.0
    assert record["speed"] == 4.0


def test_a_map_query_plans_and_a_walled_off_goal_is_written_as_no_path_exit_1(tmp_path):
    grid, _ = grid_files(tmp_path)
    assert run("--map", grid, "--cell-size", 0.5, "--start", "4,10,0", "--goal", "36,10,0",
               "--speed", 6, "--seed", 3, "--out", tmp_path / "free") == 0
    record = read(tmp_path / "free")
    assert (record["status"], record["stats"]["seed"], record["speed"]) == ("exact", 3, 6.0)
    walled = np.load(grid)
    walled[:, 36:44] = True
    np.save(tmp_path / "walled.npy", walled)
    assert run("--map", tmp_path / "walled.npy", "--cell-size", 0.5, "--start", "4,10,0",
               "--goal", "36,10,0", "--out", tmp_path / "walled") == 1
    record = read(tmp_path / "walled")
    assert (record["status"], record["cause"], record["path"]) == ("no_path", "walled_off", [])


def test_a_config_sets_the_integrator_and_overrides_params(tmp_path):
    config = tmp_path / "tuned.toml"
    config.write_text('method = "rk3"\nh = 0.025\nwhy = "a test"\npos_tol_m = 0.01\n'
                      '[[runners_up]]\nmethod = "rk4"\nh = 0.02\n[planner]\nmindist = 7.5\n'
                      'improve_expansions = 0\n')
    assert run("wall_between", "--config", config, "--out", tmp_path / "out") == 0
    record = read(tmp_path / "out")
    assert (record["stats"]["method"], record["stats"]["h"]) == ("rk3", 0.025)
    assert record["params"]["mindist"] == 7.5 and record["params"]["improve_expansions"] == 0
    assert record["config"]["provenance"] == "a test"


def test_a_finished_batch_is_kept_only_for_the_same_planner_seed_and_intact_files(tmp_path):
    """`stepzoo run` run again keeps its plans (workflows.plan.finished) only where the folder
    holds every scenario planned with the same method, h, parameters and seed, its files
    intact; anything else is planned again."""
    import shutil

    from stepzoo.workflows import plan as plan_cmd
    config = tmp_path / "tuned.toml"
    config.write_text('method = "rk4"\nh = 0.02\nwhy = "a test"\npos_tol_m = 0.1\n'
                      "[planner]\nimprove_expansions = 0\n")
    other = tmp_path / "other.toml"
    other.write_text(config.read_text().replace("improve_expansions = 0",
                                                "improve_expansions = 1"))
    scenarios = [load_scenario("wall_between")]
    out = tmp_path / "plans"
    records = plan_cmd.plan(scenarios, out, config, 3, batch=True)
    planned = json.loads(json.dumps(records))
    assert plan_cmd.finished(out, load_config(config), 3, scenarios) == planned
    assert plan_cmd.finished(out, load_config(config), 4, scenarios) is None
    assert plan_cmd.finished(out, load_config(other), 3, scenarios) is None
    assert plan_cmd.finished(out, load_config(config), 3,
                             [*scenarios, load_scenario("street")]) is None
    damaged = tmp_path / "damaged"
    shutil.copytree(out, damaged)
    (damaged / "wall_between" / "plan.json").write_text('{"status": "ex')
    assert plan_cmd.finished(damaged, load_config(config), 3, scenarios) is None
    (damaged / "wall_between" / "plan.json").write_bytes(
        (out / "wall_between" / "plan.json").read_bytes())
    (damaged / "wall_between" / "map.npy").unlink()
    assert plan_cmd.finished(damaged, load_config(config), 3, scenarios) is None


def test_the_shipped_default_is_a_tune_output_stable_across_the_default_envelope():
    """The shipped (method, h) came from `stepzoo tune` on the default envelope: it says so,
    and it is inside its method's stability limit, with the tuning margin, at the stiffest
    corner of that envelope (2 m/s, every steer)."""
    import tomllib

    from stepzoo import dynamics
    from stepzoo.dynamics.linear import lateral_eigenvalues
    from stepzoo.integrators import method
    from stepzoo.integrators.stability import max_stable_step
    config = load_config()
    assert config.source == str(DEFAULT_CONFIG) and "default envelope" in config.provenance
    raw = tomllib.loads(DEFAULT_CONFIG.read_text())
    assert len(raw["sweep_config_sha256"]) == 64 and raw["why"].startswith(config.method)
    p = dynamics.physical(None)
    for delta in (-0.785, 0.0, 0.785):
        h_max = max_stable_step(method(config.method), lateral_eigenvalues(2.0, delta, p))
        assert config.h <= (1 - raw["margin"]) * h_max * 1.01


@pytest.mark.parametrize("text, words", [
    ('method = "rk99"\nh = 0.02\n', "unknown integration method"),
    ('method = "rk4"\nh = 0.0\n', "h must be"),
    ('method = "rk4"\nh = -1\n', "h must be"),
    ('h = 0.02\n', "lacks method"),
    ('method = "rk4"\nh = 0.02\n[planner]\nn_arc = 0\n', "n_arc"),
    ('method = "rk4"\nh = 0.02\n[planner]\nmindst = 3\n', "unknown key 'mindst'"),
    ('method = rk4\n', "not valid TOML"),
])
def test_a_bad_config_is_a_usage_error(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(UsageError, match=words):
        load_config(path)


BAD = {
    "unknown scenario": ["nowhere"],
    "nothing to plan": [],
    "two things to plan": ["street", "--all"],
    "malformed start": ["--map", "{grid}", "--cell-size", "0.5", "--start", "1,2",
                        "--goal", "36,10,0"],
    "start not numbers": ["--map", "{grid}", "--cell-size", "0.5", "--start", "a,b,c",
                          "--goal", "36,10,0"],
    "goal without map": ["street", "--goal", "1,2,3"],
    "missing map file": ["--map", "{tmp}/absent.map", "--cell-size", "1", "--start", "4,10,0",
                         "--goal", "36,10,0"],
    "map needs a cell size": ["--map", "{grid}", "--start", "4,10,0", "--goal", "36,10,0"],
    "start off the map": ["--map", "{grid}", "--cell-size", "0.5", "--start=-4,10,0",
                          "--goal", "36,10,0"],
    "goal off the map": ["--map", "{grid}", "--cell-size", "0.5", "--start", "4,10,0",
                         "--goal", "36,50,0"],
    "start in an obstacle": ["--map", "{grid}", "--cell-size", "0.5", "--start", "20,10,0",
                             "--goal", "36,10,0"],
    "negative speed": ["street", "--speed", "-3"],
    "missing config": ["street", "--config", "{tmp}/absent.toml"],
    "negative seed": ["street", "--seed", "-1"],
}


@pytest.mark.parametrize("case", BAD)
def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, case):
    grid, _ = grid_files(tmp_path)
    out = tmp_path / "out"
    assert run(*[a.format(grid=grid, tmp=tmp_path) for a in BAD[case]], "--out", out) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "error" in err
    assert not out.exists()
