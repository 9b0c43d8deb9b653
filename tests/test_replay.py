"""Plan fidelity: a plan's controls, replayed by SciPy's solve_ivp on right-hand sides written
here from the paper's equations, give the replay block's deviation at every path row; a coarse step strays
farther than the tuned one on the same query; `collides` checks the replayed path densely."""
import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stepzoo import dynamics
from stepzoo.cli import main
from stepzoo.search.world.footprint import poses_collide
from stepzoo.search.world.maps import from_array
from stepzoo.search.planner.pathfinder import PathFinder
from stepzoo.search.plans.files import plan_record
from stepzoo.search.planner.config import load_config, make_config, with_params
from stepzoo.search.plans.replay import car_footprint, replay
from stepzoo.search.world.scenarios import Scenario, load_scenario

SCENARIO = "wall_between"  # 5 m/s, where rk4 at 0.05 s is stable (h lambda = -2.2 > -2.79)


def plan(config, steering="instant"):
    """(record, result, finder) of SCENARIO with `config` and `steering`, stopping at the first
    exact path."""
    scenario = load_scenario(SCENARIO)
    config = with_params(config, improve_expansions=0, max_seconds=3600.0, steering=steering)
    finder = PathFinder(scenario.omap, config, scenario.vehicle, scenario.speed)
    result = finder.plan(scenario.start, scenario.goal, scenario.goal_speed, seed=0)
    # Through JSON, as a user reads plan.json.
    record = json.loads(json.dumps(plan_record(result, scenario, config, finder.vehicle, 0, 0.0)))
    return record, result, finder


@pytest.fixture(scope="module")
def tuned():
    return plan(load_config())


@pytest.fixture(scope="module")
def coarse():
    return plan(make_config("rk4", 0.05))


@pytest.fixture(scope="module")
def ramped():
    """The default planner: its steer a state with a bounded rate, each edge a steer ramp."""
    return plan(load_config(), "rate_limited")


# --- the independent replay: the paper's equations (NOTES.md), SciPy's solver ----------------

def dynamic_bicycle(vx, steer, v, rate=0.0):
    """Paper eq. 4, linear tyres, Fxf = 0: x = [X, Y, psi, vy, r]; the steer ramps from `steer`
    at `rate` [rad/s]."""
    def f(t, x):
        _, _, psi, vy, r = x
        delta = steer + rate * t
        fyf = -v["Caf"] * ((vy + v["Lf"] * r) / vx - delta)
        fyr = -v["Car"] * (vy - v["Lr"] * r) / vx
        return [vx * np.cos(psi) - vy * np.sin(psi), vx * np.sin(psi) + vy * np.cos(psi), r,
                (fyf * np.cos(delta) + fyr) / v["m"] - vx * r,
                (v["Lf"] * fyf * np.cos(delta) - v["Lr"] * fyr) / v["Iz"]]
    return f


def kinematic_bicycle(steer, force, v, rate=0.0):
    """Paper eq. "pm": x = [X, Y, theta, v]; the steer ramps from `steer` at `rate` [rad/s]."""
    def f(t, x):
        delta = steer + rate * t
        return [x[3] * np.cos(x[2]), x[3] * np.sin(x[2]), x[3] * np.tan(delta) / v["wheelbase"],
                force / v["m"]]
    return f


def rigid_car(steer, force, v, rate=0.0):
    """The kinematic bicycle as a rigid car (Rajamani 2012, eqs. 2.26-2.29): x = [X, Y, psi,
    v], its centre of gravity moving at the slip beta = atan(Lr tan(delta) / L) beside its
    body psi, the body turning at v cos(beta) tan(delta) / L; the steer ramps from `steer` at
    `rate` [rad/s]."""
    def f(t, x):
        delta = steer + rate * t
        beta = math.atan(v["Lr"] * math.tan(delta) / v["wheelbase"])
        return [x[3] * math.cos(x[2] + beta), x[3] * math.sin(x[2] + beta),
                x[3] * math.cos(beta) * math.tan(delta) / v["wheelbase"], force / v["m"]]
    return f


KINEMATIC = {"kinematic": kinematic_bicycle, "kinematic_cg": rigid_car}


