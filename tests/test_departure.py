"""Leaving a pose forwards: the proof that no forward path leaves (boxed_in) holds against
brute force, never contradicts a free arc, and the planner turns it into a typed no_path at
once; the grown set of forward poses (reach) holds every collision-free random path's poses
and proves a start pocket of the street set, and where the car's rectangle decides, the cells
it blocks hold no free pose; the closed-form Dubins length is the shortest
Dubins path; the boxed-in queries of the earlier draw are boxed in."""
import math

import numpy as np
import pytest

from stepzoo import dynamics
from stepzoo.search.proofs.car_bounds import dubins_length
from stepzoo.search.planner.connection_ocp import dubins_paths
from stepzoo.search.proofs.departure import arc_poses, boxed_in, free_departure, turned
from stepzoo.search.world.footprint import Footprint, first_collision, poses_collide
from stepzoo.search.world.maps import MAP_DIR, from_array
from stepzoo.search.planner.pathfinder import PathFinder
from stepzoo.search.planner.config import make_config
from stepzoo.search.world.queries import QUERY_DIR, load_queries
from stepzoo.search.world.scenarios import open_map

VEHICLE = dynamics.vehicle(None)
RADIUS = (VEHICLE["Lf"] + VEHICLE["Lr"]) / math.tan(math.pi / 4)
MARGIN = 0.1


def footprint():
    """The planner's footprint: the car grown by the default margin, slices half as long as
    it is wide."""
    length, width = VEHICLE["length"] + 2 * MARGIN, VEHICLE["width"] + 2 * MARGIN
    return Footprint.from_vehicle(length, width, 2 * math.ceil(length / width))


def random_forward_paths(rng, pose, n, length, spacing=0.05):
    """(n, K, 3) forward paths from `pose` of piecewise-constant random curvature within
    +-1/RADIUS, changing every 0.2 m, `length` [m] long."""
    steps = math.ceil(length / spacing)
    kappa = rng.uniform(-1, 1, (n, math.ceil(steps * spacing / 0.2) + 1)) / RADIUS
    kappa = np.repeat(kappa, math.ceil(0.2 / spacing), axis=1)[:, :steps]
    # Extremes too: full lock either way from the start.
    kappa[:2] = np.array([[1.0], [-1.0]]) / RADIUS
    heading = pose[2] + np.c_[np.zeros(n), np.cumsum(kappa * spacing, axis=1)]
    mid = (heading[:, 1:] + heading[:, :-1]) / 2
    x = pose[0] + np.c_[np.zeros(n), np.cumsum(spacing * np.cos(mid), axis=1)]
    y = pose[1] + np.c_[np.zeros(n), np.cumsum(spacing * np.sin(mid), axis=1)]
    return np.stack([x, y, heading], axis=-1)


def facing_wall_map():
    """A 30 x 20 m yard, walls 1 m thick."""
    occupied = np.zeros((40, 60), bool)
    occupied[:, -2:] = occupied[:, :2] = occupied[:2] = occupied[-2:] = True
    return from_array(occupied, 0.5)


def test_a_start_facing_a_wall_is_boxed_in_and_every_forward_path_collides():
    omap, fp = facing_wall_map(), footprint()
    start = np.array([26.0, 10.0, 0.0])  # the front 0.55 m from the east wall
    assert not poses_collide(omap, fp, start)
    boxed, longest = boxed_in(omap, fp, start, RADIUS)
    assert boxed and 0 < longest < 2
    paths = random_forward_paths(np.random.default_rng(0), start, 400, longest + 0.05)
    assert (first_collision(omap, fp, paths) >= 0).all()
    assert not free_departure(omap, fp, start, RADIUS)
    # Facing the other way (12 m of yard ahead) it can leave, and the proof says nothing.
    assert free_departure(omap, fp, turned(start), RADIUS)
    assert not boxed_in(omap, fp, turned(start), RADIUS)[0]


