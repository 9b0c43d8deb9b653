"""Plans whose course of (X, Y) a car can drive (issue 34, read from the path rows alone), the
planner's steering = "course_limited": the tree's own moves ramp the steer slowly enough that the dynamic bicycle's centre of gravity
reads within the steer-rate limit (an oracle in plain NumPy and SciPy), and the car changes
speed, or sets off on the connection, only with its wheel straight, so its course does not
kink where its slip would change at once."""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stepzoo.dynamics.models import model
from stepzoo.dynamics.vehicles import limits, vehicle
from stepzoo.search.planner import pathfinder
from stepzoo.search.planner.config import make_config
from stepzoo.search.planner.expansion import RATE_CHANGE, STRAIGHT_STEER
from stepzoo.search.planner.pathfinder import PathFinder
from stepzoo.search.planner.status import PlannerStatus
from stepzoo.search.planner.termination import expansions
from stepzoo.search.plans.path_metrics import TOLERANCE, drivability
from stepzoo.search.world.maps import from_array

CAR = vehicle()
L = CAR["Lf"] + CAR["Lr"]
LIMITS = limits()
RATE_LIMIT = TOLERANCE["steer_rate_radps"] * LIMITS["max_steer_rate"]   # [rad/s] 0.5


def search(vx=5.0, steering="course_limited"):
    """A search (not run) on an open 40 x 20 m map at 0.5 m/cell, the tree at `vx` [m/s]."""
    config = make_config(max_seconds=3600.0, steering=steering)
    finder = PathFinder(from_array(np.zeros((40, 80), bool), 0.5), config, None, vx)
    start, goal = np.array([4.0, 10.0, 0.0]), np.array([36.0, 10.0, 0.0])
    result = pathfinder.PlanResult(PlannerStatus.NO_PATH, "", start, goal, config.h, vx)
    return pathfinder.Search(finder, start, goal, None, np.random.default_rng(0), result,
                             expansions(1))


def dynamic_course_rate(knots, duration=0.8):
    """[rad/s] the implied steer rate read from the course of (X, Y) of the linear-tyre dynamic
    bicycle (paper eq. 4, plain NumPy) at 5 m/s driven by SciPy, its steer ramped linearly
    between `knots` [rad] `duration` [s] apart, from the lateral rest."""
    p = model("dynamic5").params(CAR["name"], 5.0)
    vx = 5.0
    times = duration * np.arange(len(knots))

    def f(t, x):
        _, _, psi, vy, r = x
        delta = np.interp(t, times, knots)
        front = p["Caf"] * (delta - (vy + p["Lf"] * r) / vx)
        rear = p["Car"] * (p["Lr"] * r - vy) / vx
        return [vx * math.cos(psi) - vy * math.sin(psi), vx * math.sin(psi) + vy * math.cos(psi),
                r, (front + rear) / p["m"] - vx * r, (p["Lf"] * front - p["Lr"] * rear) / p["Iz"]]
    ts = np.arange(0.0, times[-1], 0.002)
    sol = solve_ivp(f, (0.0, times[-1]), [0.0] * 5, t_eval=ts, rtol=1e-10, atol=1e-12,
                    max_step=0.005)
    rows = np.round(np.column_stack([ts, sol.y[:3].T]), 6)
    return drivability(rows, L, math.pi / 4, **LIMITS, heading="course")["max_steer_rate_radps"]


def test_the_trees_moves_ramp_the_steer_slow_enough_for_their_course_to_read_within_the_limit():
    """The oracle's course where its steer ramps up, holds, ramps down, holds, ramps up (each
    change of rate at most the rate, as RATE_CHANGE bounds the tree's moves) reads within
    1.25 x 0.4 rad/s at the tree's own moves' rate, not at the kinematic moves' rate
    (limit_fraction of 0.4 rad/s); and a ramp reversed at once reads over the limit even at
    the tree's rate."""
    finder = search().f
    slow, fast = finder.shooter.rate, finder.tight_shooter.rate
    assert slow == pytest.approx(0.6 * LIMITS["max_steer_rate"]) and fast > 1.3 * slow
    assert RATE_CHANGE == 1.0

    def held(rate):
        a = 0.8 * rate
        return [0, 0, a, a, 0, 0, a, a]
    assert dynamic_course_rate(held(fast)) > 1.1 * RATE_LIMIT
    assert dynamic_course_rate(held(slow)) <= 0.9 * RATE_LIMIT
    assert dynamic_course_rate([0, 0, 0.8 * slow, 0, 0.8 * slow, 0]) > 1.1 * RATE_LIMIT