def independent_deviation(record):
    """Max distance [m] between the plan's path and its controls driven from the start, at
    every path row (the dense solution at the row's time)."""
    v = record["vehicle"]
    path = np.asarray(record["path"])
    replayed = np.full((len(path), 2), np.nan)
    replayed[path[:, 0] <= 0] = record["start"][:2]
    x = np.r_[record["start"], 0.0, 0.0]

    def solve(f, x0, t0, span):
        sol = solve_ivp(f, (0, span), x0, dense_output=True, rtol=1e-11, atol=1e-12)
        rows = (path[:, 0] > t0) & (path[:, 0] <= t0 + span + 1e-5) & np.isnan(replayed[:, 0])
        replayed[rows] = sol.sol(np.minimum(path[rows, 0] - t0, span))[:2].T
        return sol.y[:, -1]

    for seg in record["controls"]:
        u = seg["inputs"]
        if seg["model"] == "dynamic5":
            if "lateral0" in seg:
                x = np.r_[x[:3], seg["lateral0"]]
            x = solve(dynamic_bicycle(seg["vx"], u["delta"], v, u.get("delta_rate", 0.0)), x,
                      seg["t0"], seg["duration"])
        else:
            k = np.r_[x[:3], seg["v0"]]
            rates = u.get("delta_rate", [0.0] * len(u["F"]))
            for i, (delta, force, rate) in enumerate(zip(u["delta"], u["F"], rates)):
                k = solve(KINEMATIC[seg["model"]](delta, force, v, rate), k,
                          seg["t0"] + i * seg["dt"], seg["dt"])
            x = np.r_[k[:3], 0.0, 0.0]
    assert not np.isnan(replayed).any()
    return float(np.hypot(*(path[:, 1:3] - replayed).T).max())


def test_the_controls_replayed_independently_give_the_replay_blocks_deviation(tuned, coarse,
                                                                             ramped):
    for record, result, finder in (tuned, coarse, ramped):
        assert record["status"] == "exact"
        assert record["replay"]["max_deviation_m"] == pytest.approx(
            independent_deviation(record), abs=1e-3)
        # The planner's result object replays to the same block as its plan.json.
        direct = replay(result, finder.omap, finder.vehicle_footprint, vehicle=finder.vehicle)
        for key in ("max_deviation_m", "final_deviation_m", "goal_distance_m"):
            assert direct[key] == pytest.approx(record["replay"][key], abs=1e-5)
        assert direct["collides"] is record["replay"]["collides"] is False


def kinematic_moves():
    """Plans whose tree drives kinematic moves: a tight turn out of a yard's corner (as
    test_planner's yard) and reverse gear away from a wall the start faces."""
    yard = np.ones((64, 64), bool)
    yard[2:62, 2:62] = False
    facing = np.zeros((40, 60), bool)
    facing[:, -2:] = facing[:, :2] = facing[:2] = facing[-2:] = True
    for occupied, start, goal, vx, reverse in (
            (yard, (27.5, 16.0, 0.3), (8.0, 16.0, np.pi), 5.0, 0),
            (facing, (26.0, 10.0, 0.0), (8.0, 10.0, np.pi), 2.0, 1)):
        omap = from_array(occupied, 0.5)
        # The paper's instant steering turns out of the corner with tight moves at once.
        config = make_config(reverse=reverse, improve_expansions=0, max_seconds=3600.0,
                             steering="rate_limited" if reverse else "instant")
        finder = PathFinder(omap, config, None, vx)
        result = finder.plan(start, goal)
        scenario = Scenario("moves", "", omap, "generated", start, goal, None, None, vx)
        yield json.loads(json.dumps(plan_record(result, scenario, config, finder.vehicle, 0,
                                                0.0)))


def test_tight_moves_and_reverse_gear_replay_on_the_kinematic_bicycle():
    tight, reverse = kinematic_moves()
    assert [s["move"] for s in tight["controls"]][:2] == ["tight", "tree"]
    assert reverse["controls"][0]["move"] == "reverse"   # backing away from the wall
    assert reverse["controls"][0]["v0"] == -2.0
    for record in (tight, reverse):
        assert record["status"] == "exact"
        # The kinematic steps are rk4 at 0.02 s: a wrong speed sign or state hand-over
        # would put the replay metres off the path, not a fraction of a millimetre.
        assert record["replay"]["max_deviation_m"] < 1e-3
        assert record["replay"]["max_deviation_m"] == pytest.approx(
            independent_deviation(record), abs=1e-6)


def test_controls_and_vehicle_hold_what_a_user_needs_to_drive_them(tuned):
    record = tuned[0]
    assert {"m", "Iz", "Lf", "Lr", "Caf", "Car", "wheelbase"} <= set(record["vehicle"])
    *edges, conn = record["controls"]
    assert {seg["model"] for seg in edges} == {"dynamic5"}
    assert edges[0]["t0"] == 0.0 and {"duration", "vx", "inputs"} <= set(edges[0])
    assert conn["model"] == "kinematic" and conn["v0"] == record["speed"]
    assert len(conn["inputs"]["delta"]) == len(conn["inputs"]["F"]) == conn["steps"]
    # The segments follow each other in time and end when the path does.
    ends = [s["t0"] + (s["duration"] if s["model"] == "dynamic5" else s["dt"] * s["steps"])
            for s in record["controls"]]
    assert [s["t0"] for s in record["controls"][1:]] == pytest.approx(ends[:-1], abs=1e-12)
    assert ends[-1] == pytest.approx(record["path"][-1][0], abs=1e-5)