def test_boxed_in_never_contradicts_a_collision_free_path_on_a_real_map():
    """Poses near walls on den312d: where boxed_in claims, 200 random forward paths and the
    witness arcs all collide; where any of them is free, it does not claim."""
    omap, fp = open_map(MAP_DIR / "den312d.map", 1.5), footprint()
    rng = np.random.default_rng(1)
    claims = frees = 0
    while claims < 6 or frees < 6:
        xmin, xmax, ymin, ymax = omap.bounds()
        pose = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax),
                         rng.uniform(-math.pi, math.pi)])
        if poses_collide(omap, fp, pose) or omap.clearance(pose[:2]) > 3.0:
            continue
        boxed, longest = boxed_in(omap, fp, pose, RADIUS)
        paths = random_forward_paths(rng, pose, 200, max(longest, 0.5) + 0.05)
        free = (first_collision(omap, fp, paths) < 0).any() or free_departure(
            omap, fp, pose, RADIUS)
        assert not (boxed and free), pose
        claims += boxed
        frees += free


def test_the_planner_says_start_boxed_in_without_searching_and_reverse_is_not_boxed():
    omap = facing_wall_map()
    start, goal = (26.0, 10.0, 0.0), (8.0, 10.0, math.pi)
    result = PathFinder(omap, make_config(), None, 2.0).plan(start, goal)
    assert (result.status, result.cause, result.expansions) == ("no_path", "start_boxed_in", 0)
    assert "try --reverse" in result.reason
    # The goal turned round is the same pose facing the wall: no forward arrival.
    result = PathFinder(omap, make_config(), None, 2.0).plan(goal, (26.0, 10.0, math.pi))
    assert (result.status, result.cause, result.expansions) == ("no_path", "goal_boxed_in", 0)
    # With reverse gear nothing is claimed (the planner's search decides).
    config = make_config(reverse=1, max_expansions=1)
    assert PathFinder(omap, config, None, 2.0).plan(start, goal).cause != "start_boxed_in"


def grown_holds(grown, grid, poses) -> np.ndarray:
    """bool (K,): whether each of `poses` (K, 3) [X, Y, psi] lies in a cell of `grown`
    (forward_reach's (reach, corner) on `grid`)."""
    reach, corner = grown
    col = np.floor((poses[:, 0] - corner[0]) / grid.cell_m).astype(int)
    row = np.floor((poses[:, 1] - corner[1]) / grid.cell_m).astype(int)
    b = np.floor(np.mod(poses[:, 2], 2 * np.pi) / (2 * np.pi / grid.heading_bins)).astype(int)
    return reach[b % grid.heading_bins, row, col]


def den312d_11():
    """(query, map) of den312d-11: its goal lies where a street opens into a yard, the
    car's rear towards a wall corner."""
    query = next(q for q in load_queries(QUERY_DIR / "streets.json") if q.id == "den312d-11")
    return query, open_map(query.map_path, query.cell_size)