def node(s, steer, steer0, tight, y=10.0):
    """A node added to the search's tree at (10, y) facing east, reached by a move of a whole
    shooting from steer0 to steer [rad] (a tight move if `tight`)."""
    edge = np.zeros((s.f.shooter.n_steps + 1, 5))
    return s.tree.add([edge], states=np.array([10.0, y, 0.0, 0.0, 0.0]), parent=0, g=5.0,
                      H=26.0, rest=26.0, guide=26.0, car=26.0, steer=steer, steer0=steer0,
                      direction=1, tight=tight)[0]


@pytest.mark.parametrize("rate,tight,kinematic,lo,hi", [
    (1.0, False, False, 0.0, 1.0),      # after the tree's ramp up: hold or go on up
    (-1.0, False, False, -1.0, 0.0),
    (0.5, False, True, -0.5, 1.5),      # a tight move after it: within the tree's rate of it
    (1.0, True, False, -1.0, 0.0),      # the tree's after a tight ramp at its full rate
    (0.5, True, False, -1.0, 0.5 * 0.8 / 0.6),  # ... and at half its rate
    (1.0, True, True, -0.8 / 0.6, 0.8 / 0.6)])  # a tight chain: its own rate only
def test_a_move_sets_its_steer_rate_near_its_nodes_edge(rate, tight, kinematic, lo, hi):
    """The rates [in units of the tree's rate limit] the moves from a node can set: the end
    steers of a fan over the whole range, bounded by Expander.rate_bounded."""
    s = search()
    tree_rate = s.f.shooter.rate
    edge_rate = rate * (s.f.tight_shooter.rate if tight else tree_rate)
    T = s.f.shooter.duration
    i = node(s, 0.0, -edge_rate * T, tight)
    shooter = s.f.tight_shooter if kinematic else s.f.shooter
    per = s.expander.per
    wanted = np.linspace(-3.0, 3.0, per) * tree_rate * T
    end = s.expander.rate_bounded([i], wanted, np.zeros(per), shooter)
    rates = end / (T * tree_rate)
    assert rates.min() == pytest.approx(max(lo, -shooter.rate / tree_rate))
    assert rates.max() == pytest.approx(min(hi, shooter.rate / tree_rate))


def test_the_tree_slows_down_from_its_own_move_only_with_the_wheel_straight():
    """Once the search widened, every node takes tight moves, but a node of the tree's own
    moves (the dynamic bicycle at 5 m/s) only with its steer within STRAIGHT_STEER."""
    s = search()
    node = np.array([[10.0, y, 0.0, 0.0, 0.0] for y in (4.0, 10.0, 16.0)])  # cells apart
    steers = [0.2, 0.5 * STRAIGHT_STEER, -0.2]
    rows = s.tree.add([None] * 3, states=node, parent=0, g=5.0, H=26.0, rest=26.0, guide=26.0,
                      car=26.0, steer=steers, steer0=steers, direction=1,
                      tight=[False, False, True])
    s.widened_at = len(s.tree)
    new = s.expander.expand(list(rows))
    slowed = {int(s.tree.parent[i]) for i in new if s.tree.tight[i]}
    assert slowed == {rows[1], rows[2]}


def test_a_node_with_the_wheel_straight_is_not_pruned_by_one_turned_in_its_steer_cell():
    """The straight wheel can change speed and connect, the turned one cannot: cells apart
    (rate_limited steering, which changes speed up to 0.3 rad, keeps them in one cell)."""
    s = search()
    state = np.array([10.2, 10.2, 0.1, 0.0, 0.0])
    assert s.cell(state, 1, 0.0) != s.cell(state, 1, 0.1)
    assert s.cell(state, 1, 0.0) == s.cell(state, 1, -0.5 * STRAIGHT_STEER)
    assert s.cell(state, 1, 0.1) == s.cell(state, 1, 0.12)
    shipped = search(steering="rate_limited")
    assert shipped.cell(state, 1, 0.0) == shipped.cell(state, 1, 0.1)


