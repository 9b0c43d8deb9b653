"""The heading guide (search/planner/heading_lattice.py), the search's tie-break and its
narrow cells: the
lattice's cost to go agrees with the obstacle-blind Dubins length in the open (computed by
car_bounds, independently of the lattice) and exceeds it where walls forbid the turn, which
the 2-D geodesic cannot tell; equal f are ordered the same whatever order they were queued
in, and whatever the last bits of f; a door keeps nodes a pruning cell of the open would
merge."""
import heapq
import math

import numpy as np
import pytest

from stepzoo.search.planner.config import make_config
from stepzoo.search.planner.expansion import SPEED_CHANGE_STEER
from stepzoo.search.planner.guide import Guide, corridors
from stepzoo.search.planner.heading_lattice import HeadingLattice
from stepzoo.search.planner.pathfinder import F_QUANTUM, PathFinder, Search
from stepzoo.search.planner.status import PlannerStatus, PlanResult
from stepzoo.search.planner.termination import expansions
from stepzoo.search.proofs.car_bounds import dubins_length
from stepzoo.search.world.footprint import Footprint
from stepzoo.search.world.maps import from_array

FOOTPRINT = Footprint.from_vehicle(4.8, 2.0, 6)   # about a BMW 320i (4.5 x 1.6 m) + margin
RADIUS = 2.58                                      # [m] its tightest turn at 2 m/s


def open_map() -> np.ndarray:
    """90 x 90 m at 1.5 m/cell, walled round."""
    occupied = np.zeros((60, 60), bool)
    occupied[[0, -1], :] = occupied[:, [0, -1]] = True
    return occupied


def dead_end() -> np.ndarray:
    """An open yard x 1.5..30 m, y 1.5..28.5 m and, from its east side, a corridor 3 m wide
    (y 13.5..16.5 m) closed at x = 87 m: a car in it cannot turn round (4.8 m long)."""
    occupied = np.ones((20, 60), bool)
    occupied[1:19, 1:20] = False
    occupied[9:11, 20:58] = False
    return occupied


def test_in_the_open_the_cost_to_go_is_the_dubins_length_within_the_lattices_rounding():
    goal = np.array([45.0, 45.0, 0.3])
    lattice = HeadingLattice(from_array(open_map(), 1.5), goal, FOOTPRINT, RADIUS)
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(15, 75, 2000), rng.uniform(15, 75, 2000),
                             rng.uniform(-math.pi, math.pi, 2000)])
    far = np.hypot(*(poses[:, :2] - goal[:2]).T) > 15   # where the goal's rounding is small
    cost, dubins = lattice.at(poses[far]), dubins_length(poses[far], goal, RADIUS)
    # A move ends rounded to the 1.5 m lattice and its heading to pi/8: the lattice's path
    # is at most two spacings longer than the car's shortest (measured 2.85 m) and shorter by
    # at most a tenth or so of it (measured 0.87 times it), its rounding's error.
    assert np.all(cost <= dubins + 2 * lattice.spacing)
    assert np.all(cost >= 0.85 * dubins)
    assert 0.95 < np.median(cost / dubins) <= 1.0


def test_a_car_just_past_the_goal_facing_its_way_has_a_loop_to_drive():
    goal = np.array([45.0, 45.0, 0.0])
    lattice = HeadingLattice(from_array(open_map(), 1.5), goal, FOOTPRINT, RADIUS)
    past, behind = np.array([[46.5, 45.0, 0.0]]), np.array([[43.5, 45.0, 0.0]])
    assert lattice.at(behind)[0] <= 1.5
    loop = dubins_length(past, goal, RADIUS)[0]
    assert loop > 2 * math.pi * RADIUS and lattice.at(past)[0] >= 0.85 * loop