def test_a_coarse_step_strays_farther_from_its_plan_than_the_tuned_one(tuned, coarse):
    fine, rough = tuned[0]["replay"], coarse[0]["replay"]
    assert (coarse[0]["stats"]["method"], coarse[0]["stats"]["h"]) == ("rk4", 0.05)
    assert tuned[0]["stats"]["h"] < 0.05
    assert rough["max_deviation_m"] > 3 * fine["max_deviation_m"]
    assert rough["max_heading_deviation_rad"] > fine["max_heading_deviation_rad"]


# --- the dense collision check ------------------------------------------------------------

def wall_map():
    """40 x 20 m at 0.5 m/cell, a wall one cell thick at x = 20..20.5 m with a 4 m door at
    y = 14..18 m."""
    occupied = np.zeros((40, 80), bool)
    occupied[:28, 40] = True
    occupied[36:, 40] = True
    return from_array(occupied, 0.5)


def straight(y, delta=0.0):
    """A plan driving straight along y [m] from x = 5 to 35 m at 5 m/s, on nodes 10 m apart,
    under controls that steer `delta` [rad] (0: the path they drive)."""
    vehicle = dynamics.vehicle(None)
    return {"start": [5.0, y, 0.0], "goal": [35.0, y, 0.0], "params": {"margin": 0.1},
            "vehicle": {k: vehicle[k] for k in ("name", "length", "width", "m", "Iz", "Lf",
                                                 "Lr", "Caf", "Car")}
            | {"wheelbase": vehicle["Lf"] + vehicle["Lr"]},
            "controls": [{"model": "kinematic", "t0": 0.0, "dt": 2.0, "v0": 5.0, "steps": 3,
                          "inputs": {"delta": [delta] * 3, "F": [0.0] * 3}}],
            "path": [[2.0 * k, 5.0 + 10.0 * k, y, 0.0] for k in range(4)]}


def test_collides_is_a_dense_check_of_the_replayed_path():
    omap = wall_map()
    through_wall, through_door = straight(5.0), straight(16.0)
    nodes = np.array(through_wall["path"])[:, 1:]
    footprint = car_footprint(through_wall["vehicle"], 0.1)
    assert not poses_collide(omap, footprint, nodes).any()  # the nodes alone see no wall
    hit, miss = replay(through_wall, omap), replay(through_door, omap)
    assert hit["collides"] is True and miss["collides"] is False
    for block in (hit, miss):
        assert block["max_deviation_m"] < 1e-9 and block["goal_distance_m"] < 1e-9
    # Through the door the car's discs pass its posts at 2 m from the axis, less their radius.
    assert miss["clearance_min_m"] == pytest.approx(2.0 - footprint.radius, abs=1e-6)
    assert hit["clearance_min_m"] <= 0
    # Steering a little, the car drifts 1.3 m aside by the door and meets its post, where the
    # planned path through the door's middle is clear: the replayed path is the one checked.
    drift = replay(straight(16.0, 0.03), omap)
    assert drift["collides"] is True and drift["max_deviation_m"] > 1.0


def test_a_plan_without_a_path_has_a_replay_block_of_nulls():
    occupied = np.zeros((40, 80), bool)
    occupied[:, 40] = True  # a wall from edge to edge: the goal is walled off
    omap = from_array(occupied, 0.5)
    start, goal = (5.0, 10.0, 0.0), (35.0, 10.0, 0.0)
    config = load_config()
    finder = PathFinder(omap, config, None, 5.0)
    result = finder.plan(start, goal)
    scenario = Scenario("walled", "", omap, "generated", start, goal, None, None, 5.0)
    record = plan_record(result, scenario, config, finder.vehicle, 0, 0.0)
    assert (result.status, record["controls"]) == ("no_path", [])
    for block in (record["replay"], replay(result, omap, vehicle=finder.vehicle)):
        assert block["max_deviation_m"] is block["collides"] is block["goal_distance_m"] is None