def test_a_goal_pocket_no_rigid_car_arrives_at_forwards_is_proved_on_the_fine_grid():
    """den312d-11's goal, arrived at forwards by the rigid car (its rear axle rolls along the
    body, Lr behind the centre of gravity), is left backwards: forwards from the rear axle's
    pose turned round. The coarse growth, a pose every metre, steps past the wall corner that
    every such path runs into and slides out along the street; the fine growth closes in its
    3.5 m window, away from the start. The car itself, driven along 300 random paths,
    agrees: every path collides, no collision-free prefix gets 3 m from the goal, and the
    prefixes' poses every half metre lie in the fine set."""
    from stepzoo.search.planner.endpoints import seen
    from stepzoo.search.proofs.reach import COARSE, FINE, forward_reach, misses
    query, omap = den312d_11()
    fp, goal, lever = footprint(), np.array(query.goal), VEHICLE["Lr"]
    pose, car = seen(fp, goal, lever, True)
    assert forward_reach(omap, car, pose, RADIUS, COARSE) is None
    grown = forward_reach(omap, car, pose, RADIUS, FINE)
    assert grown is not None and misses(grown, np.array(query.start[:2]), FINE)
    paths = random_forward_paths(np.random.default_rng(4), pose, 300, 6.0)
    # The car's poses along them: facing back again, its centre of gravity Lr ahead of the
    # rear axle; checked with the footprint as the planner's checker sees it.
    heading = paths[..., 2] - math.pi
    bodies = np.stack([paths[..., 0] + lever * np.cos(heading),
                       paths[..., 1] + lever * np.sin(heading), heading], axis=-1)
    hit = first_collision(omap, fp, bodies)
    assert (hit > 0).all()
    every = round(FINE.step_m / 0.05)
    farthest = 0.0
    for path, body, first in zip(paths, bodies, hit):
        farthest = max(farthest, float(np.hypot(*(body[:first, :2] - goal[:2]).T).max()))
        assert grown_holds(grown, FINE, path[:first:every]).all()
    assert 1.0 < farthest < 3.0


def test_a_search_cut_short_by_its_budget_says_when_no_forward_path_arrives():
    """den312d-11 on 40 expansions: the search ends without a path and, instead of an
    approximate path to a node that may stand beside the goal facing elsewhere, the plan is
    no_path with the enclosure proof's cause."""
    query, omap = den312d_11()
    result = PathFinder(omap, make_config(max_expansions=40), None, 5.0).plan(query.start,
                                                                            query.goal)
    assert (result.status, result.cause) == ("no_path", "goal_boxed_in")
    assert 0 < result.expansions <= 40 and "budget ended" in result.reason
    assert "grown on 0.025 m" in result.reason


@pytest.mark.parametrize("qid", ["room-64-64-8-05-boxed", "room-64-64-8-09-boxed"])
def test_the_boxed_in_queries_of_the_earlier_draw_are_boxed_in(qid):
    query = {q.id: q for q in load_queries(QUERY_DIR / "boxed_in.json")}[qid]
    omap = open_map(query.map_path, query.cell_size)
    result = PathFinder(omap, make_config(), None, 5.0).plan(query.start, query.goal)
    # On 3 m cells the check decides by the rectangle. The departure proof reasons about the
    # front disc inside it, which does not prove these before a search; the enclosure proof,
    # about the rectangle itself, proves both once the search exhausts (44 and 52 expansions).
    assert (result.status, result.cause) == ("no_path", "start_boxed_in")
    assert 0 < result.expansions < 100
    assert not free_departure(omap, footprint(), np.array(query.start), RADIUS)
    # The disc cover alone is boxed in before any search.
    assert boxed_in(omap, discs_only(footprint()), np.array(query.start), RADIUS)[0]


def test_arc_poses_lie_on_the_circle_of_their_curvature():
    poses = arc_poses((1.0, 2.0, 0.3), 0.25, 3.0, 0.1)
    centre = np.array([1.0, 2.0]) + 4.0 * np.array([-math.sin(0.3), math.cos(0.3)])
    assert np.allclose(np.hypot(*(poses[:, :2] - centre).T), 4.0, atol=1e-12)
    assert np.allclose(np.diff(poses[:, 2]) * 4.0, np.hypot(*np.diff(poses[:, :2], axis=0).T),
                       rtol=1e-3)


def test_the_closed_form_dubins_length_is_the_shortest_driven_dubins_path():
    rng = np.random.default_rng(2)
    starts = np.column_stack([rng.uniform(-15, 15, 300), rng.uniform(-15, 15, 300),
                              rng.uniform(-4, 4, 300)])
    goal = np.array([1.0, -2.0, 0.7])
    driven = [sum(q for _, q in dubins_paths(s, goal, RADIUS)[0]) for s in starts]
    assert np.allclose(dubins_length(starts, goal, RADIUS), driven, rtol=0, atol=1e-9)
    # At the goal itself the length is zero; straight behind it, the gap.
    assert dubins_length(goal[None], goal, RADIUS)[0] == pytest.approx(0.0, abs=1e-9)
    behind = goal - (5 * math.cos(0.7), 5 * math.sin(0.7), 0.0)
    assert dubins_length(behind[None], goal, RADIUS)[0] == pytest.approx(5.0, abs=1e-9)


