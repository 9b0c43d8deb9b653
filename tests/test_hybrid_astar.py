"""The Hybrid A* baseline (search/baselines/hybrid_astar.py): in an empty map its path is the
Dubins optimum, with reverse gear the Reeds-Shepp one (the shot finds it), and a goal just
behind is reached backwards; around a wall its path is collision-free by an independent dense
check with the map's exact distance and curves no tighter than the car can; it is
deterministic; a goal in an obstacle, walled off, or beyond the budget gives no path."""
import math

import numpy as np
import pytest

from stepzoo.search.baselines.hybrid_astar import HybridAStar, HybridAStarParams
from stepzoo.search.planner.config import load_config
from stepzoo.search.planner.pathfinder import PathFinder
from stepzoo.search.planner.status import Cause, PlannerStatus
from stepzoo.search.plans.path_metrics import TOLERANCE, distance_to_obstacles, drivability
from stepzoo.search.plans.replay import car_footprint
from stepzoo.search.proofs.car_bounds import dubins_length, reeds_shepp_length
from stepzoo.search.world.maps import from_array
from stepzoo.dynamics.vehicles import limits


def planner(grid, cell=1.0, **params) -> HybridAStar:
    return HybridAStar.like(PathFinder(from_array(grid, cell), load_config()),
                            HybridAStarParams(**params))


def walled() -> np.ndarray:
    """60 x 40 m, a wall at x 28..32 m from y = 0 to 30 m: the way round is by the top."""
    grid = np.zeros((40, 60), bool)
    grid[:30, 28:32] = True
    return grid


START, GOAL = (8.0, 10.0, 0.0), (52.0, 10.0, 0.0)


def dense(rows, spacing=0.01) -> np.ndarray:
    """Poses (M, 3) [X, Y, psi] along rows (K, 4) at most `spacing` [m] apart, linear in X, Y
    and the unwrapped psi."""
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(rows[:, 1:3], axis=0).T))]
    at = np.linspace(0.0, s[-1], math.ceil(s[-1] / spacing) + 1)
    return np.column_stack([np.interp(at, s, rows[:, 1]), np.interp(at, s, rows[:, 2]),
                            np.interp(at, s, np.unwrap(rows[:, 3]))])


@pytest.mark.parametrize("reverse", [False, True])
def test_in_an_empty_map_the_path_is_the_dubins_or_reeds_shepp_optimum(reverse):
    search = planner(np.zeros((40, 60), bool), reverse=reverse)
    start, goal = (10.0, 20.0, 0.0), (45.0, 28.0, 2.0)
    result = search.plan(start, goal)
    optimum = (reeds_shepp_length if reverse else dubins_length)(
        search.rear(start)[None], search.rear(goal), search.radius)[0]
    assert result.status == PlannerStatus.EXACT and result.expansions == 1
    assert result.length_m == pytest.approx(optimum, rel=1e-9)
    rear = np.column_stack([result.rows[:, 1:3] - search.lr * np.column_stack(
        [np.cos(result.rows[:, 3]), np.sin(result.rows[:, 3])]), result.rows[:, 3]])
    assert np.hypot(*np.diff(rear[:, :2], axis=0).T).sum() == pytest.approx(optimum, rel=1e-3)
    assert np.allclose(result.rows[0, 1:], start) and np.allclose(result.rows[-1, 1:3],
                                                                   goal[:2], atol=1e-6)
    assert math.remainder(result.rows[-1, 3] - goal[2], 2 * math.pi) == pytest.approx(0, abs=1e-6)


def test_with_reverse_gear_a_goal_just_behind_is_reached_backwards():
    search = planner(np.zeros((40, 60), bool), reverse=True)
    result = search.plan((30.0, 20.0, 0.0), (24.0, 20.0, 0.0))
    assert result.status == PlannerStatus.EXACT and result.length_m == pytest.approx(6.0)
    car = PathFinder(search.omap, load_config()).vehicle
    measured = drivability(result.rows, car["Lf"] + car["Lr"], math.pi / 4, **limits())
    assert measured["reverse_length_m"] == pytest.approx(6.0) and measured["cusps"] == 0


def test_around_a_wall_the_car_never_touches_by_a_dense_exact_check():
    grid = walled()
    search = planner(grid)
    result = search.plan(START, GOAL)
    assert result.status == PlannerStatus.EXACT
    # The shot from the start collides: the path is the search's.
    assert result.expansions > 10 and result.rows[:, 2].max() > 30.0
    finder = PathFinder(from_array(grid, 1.0), load_config())
    car = car_footprint(finder.vehicle, finder.config.params.margin)
    centres = car.disc_centres(dense(result.rows))
    clearance = distance_to_obstacles(search.omap, centres.reshape(-1, 2)) - car.radius
    assert clearance.min() > 0.0


def test_the_path_curves_no_tighter_than_the_car_can():
    search = planner(walled())
    result = search.plan(START, GOAL)
    car = PathFinder(search.omap, load_config()).vehicle
    wheelbase, delta_max = car["Lf"] + car["Lr"], math.pi / 4
    limit = math.tan(delta_max) / wheelbase
    measured = drivability(result.rows, wheelbase, delta_max, **limits())
    assert measured["max_curvature_1pm"] <= TOLERANCE["curvature_1pm"] * limit
    # Row by row too: the body turns at most 1/R per metre of the rear axle, less per metre
    # of the centre of gravity.
    step = np.hypot(*np.diff(result.rows[:, 1:3], axis=0).T)
    turn = np.abs(np.diff(np.unwrap(result.rows[:, 3])))
    assert (turn / step).max() <= limit * (1 + 1e-3)
    assert measured["cusps"] == 0 and measured["reverse_length_m"] == 0.0


def test_the_same_query_gives_the_same_path():
    first, second = (planner(walled()).plan(START, GOAL) for _ in range(2))
    assert first.expansions == second.expansions
    assert np.array_equal(first.rows, second.rows)


@pytest.mark.parametrize("case", ["goal_in_obstacle", "walled_off", "budget"])
def test_no_reachable_goal_gives_no_path(case):
    grid = walled()
    goal, budget = GOAL, 1_000_000
    if case == "goal_in_obstacle":
        goal = (30.0, 10.0, 0.0)
    elif case == "walled_off":
        grid[:, 28:32] = True
    else:
        budget = 5
    result = planner(grid, max_expansions=budget).plan(START, goal)
    assert result.status == PlannerStatus.NO_PATH and len(result.rows) == 0
    assert result.cause == {"goal_in_obstacle": Cause.GOAL_IN_COLLISION,
                            "walled_off": Cause.WALLED_OFF, "budget": Cause.BUDGET}[case]
    assert result.expansions == (5 if case == "budget" else 0)