def test_a_car_facing_out_of_a_dead_end_goes_out_turns_and_comes_back():
    omap = from_array(dead_end(), 1.5)
    goal = np.array([75.0, 15.0, 0.0])
    lattice = HeadingLattice(omap, goal, FOOTPRINT, RADIUS)
    inward, outward = np.array([[60.0, 15.0, 0.0]]), np.array([[60.0, 15.0, math.pi]])
    mouth = 30.0                              # [m] where the corridor opens into the yard
    assert lattice.at(inward)[0] <= 15.0 + lattice.length     # straight on, one move's rounding
    assert lattice.at(outward)[0] >= 2 * (60.0 - mouth) + (75.0 - 60.0)
    # The bounds the search had cannot tell the two apart this well: the geodesic (positions
    # only) is the same for both, the Dubins length ignores the walls.
    guide = Guide(omap, corridors(omap, 1.8), goal, 1.0, 12.0, RADIUS, False)
    assert guide.rest(inward)[0] == guide.rest(outward)[0]
    assert dubins_length(outward, goal, RADIUS)[0] < 2 * (60.0 - mouth)


def test_a_goal_facing_out_of_a_dead_end_is_reached_only_backwards():
    omap = from_array(dead_end(), 1.5)
    goal = np.array([75.0, 15.0, math.pi])     # nose out, at the corridor's closed end
    outward = np.array([[60.0, 15.0, math.pi]])
    assert HeadingLattice(omap, goal, FOOTPRINT, RADIUS).at(outward)[0] == math.inf
    back = HeadingLattice(omap, goal, FOOTPRINT, RADIUS, reverse_penalty=3.0)
    # 15 m backwards at 3 per metre, within a move's length and the lookup's square.
    assert (3.0 * (75.0 - 60.0 - back.spacing) <= back.at(outward)[0]
            <= 3.0 * (75.0 - 60.0 + back.length))


def test_the_descent_follows_the_cost_to_go_into_the_dead_end_facing_in():
    omap = from_array(dead_end(), 1.5)
    goal = np.array([75.0, 15.0, 0.0])
    lattice = HeadingLattice(omap, goal, FOOTPRINT, RADIUS)
    point = lattice.descend(np.array([45.0, 15.0, 0.0]), 9.0)
    assert 52.0 <= point[0] <= 56.0 and abs(point[1] - 15.0) <= 0.75


def search(tie_break: str, occupied=None, vx=4.0, **params) -> Search:
    """A search on a small map (default: open, 40 x 20 m), not run: its tree, heap key and
    cells are what is tested."""
    config = make_config(max_seconds=3600.0, tie_break=tie_break, **params)
    occupied = np.zeros((40, 80), bool) if occupied is None else occupied
    finder = PathFinder(from_array(occupied, 0.5), config, None, vx)
    start, goal = np.array([4.0, 10.0, 0.0]), np.array([36.0, 10.0, 0.0])
    result = PlanResult(PlannerStatus.NO_PATH, "", start, goal, config.h, 4.0)
    return Search(finder, start, goal, None, np.random.default_rng(0), result, expansions(1))


def popped(s: Search, nodes) -> list[int]:
    heap = []
    for entry in s.entries(nodes):
        heapq.heappush(heap, entry)
    return [heapq.heappop(heap)[-1] for _ in nodes]


@pytest.mark.parametrize("tie_break", ["cell", "inserted"])
def test_equal_f_are_expanded_in_one_order_whatever_order_they_were_queued_in(tie_break):
    s = search(tie_break)
    rng = np.random.default_rng(1)
    # Twelve siblings: one f but for a rounding of their edges' lengths, in cells of their own.
    ends = np.column_stack([8.0 + 1.5 * rng.permutation(12), 10.0 + 0.3 * rng.random(12),
                            np.zeros(12), np.zeros(12), np.zeros(12)])
    # (f = g + 2 guide, 64.2 m, lies between two steps of F_QUANTUM, as nearly every f does.)
    g = 4.0 + 1e-13 * rng.integers(-3, 4, 12)
    rows = s.tree.add([None] * 12, states=ends, parent=0, g=g, H=30.0, rest=30.0, guide=30.1,
                      car=0.0, steer=0.0, steer0=0.0, direction=1, tight=False)
    one, other = list(rows), list(rng.permutation(list(rows)))
    if tie_break == "cell":
        assert popped(s, one) == popped(s, other)
        # ... and in the order of their cells, west to east here.
        assert np.all(np.diff(s.tree.states[popped(s, one), 0]) > 0)
    else:
        assert popped(s, one) != popped(s, other)   # the rounding and the queue decide