def test_plan_prints_the_replay_deviation_on_its_line(tmp_path, capsys):
    assert main(["plan", SCENARIO, "--out", str(tmp_path)]) == 0
    record = json.loads((tmp_path / "plan.json").read_text())
    line = capsys.readouterr().out
    assert f"replay deviation {record['replay']['max_deviation_m']:.3g} m" in line


REPLAY_IN_FLOAT32 = """
import json, sys
import jax
from stepzoo.search.world.maps import from_array
from stepzoo.search.plans.replay import replay
record = json.load(open(sys.argv[1]))
omap = from_array(json.load(open(sys.argv[2])), 0.5, (0.0, 0.0))
block = replay(record, omap)
print(json.dumps([jax.config.jax_enable_x64, block["max_deviation_m"], block["collides"]]))
"""


def test_a_caller_in_float32_gets_the_float64_replay_and_keeps_its_setting(tuned, tmp_path):
    """The library leaves the caller's precision alone: a process that never turned float64
    on replays a plan to the same deviation, bit for bit, and is still in float32 after."""
    import subprocess
    import sys
    record, result, finder = tuned
    (tmp_path / "plan.json").write_text(json.dumps(record))
    (tmp_path / "map.json").write_text(json.dumps(finder.omap.occupied.astype(int).tolist()))
    assert finder.omap.resolution == 0.5 and tuple(finder.omap.origin) == (0.0, 0.0)
    proc = subprocess.run([sys.executable, "-c", REPLAY_IN_FLOAT32, tmp_path / "plan.json",
                           tmp_path / "map.json"], capture_output=True, text=True, timeout=300,
                          env={k: v for k, v in __import__("os").environ.items()
                               if not k.startswith("JAX_")})
    assert proc.returncode == 0, proc.stderr[-2000:]
    x64, deviation, collides = json.loads(proc.stdout.strip().splitlines()[-1])
    assert x64 is False
    assert deviation == record["replay"]["max_deviation_m"] and collides is False


def test_a_plan_result_replays_to_its_plan_json_block(tuned):
    """plan-bench replays the planner's result, plan.json its record: the same block (to the
    rounding of plan.json's path rows: 1e-6 m, and 1e-6 s in the time at which each row is
    compared, a few micrometres at 5 m/s), the disc cover sized with the planner's margin in
    both."""
    record, result, finder = tuned
    block = replay(result, finder.omap, vehicle=finder.vehicle,
                   margin=finder.config.params.margin)
    for key in ("collides", "nodes", "rows", "samples"):
        assert block[key] == record["replay"][key], key
    for key in ("max_deviation_m", "final_deviation_m", "max_heading_deviation_rad",
                "clearance_min_m", "goal_distance_m"):
        assert block[key] == pytest.approx(record["replay"][key], abs=1e-5), key


def test_path_rows_between_the_connections_nodes_are_what_its_model_drives(tuned):
    """Between two nodes of the connection the path rows are the kinematic bicycle driven
    from the earlier node under that interval's inputs (SciPy here), to plan.json's rounding;
    the chords between the nodes, which the rows were, stray millimetres from it."""
    record = tuned[0]
    conn, v = record["controls"][-1], record["vehicle"]
    assert conn["move"] == "connection"
    path = np.asarray(record["path"])
    u = conn["inputs"]
    rates = u.get("delta_rate", [0.0] * conn["steps"])
    speed = conn["v0"] + np.r_[0.0, np.cumsum(u["F"])] / v["m"] * conn["dt"]
    worst, chord = 0.0, 0.0
    for i in range(conn["steps"]):
        t0 = conn["t0"] + i * conn["dt"]
        node = np.argmin(np.abs(path[:, 0] - t0))
        end = np.argmin(np.abs(path[:, 0] - (t0 + conn["dt"])))
        assert abs(path[node, 0] - t0) < 1e-5 and end > node
        inside = path[node + 1:end]
        if not len(inside):
            continue
        sol = solve_ivp(kinematic_bicycle(u["delta"][i], u["F"][i], v, rates[i]),
                        (0, conn["dt"]), np.r_[path[node, 1:4], speed[i]], dense_output=True,
                        rtol=1e-11, atol=1e-12)
        drives = sol.sol(inside[:, 0] - t0)[:2].T
        worst = max(worst, np.hypot(*(inside[:, 1:3] - drives).T).max())
        frac = (inside[:, 0] - t0) / conn["dt"]
        straight = path[node, 1:3] + frac[:, None] * (path[end, 1:3] - path[node, 1:3])
        chord = max(chord, np.hypot(*(straight - drives).T).max())
    assert worst < 1e-5
    assert chord > 1e-3