def test_the_reeds_shepp_length_equals_ompls_reeds_shepp_distance():
    """OMPL's ReedsSheppStateSpace (the test extras' ompl) on 500 random pose pairs."""
    ob = pytest.importorskip("ompl.base")
    from stepzoo.search.proofs.car_bounds import reeds_shepp_length
    radius = 2.5
    space = ob.ReedsSheppStateSpace(radius)
    a, b = space.allocState(), space.allocState()
    rng = np.random.default_rng(3)
    starts = np.column_stack([rng.uniform(-12, 12, 500), rng.uniform(-12, 12, 500),
                              rng.uniform(-4, 4, 500)])
    goal = np.array([0.5, 1.0, 0.3])
    b.setX(goal[0]), b.setY(goal[1]), b.setYaw(goal[2])
    ompl = []
    for x, y, yaw in starts:
        a.setX(x), a.setY(y), a.setYaw(yaw)
        ompl.append(space.distance(a, b))
    rs = reeds_shepp_length(starts, goal, radius)
    assert np.allclose(rs, ompl, rtol=0, atol=1e-9)
    # Backwards is allowed: never longer than Dubins, and shorter for a goal straight behind.
    assert (rs <= dubins_length(starts, goal, radius) + 1e-9).all()
    behind = goal + (5 * math.cos(0.3), 5 * math.sin(0.3), 0.0)
    assert reeds_shepp_length(behind[None], goal, radius)[0] == pytest.approx(5.0, abs=1e-9)


def test_the_trees_dynamic_shootings_from_a_boxed_in_start_collide_too():
    """The proof covers paths along the heading; the tree's dynamic bicycle slips sideways.
    From the boxed start every one of its shootings (full lock either way, and between)
    collides before the length the proof names."""
    from stepzoo.search.planner.shooting import Shooter
    from stepzoo.search.world.validity import FootprintChecker
    omap, fp = facing_wall_map(), footprint()
    start = np.array([26.0, 10.0, 0.0, 0.0, 0.0])
    boxed, longest = boxed_in(omap, fp, start, RADIUS)
    shooter = Shooter(FootprintChecker(omap, fp), None, 5.0, "rk4", 0.01, 60, 9, math.pi / 4)
    fan = np.linspace(-math.pi / 2, math.pi / 2, 9)
    ahead = start[:2] + 2.0 * np.column_stack([np.cos(fan), np.sin(fan)])
    shots = shooter.shoot(start, ahead, np.zeros(2))
    assert boxed and np.abs(shots.steer).max() == pytest.approx(math.pi / 4)
    reached = shots.travelled[np.arange(9), shots.free - 1]
    assert (shots.free < shots.states.shape[1]).all() and (reached <= longest).all()


def discs_only(fp):
    """`fp`'s discs as the car's shape (the check decides by them on any map)."""
    return Footprint(fp.length, fp.width, fp.offsets, fp.radius)