@pytest.mark.parametrize("steer", [0.1, 0.4])
def test_a_chain_of_tight_moves_straightens_the_wheel_as_fast_as_it_can(steer):
    """One of the fan of tight moves from a tight node ends at the steer nearest straight that
    one shooting reaches: 0 from 0.1 rad, 0.4 rad less the rate's reach from 0.4 rad."""
    s = search()
    node = s.tree.add([None], states=np.array([10.0, 10.0, 0.0, 0.0, 0.0]), parent=0, g=5.0,
                      H=26.0, rest=26.0, guide=26.0, car=26.0, steer=steer, steer0=steer,
                      direction=1, tight=True)
    shooter, _, fan, _ = s.expander.tight_request(s.expander.filled(list(node)))
    reach = shooter.rate * shooter.duration
    nearest = max(steer - reach, 0.0)
    assert np.min(np.abs(fan[:s.expander.per] - nearest)) == 0.0
    assert np.all(np.abs(fan[:s.expander.per] - steer) <= reach + 1e-12)


def test_a_stop_read_from_the_course_is_no_steer_rate_of_its_rounding():
    """The kinematic bicycle ramping its steer at 0.3 rad/s while it brakes from 2 m/s to a
    stop, stands a second and sets off again (SciPy), its rows every 12.6 ms with positions
    rounded to the micrometre as plan.json holds them: from the heading column the ramp's
    rate; from the course of (X, Y) too, where a window of a few millimetres' travel would
    read the rounding (0.42 rad/s) as a steer rate. Rows as files.path_rows fills them, no
    more than COURSE_MIN_TRAVEL_M apart."""
    from stepzoo.search.plans.files import ROW_SPACING_M
    from stepzoo.search.plans.path_metrics import COURSE_MIN_TRAVEL_M
    assert COURSE_MIN_TRAVEL_M >= ROW_SPACING_M
    rate, brake = 0.3, 1.5

    def f(t, x):
        v = 2.0 * (max(1 - t / brake, 0.0) + min(max(t - brake - 1.0, 0.0) / brake, 1.0))
        return [v * math.cos(x[2]), v * math.sin(x[2]), v * math.tan(0.2 + rate * t) / L]
    ts = np.arange(0.0, 2 * brake + 1.0, 0.0126)
    sol = solve_ivp(f, (0.0, ts[-1]), [0.0, 0.0, 0.0], t_eval=ts, rtol=1e-12, atol=1e-12,
                    max_step=0.005)
    rows = np.column_stack([ts, np.round(sol.y[:2].T, 6), sol.y[2]])
    assert drivability(rows, L, math.pi / 4, **LIMITS)["max_steer_rate_radps"] == \
        pytest.approx(rate, rel=0.02)
    by_course = drivability(rows, L, math.pi / 4, **LIMITS, heading="course")
    assert by_course["max_steer_rate_radps"] <= TOLERANCE["steer_rate_radps"] * rate


def test_a_plan_at_5_mps_is_drivable_read_from_its_course():
    """wall_between (the tree at 5 m/s round a wall, tight moves and the connection) with the
    course_limited planner: within every limit read from the course of its rear axle (the
    rows' (X, Y) Lr back along psi), as from its heading column. (Its centre of gravity's
    course is a rigid car's: it sets off aside where the wheel turns standing.)"""
    from stepzoo.search.planner.config import load_config, with_params
    from stepzoo.search.plans.files import path_rows
    from stepzoo.search.world.scenarios import load_scenario
    scenario = load_scenario("wall_between")
    config = with_params(load_config(), max_seconds=3600.0, steering="course_limited")
    finder = PathFinder(scenario.omap, config, scenario.vehicle, scenario.speed)
    result = finder.plan(scenario.start, scenario.goal, scenario.goal_speed)
    assert result.status == "exact", result.reason
    rows = path_rows(result, finder.vehicle)
    for heading in ("psi", "rear_axle"):
        d = drivability(rows, finder.wheelbase, math.pi / 4, **LIMITS, heading=heading,
                        lr=finder.vehicle["Lr"])
        assert d["drivable"], (heading, d)