def test_the_rounded_f_keeps_the_order_of_f_that_differ_by_more_than_its_step():
    s = search("cell")
    rows = s.tree.add([None] * 3, states=np.zeros((3, 5)) + [[9, 10, 0, 0, 0]], parent=0,
                      g=[5.0, 5.0 - 2 * F_QUANTUM, 5.0 + 0.25], H=30.0, rest=30.0, guide=30.0,
                      car=0.0, steer=0.0, steer0=0.0, direction=1, tight=False)
    assert popped(s, list(rows)) == [rows[1], rows[0], rows[2]]


def test_a_pose_that_reaches_nothing_has_no_descent():
    omap = from_array(dead_end(), 1.5)
    lattice = HeadingLattice(omap, np.array([75.0, 15.0, math.pi]), FOOTPRINT, RADIUS)
    assert lattice.descend(np.array([60.0, 15.0, math.pi]), 4.0) is None


@pytest.mark.parametrize("narrow", [0.0, 2.0])
def test_in_a_door_the_pruning_cells_are_halved_and_in_the_open_not(narrow):
    occupied = np.zeros((40, 80), bool)
    occupied[:, 40:42] = True
    occupied[17:23, 40:42] = False                  # a door 3 m wide at x 20-21 m, y 8.5-11.5 m
    s = search("cell", occupied, narrow_cell_m=narrow)
    def apart(a, b):
        return s.cell(np.array(a), 1) != s.cell(np.array(b), 1)
    # 0.5 m and 0.2 rad apart: one cell of 1 m and pi/8, two of half that.
    assert apart([20.2, 10.0, 0.0], [20.7, 10.0, 0.0]) == (narrow > 0)
    assert apart([20.2, 10.0, 0.1], [20.2, 10.0, 0.3]) == (narrow > 0)
    assert not apart([10.2, 15.0, 0.1], [10.7, 15.0, 0.3])


@pytest.mark.parametrize("vx,steer_max", [(4.0, None), (2.0, None), (4.0, 1.6)])
def test_no_connection_sets_off_from_a_node_steered_past_the_speed_change_steer(vx, steer_max):
    """With connect_steer_max at its default (None), SPEED_CHANGE_STEER; 1.6 turns it off
    (rate_limited steering: course_limited connects only with the wheel straight)."""
    s = search("inserted", vx=vx, steering="rate_limited",
               **({} if steer_max is None else {"connect_steer_max": steer_max}))
    called = []
    s.f.connect = lambda node, *args, **kw: (called.append(kw["steer"]), (None, "recorded"))[1]
    goal = s.goal
    near = np.array([[goal[0] - 5.0, goal[1], 0.0, 0.0, 0.0]] * 3)
    s.tree.add([None] * 3, states=near, parent=0, g=30.0, H=5.0, rest=5.0, guide=5.0, car=5.0,
               steer=[0.5, 0.1, -0.5], steer0=0.0, direction=1, tight=[False, False, True])
    s.connector.try_connect()
    assert s.prm.connect_steer_max == (SPEED_CHANGE_STEER if steer_max is None else 1.6)
    if vx > 2.0 and steer_max is None:
        # The tree's move at 0.5 rad is skipped (its curvature would step into the
        # connection's); the one at 0.1 rad and the tight move (the connection's own model
        # and speed) are tried.
        assert sorted(called) == [-0.5, 0.1]
        assert s.connector.attempts() == 2
        assert any("steer past" in f for f in s.connector.failures)
    else:
        # At the tight moves' speed the tree's edges meet the connection without a step;
        # turned off, every node is tried, as the paper's planner.
        assert sorted(called) == [-0.5, 0.1, 0.5]