def test_a_reversing_rigid_car_rolls_its_rear_axle_on_the_circle_of_its_steer():
    """Setting off backwards at a steady steer (rate-limited: the rigid car, its steer a
    state), the replayed poses are the car's centre of gravity and body: the rear axle, Lr
    behind it along the body, stays on the circle of radius L / tan(delta) about the turn's
    centre (it rolls without sliding), and the body turns at v cos(beta) tan(delta) / L."""
    from stepzoo.search.plans.replay import drive
    vehicle = {"m": 1093.3, "Iz": 1791.6, "Lf": 1.156, "Lr": 1.422, "Caf": 129627.6,
               "Car": 105379.4}
    L = vehicle["Lf"] + vehicle["Lr"]
    n, dt, v, steer = 40, 0.02, -2.0, 0.3
    seg = {"model": "kinematic_cg", "t0": 0.0, "dt": dt, "v0": v, "move": "reverse",
           "steps": n, "inputs": {"delta": [steer] * n, "F": [0.0] * n, "delta_rate": [0.0] * n}}
    _, samples = drive([seg], (3.0, 4.0, 0.5), vehicle)
    t = n * dt * np.arange(len(samples)) / (len(samples) - 1)
    beta = math.atan(vehicle["Lr"] * math.tan(steer) / L)
    assert np.abs(samples[:, 2] - (0.5 + v * math.cos(beta) * math.tan(steer) / L * t)).max() \
        < 1e-8
    rear = samples[:, :2] - vehicle["Lr"] * np.column_stack([np.cos(samples[:, 2]),
                                                              np.sin(samples[:, 2])])
    radius = L / math.tan(steer)
    centre = rear[0] + radius * np.array([-math.sin(0.5), math.cos(0.5)])
    assert np.abs(np.hypot(*(rear - centre).T) - radius).max() < 1e-8
    # The rear axle rolls at v cos(beta): the chord of its arc.
    arc = abs(v) * math.cos(beta) * n * dt
    assert np.hypot(*(rear[-1] - rear[0])) == pytest.approx(2 * radius * math.sin(
        arc / (2 * radius)), rel=1e-9)


def test_a_car_backing_out_beside_a_wall_clears_it_as_the_planner_checked():
    """Backing out 0.4 m at steer 0.3 rad beside a wall at y = 5 m, the car (centre y = 4 m,
    discs of radius 0.89 m) keeps 0.11 m at the start and less as its front swings towards
    the wall; the least clearance is the one measured on poses of the rigid car integrated
    here (SciPy, rigid_car). Had its centre of gravity moved along the body's heading plus
    the slip while the body stood (the planner's former kinematic bicycle, whose heading was
    that of its centre of gravity's path), its front would have swung 0.3 m into the wall."""
    from stepzoo.search.plans.replay import drive, safety
    vehicle = dynamics.vehicle(None)
    veh = {k: vehicle[k] for k in ("name", "length", "width", "m", "Iz", "Lf", "Lr", "Caf",
                                   "Car")} | {"wheelbase": vehicle["Lf"] + vehicle["Lr"]}
    occupied = np.zeros((200, 400), bool)  # 20 x 10 m at 0.05 m/cell
    occupied[100:102] = True               # the wall, y = 5.0..5.1 m
    omap = from_array(occupied, 0.05)
    n, dt = 10, 0.02
    seg = {"model": "kinematic_cg", "t0": 0.0, "dt": dt, "v0": -2.0, "steps": n,
           "move": "reverse",
           "inputs": {"delta": [0.3] * n, "F": [0.0] * n, "delta_rate": [0.0] * n}}
    start = [10.0, 4.0, 0.0]
    poses, samples = drive([seg], start, veh, dt * np.arange(n + 1))
    record = {"start": start, "goal": list(samples[-1]), "params": {"margin": 0.1},
              "vehicle": veh, "controls": [seg],
              "path": np.column_stack([dt * np.arange(n + 1), poses]).tolist()}
    block = replay(record, omap)
    assert block["collides"] is False
    sol = solve_ivp(rigid_car(0.3, 0.0, veh), (0, n * dt), [*start, -2.0], rtol=1e-11,
                    atol=1e-12, t_eval=np.linspace(0, n * dt, 201))
    _, least = safety(omap, car_footprint(veh, 0.1), sol.y[:3].T)
    assert block["clearance_min_m"] == pytest.approx(least, abs=2e-3)
    assert 0.05 < block["clearance_min_m"] < 0.11
    slipped = samples.copy()
    slipped[:, 2] += math.asin(veh["Lr"] * math.tan(0.3) / veh["wheelbase"])
    assert safety(omap, car_footprint(veh, 0.1), slipped)[0]