@pytest.mark.parametrize("shape", ["discs", "rectangle"])
def test_the_grown_forward_poses_hold_every_free_path_and_enclose_a_street_start(shape):
    """room-64-64-8-09's start faces a wall 4.5 m away at 15 degrees: a 2 m arc leaves it;
    for the disc cover, the grown set closes within 7 m and the goal lies far outside; every
    collision-free prefix of 300 random forward paths has its poses at each step_m of length
    in it. For the rigid car's rectangle (which the check decides by on these 3 m cells), seen
    from its rear axle as the planner's proofs see it, the growth leaves the window: its
    full-lock turn clears the wall by 4.8 cm, and the planner finds the way."""
    from stepzoo.search.proofs.reach import COARSE, forward_reach, misses
    query = next(q for q in load_queries(QUERY_DIR / "streets.json")
                 if q.id == "room-64-64-8-09")
    omap = open_map(query.map_path, query.cell_size)
    fp = discs_only(footprint()) if shape == "discs" else footprint()
    start = np.array(query.start)
    assert free_departure(omap, fp, start, RADIUS) and not boxed_in(omap, fp, start, RADIUS)[0]
    if shape == "rectangle":
        from stepzoo.search.planner.endpoints import seen
        pose, car = seen(fp, start, VEHICLE["Lr"])
        assert forward_reach(omap, car, pose, RADIUS) is None
        return
    reach, corner = forward_reach(omap, fp, start, RADIUS)
    assert misses((reach, corner), np.array(query.goal[:2]))
    paths = random_forward_paths(np.random.default_rng(3), start, 300, 8.0)
    hit = first_collision(omap, fp, paths)
    every = round(COARSE.step_m / 0.05)
    samples = 0
    for path, first in zip(paths, hit):
        free = path[:first] if first >= 0 else path
        poses = free[::every]
        assert grown_holds((reach, corner), COARSE, poses).all()
        samples += len(poses) - 1
    assert samples > 300  # the paths do move: more than one step each on average


@pytest.mark.parametrize("grid", ["COARSE", "FINE"])
def test_the_shrunk_rectangle_blocks_no_cell_that_holds_a_free_pose(grid):
    """Where the check decides by the rectangle (den312d's 1.5 m cells), the growth's cells
    near walls, the car seen from its centre and, as the proofs see the rigid car, from its
    rear axle facing either way: in every cell _blocked claims, the poses at its corners and
    bin edges and 30 random poses within it (position in its square, heading in its bin) all
    collide by the exact check. The rectangle at the cell's centre unshrunk would claim cells
    with free poses: the shrink carries it."""
    from stepzoo.search.proofs import reach
    g = getattr(reach, grid)
    omap, rng = open_map(MAP_DIR / "den312d.map", 1.5), np.random.default_rng(5)
    bin_size = 2 * math.pi / g.heading_bins
    xmin, xmax, ymin, ymax = omap.bounds()
    xy = rng.uniform((xmin, ymin), (xmax, ymax), (40000, 2))
    xy = xy[(omap.clearance(xy) > 0) & (omap.clearance(xy) < 3.0)][:3000]
    x, y = ((np.floor(xy / g.cell_m) + 0.5) * g.cell_m).T
    heading = (np.floor(rng.uniform(0, 2 * math.pi, len(x)) / bin_size) + 0.5) * bin_size
    corners = [(u, v, w) for u in (-0.5, 0.5) for v in (-0.5, 0.5) for w in (-0.5, 0.5)]
    offsets = np.r_[np.array(corners), rng.uniform(-0.5, 0.5, (30, 3))]
    rear = footprint().seen_from(VEHICLE["Lr"])
    for car in (footprint(), rear, rear.turned()):
        blocked = reach._blocked(omap, car, x, y, heading, g)
        poses = np.stack([x[:, None] + offsets[:, 0] * g.cell_m,
                          y[:, None] + offsets[:, 1] * g.cell_m,
                          heading[:, None] + offsets[:, 2] * bin_size], axis=-1)
        free = ~poses_collide(omap, car, poses)      # (cells, poses)
        assert not (blocked[:, None] & free).any()
        centre = omap.rectangle_hits(x + car.centre * np.cos(heading),
                                     y + car.centre * np.sin(heading), heading,
                                     car.length, car.width)
        assert (centre & free.any(axis=1)).sum() > 10    # the unshrunk claim would be wrong
        assert blocked.sum() > 0.5 * centre.sum() > 100  # and the shrunk one claims most
