"""The tree planner: the five scenarios plan to exact paths that an independent dense check
(reference integrator, sampled footprint, raw occupancy cells) finds collision-free; the same
inputs give the same path; bad endpoints, walled-off goals, budgets and blow-up end cleanly."""
import functools

import numpy as np
import pytest
from scipy.ndimage import label

from stepzoo import dynamics
from stepzoo.dynamics.models import steered
from stepzoo.integrators import integrate
from stepzoo.integrators.reference import reference
from stepzoo.search.planner.connection_ocp import resimulate
from stepzoo.search.world.maps import MAP_DIR, SUBDIV, from_array, load_map
from stepzoo.search.planner.pathfinder import PathFinder
from stepzoo.search.planner.config import make_config, with_params
from stepzoo.search.planner.point_selector import point_selector, random_points
from stepzoo.search.world.scenarios import builtin_names, load_scenario
from stepzoo.search.planner.shooting import Shooter, pure_pursuit

# An hour of clock: what these tests check never depends on the machine's speed or load
# (the plans end by themselves; test_a_plan_that_ends_by_itself... checks that they did).
CONFIG = make_config(max_seconds=3600.0)


def finder_for(scenario, config=CONFIG):
    return PathFinder(scenario.omap, config, scenario.vehicle, scenario.speed)


@pytest.fixture(scope="module")
def plans():
    """Every built-in scenario planned once with the default config and seed 0."""
    out = {}
    for name in builtin_names():
        scenario = load_scenario(name)
        out[name] = scenario, finder_for(scenario).plan(scenario.start, scenario.goal,
                                                         scenario.goal_speed, seed=0)
    return out


# --- the independent dense check -------------------------------------------------------------

def footprint_hits(omap, vehicle, poses, spacing):
    """bool (K,): the length x width rectangle at each pose [X, Y, psi], sampled on a grid of
    `spacing` [m] (edges included), touches an occupied cell or leaves the grid."""
    along = np.linspace(-vehicle["length"] / 2, vehicle["length"] / 2,
                        int(np.ceil(vehicle["length"] / spacing)) + 1)
    across = np.linspace(-vehicle["width"] / 2, vehicle["width"] / 2,
                         int(np.ceil(vehicle["width"] / spacing)) + 1)
    a, c = (v.ravel() for v in np.meshgrid(along, across))
    cos, sin = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
    x = poses[:, 0:1] + a * cos - c * sin
    y = poses[:, 1:2] + a * sin + c * cos
    col = np.floor((x - omap.origin[0]) / omap.resolution).astype(int)
    row = np.floor((y - omap.origin[1]) / omap.resolution).astype(int)
    rows, cols = omap.occupied.shape
    inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
    hit = ~inside | omap.occupied[np.clip(row, 0, rows - 1), np.clip(col, 0, cols - 1)]
    return hit.any(axis=1)


def dense_check(scenario, result):
    """Re-simulate every path edge with the adaptive reference (tight moves on the kinematic
    bicycle, as a rigid car where the steer is rate-limited) and the connection on a ten
    times finer step; return (collisions, largest joint
    gap [m], connection miss [m])."""
    vehicle = dynamics.vehicle(scenario.vehicle)
    rigid = bool(result.path_steer_rates)  # rate-limited: its kinematic moves a rigid car's
    model = dynamics.model("dynamic5")
    tight = dynamics.model("kinematic_cg" if rigid else "kinematic")
    p = model.params(scenario.vehicle, scenario.speed)
    p_tight = tight.params(scenario.vehicle, scenario.speed)
    # Sample the footprint at a quarter cell and the motion so finely that no point of the car
    # moves more than a quarter cell between poses (speed plus rotation of the far corner).
    spacing = min(scenario.omap.resolution / 4, 0.1)
    collisions, joint_gap, previous_end = 0, 0.0, result.path_edges[0][0]
    rates = result.path_steer_rates or [None] * len(result.path_edges)
    for edge, steer, kinematic, rate in zip(result.path_edges, result.path_steers,
                                            result.path_tight, rates):
        # An edge may be the collision-free first part of a shooting: its own duration.
        duration = (len(edge) - 1) * result.h
        ts = np.linspace(0.0, duration, int(np.ceil(duration * scenario.speed * 4 / spacing)) + 1)
        # Tight moves are driven at the plan's tight speed.
        x0, u, rhs = np.r_[edge[0, :3], result.tight_vx], np.array([steer, 0.0]), tight.rhs
        if not kinematic:
            x0, u, rhs = edge[0], np.array([steer]), model.rhs
        if rate is not None:
            # A steer ramp ending at `steer`: the steer a state, its rate the input.
            x0, rhs = np.r_[x0, steer - rate * duration], steered(rhs)
            u[0] = rate
        ref = reference(rhs, x0, u, p_tight if kinematic else p, ts, rtol=1e-10, atol=1e-10)
        xs = np.asarray(ref.x)
        assert bool(ref.success)
        collisions += int(footprint_hits(scenario.omap, vehicle, xs[:, :3], spacing).sum())
        joint_gap = max(joint_gap, float(np.hypot(*(edge[0, :2] - previous_end[:2]))))
        previous_end = xs[-1]
    conn = result.connection
    fine = resimulate(conn, L=vehicle["Lf"] + vehicle["Lr"], m=vehicle["m"], refine=10,
                      **({"Lr": vehicle["Lr"]} if rigid else {}))
    collisions += int(footprint_hits(scenario.omap, vehicle, fine, spacing).sum())
    joint_gap = max(joint_gap, float(np.hypot(*(fine[0, :2] - previous_end[:2]))))
    miss = float(np.hypot(*(fine[-1, :2] - np.asarray(scenario.goal[:2]))))
    return collisions, joint_gap, miss


def test_dense_check_sees_a_pose_inside_an_obstacle():
    omap = from_array(np.pad(np.ones((2, 2)), 10), 0.5)  # one 1 m block at (5..6, 5..6)
    vehicle = dynamics.vehicle(None)
    poses = np.array([[5.5, 5.5, 0.0], [5.5, 3.0, 0.0], [5.5, 4.2, 0.3], [2.0, 2.0, 0.0]])
    assert footprint_hits(omap, vehicle, poses, 0.125).tolist() == [True, False, True, True]


# --- the paper's claims -----------------------------------------------------------------------

@pytest.mark.parametrize("name", builtin_names())
def test_every_builtin_scenario_plans_an_exact_path_that_the_dense_check_accepts(plans, name):
    scenario, result = plans[name]
    assert result.status == "exact", result.reason
    assert result.connection is not None and result.path_edges
    collisions, joint_gap, miss = dense_check(scenario, result)
    assert collisions == 0
    # The reference lands where the planner's integrator put the next node: edges chain.
    assert joint_gap < 1e-3
    assert miss < 1e-3
    assert np.allclose(result.path_edges[0][0, :3], scenario.start)


def test_there_are_five_builtin_scenarios():
    assert len(builtin_names()) == 5


def test_same_inputs_give_the_same_path_and_another_seed_another_tree(plans):
    scenario, first = plans["obstacles_between"]
    again = finder_for(scenario).plan(scenario.start, scenario.goal, scenario.goal_speed, seed=0)
    assert again.status == first.status and again.expansions == first.expansions
    for a, b in zip(first.path_edges, again.path_edges, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(first.connection.states, again.connection.states)
    other = finder_for(scenario).plan(scenario.start, scenario.goal, scenario.goal_speed, seed=1)
    assert (other.nodes, other.expansions) != (first.nodes, first.expansions) or any(
        not np.array_equal(a, b) for a, b in zip(first.tree, other.tree))


def test_no_two_tree_nodes_share_a_pruning_cell():
    # The paper's instant steering and cells of one size, whose cells are (x, y, heading) of
    # the edges' ends; the rate-limited planner's also bin the steer, which the edges do not
    # hold, and narrow_cell_m halves them near walls.
    scenario = load_scenario("wall_between")
    config = make_config(max_seconds=3600.0, steering="instant", narrow_cell_m=0.0)
    result = finder_for(scenario, config).plan(scenario.start, scenario.goal)
    prm = config.params
    ends = np.array([scenario.start] + [e[-1, :3] for e in result.tree])
    cells = np.column_stack([np.floor(ends[:, :2] / prm.cell_xy),
                             np.floor(ends[:, 2] % (2 * np.pi) / prm.cell_heading)])
    assert len(np.unique(cells, axis=0)) == len(ends) == result.nodes


def test_path_length_is_at_least_the_straight_line_and_the_plans_lower_bound(plans):
    from stepzoo.search.planner.pathfinder import OCTILE_EXCESS
    for scenario, result in plans.values():
        straight = np.hypot(*np.subtract(scenario.goal[:2], scenario.start[:2]))
        assert result.path_length() >= max(straight, result.lower_bound_m)
        # The bound knows at least the straight line (the geodesic is never shorter).
        step = scenario.omap.resolution / SUBDIV
        assert result.lower_bound_m >= straight / OCTILE_EXCESS - 2 * step - 1e-9


def test_a_plan_that_ends_by_itself_says_no_budget_bound_it(plans):
    """Reproducible plans: none of the five scenarios' plans is cut short (they are then
    the same on any machine, as the test above shows for one)."""
    assert [result.budget_bound for _, result in plans.values()] == [None] * len(plans)


# --- bad endpoints, walls, budgets, blow-up ---------------------------------------------------

@pytest.mark.parametrize("start, goal, cause", [
    ((30.0, 25.0, 0.0), (50.0, 25.0, 0.0), "start_in_collision"),
    ((10.0, 25.0, 0.0), (30.0, 20.0, 1.0), "goal_in_collision"),
    ((-5.0, 25.0, 0.0), (50.0, 25.0, 0.0), "start_off_map"),
    ((10.0, 25.0, 0.0), (50.0, 99.0, 0.0), "goal_off_map"),
    ((10.0, 0.5, 0.0), (50.0, 25.0, 0.0), "start_in_collision"),  # centre inside, car sticks out
])
def test_bad_endpoints_are_no_path_with_that_reason(start, goal, cause):
    scenario = load_scenario("wall_between")
    result = finder_for(scenario).plan(start, goal)
    assert (result.status, result.cause, result.expansions) == ("no_path", cause, 0)
    assert cause.split("_")[0] in result.reason and result.path_edges == []


def walled_map():
    """40 x 30 m; the goal's 10 x 10 m room at the right has no door."""
    occupied = np.zeros((60, 80), bool)
    occupied[10:50, 50:52] = occupied[10:12, 50:72] = occupied[48:50, 50:72] = True
    occupied[10:50, 70:72] = True
    return from_array(occupied, 0.5)


def test_a_walled_off_goal_is_no_path_without_searching():
    finder = PathFinder(walled_map(), CONFIG, None, 5.0)
    result = finder.plan((5.0, 15.0, 0.0), (30.5, 15.0, 0.0))
    assert (result.status, result.cause, result.expansions) == ("no_path", "walled_off", 0)


def test_a_dead_end_the_car_cannot_turn_in_is_proved_boxed_in_once_the_search_exhausts():
    # A 3.5 m wide blind corridor: the corridor check passes (the goal is in the same free
    # space), but a forward-only car facing the dead end cannot turn round, not even with
    # the tight moves the search widens to; the grown set of forward poses then proves it.
    occupied = np.ones((60, 100), bool)
    occupied[10:50, 0:30] = False           # a 15 x 20 m yard with the goal
    occupied[26:33, 30:70] = False           # the corridor, 3.5 m wide, closed at x = 35
    finder = PathFinder(from_array(occupied, 0.5), CONFIG, None, 5.0)
    result = finder.plan((30.0, 14.75, 0.0), (7.0, 15.0, 0.0))
    assert (result.status, result.cause, result.widened) == ("no_path", "start_boxed_in", True)
    assert 0 < result.expansions < CONFIG.params.max_expansions


@functools.cache
def yard_facing_a_wall(steering="rate_limited", heading=0.6):
    """Facing a wall 3.5 m ahead at `heading` [rad] (default 34 degrees) in a 30 x 30 m yard,
    planned with `steering`: (scenario, finder, result), planned once (deterministic) for the
    tests that read it. The dynamic bicycle at 5 m/s understeers to a 3.3 m turn at full lock and cannot
    turn out; the kinematic bicycle (2.6 m at full lock, what the connection drives) can."""
    from stepzoo.search.world.scenarios import Scenario
    occupied = np.ones((64, 64), bool)
    occupied[2:62, 2:62] = False            # its far wall at x = 31 m
    omap = from_array(occupied, 0.5)
    start, goal = (27.5, 16.0, heading), (8.0, 16.0, np.pi)
    finder = PathFinder(omap, with_params(CONFIG, steering=steering), None, 5.0)
    scenario = Scenario("yard", "", omap, "generated", start, goal, None, None, 5.0)
    return scenario, finder, finder.plan(start, goal)


def test_a_start_the_tree_cannot_turn_out_of_is_left_by_tight_moves():
    # Its moves collide, so the tree shoots tight moves there (rate-limited, at once; the
    # paper's instant steering only once its tree has exhausted) and finds a path that the
    # dense check re-simulates on each edge's own model (rate-limited, the rigid car's tight
    # moves turn out facing the wall at 17 degrees too).
    for steering, widened, heading in (("rate_limited", False, 0.6), ("instant", True, 0.3)):
        scenario, _, result = yard_facing_a_wall(steering, heading)
        assert (result.status, result.widened) == ("exact", widened), result.reason
        assert any(result.path_tight)
        collisions, joint_gap, miss = dense_check(scenario, result)
        assert (collisions, joint_gap < 1e-3, miss < 1e-3) == (0, True, True)


def test_a_turn_tighter_than_the_trees_speed_allows_is_driven_slower():
    """From the path rows alone (the heading's change over half a metre of the rear axle's
    rows, Lr behind (X, Y), as the drivability block reads it, and the speed the centre of
    gravity's rows and times give): where the path turns on a radius r tighter than the
    lateral limit allows at the tree's 5 m/s, the car drives it at v <= sqrt(a_lat r), a_lat
    the planned limit (limit_fraction of the car's); and it does turn that tight, at the
    tight moves' speed."""
    from stepzoo.search.plans.files import path_rows
    from stepzoo.search.plans.path_metrics import rear_axle_rows
    _, finder, result = yard_facing_a_wall()
    assert result.status == "exact", result.reason
    rows = path_rows(result, finder.vehicle)
    rear = rear_axle_rows(rows, finder.vehicle["Lr"])
    ds = np.hypot(*np.diff(rear[:, 1:3], axis=0).T)
    keep = ds > 1e-6
    heading = np.unwrap(rows[1:, 3])[keep]
    along, t = np.cumsum(ds[keep]), rows[1:, 0][keep]
    cog = np.cumsum(np.hypot(*np.diff(rows[:, 1:3], axis=0).T))[keep]
    n = int(np.ceil(0.5 / np.median(ds[keep])))          # about half a metre of rows
    kappa = np.abs(heading[n:] - heading[:-n]) / (along[n:] - along[:-n])
    v = (cog[n:] - cog[:-n]) / (t[n:] - t[:-n])
    a_lat = finder.lateral_limit
    assert a_lat == pytest.approx(0.8 * 11.5)
    assert (v ** 2 * kappa).max() <= 1.02 * a_lat
    tight = kappa > 1.02 * a_lat / 5.0 ** 2
    assert tight.any()
    assert (v[tight] <= 1.01 * np.sqrt(a_lat / kappa[tight])).all()
    assert v[tight].max() == pytest.approx(finder.config.params.tight_speed, rel=0.02)


def test_the_rigid_cars_centre_of_gravity_rolls_as_geometry_says():
    """Geometry alone: a car rolling without slip with its rear axle on a circle of radius r
    about the origin, its body along the axle's tangent, has its steer atan(L / r), its
    centre of gravity (Lr ahead of the axle) on the circle of radius sqrt(r^2 + Lr^2),
    moving square to its radius; kinematic_cg's rigid_terms give that velocity's direction
    and the body's turn v / sqrt(r^2 + Lr^2) for its speed v."""
    import math
    from stepzoo.dynamics.kinematic import rigid_terms
    car = dynamics.vehicle(None)
    L, Lr = car["Lf"] + car["Lr"], car["Lr"]
    for r in (2.6, 4.0, 10.0):
        body = np.array([0.0, 1.0])                      # turning left about the origin
        cog = np.array([r, 0.0]) + Lr * body
        R = np.hypot(*cog)
        dx, dy, turn, _ = rigid_terms([*cog, np.pi / 2, 2.0], [math.atan(L / r), 0.0], L, Lr,
                                      1.0, math.cos, math.sin, math.tan, math.sqrt)
        assert np.array([dx, dy]) == pytest.approx(2.0 * np.array([-cog[1], cog[0]]) / R,
                                                   abs=1e-12)
        assert turn == pytest.approx(2.0 / R, abs=1e-12)


class Recorder:
    """A validity checker that finds everything free and keeps the poses it was given."""

    def __init__(self):
        self.seen = []

    def first_invalid(self, poses):
        self.seen.append(np.array(poses))
        return np.full(len(poses), -1)


@pytest.mark.parametrize("tight", [True, False])
def test_the_planner_checks_a_kinematic_move_where_the_cars_body_is(tight):
    """A tight move drives the kinematic bicycle as a rigid car (its psi the body), the tree's
    own move the dynamic bicycle (its psi the body): either way the validity checker is given
    the states' poses as they are, the node's and the ramp's last."""
    recorder = Recorder()
    shooter = Shooter(recorder, None, 2.0 if tight else 5.0, "rk4", 0.02, 40, 3, 0.7,
                      tight=tight, max_steer_rate=0.32)
    steer0, steer = 0.2, np.array([-0.05, 0.2, 0.45])
    shots = shooter.shoot_steers(np.zeros(5), steer, np.array([20.0, 0.0, 0.0]), steer0)
    checked, states = recorder.seen[-1], shots.states
    assert checked[:, 0] == pytest.approx(states[:, 0, :3], abs=1e-12)   # the node itself
    assert checked[:, -1] == pytest.approx(states[:, -1, :3], abs=1e-12)
    assert np.ptp(states[:, -1, 2]) > 0.05     # the three steers turned the body apart


@pytest.mark.parametrize("reverse", [False, True])
def test_a_kinematic_move_sets_off_without_sliding_its_rear_axle(reverse):
    """Geometry as the oracle: a car rolling without slip at a steady steer moves its rear
    axle along its body, from the first metre on. A kinematic move (tight or backwards) from
    a standstill (the start, a cusp), its wheel turned first (steer0 NaN), from a node whose
    body faces psi = 0.4: between every two poses the validity checker is given (the
    body's), the rear axle's chord lies along the mean of their body headings, and the first
    pose is the node's. A move that set off along the node's heading instead of the slip
    beyond it slides the rear axle by up to 0.45 rad (full lock) at the start."""
    recorder = Recorder()
    car = dynamics.vehicle(None)
    Lr = car["Lr"]
    shooter = Shooter(recorder, None, 2.0, "rk4", 0.01, 80, 4, 0.75, reverse=reverse,
                      tight=not reverse, max_steer_rate=0.32)
    steer = np.array([-0.75, -0.2, 0.45, 0.75])
    start = np.array([3.0, -1.0, 0.4, 0.0, 0.0])
    shooter.shoot_steers(start, steer, np.array([20.0, 0.0, 0.0]), np.nan)
    body = recorder.seen[-1]
    assert body[:, 0] == pytest.approx(np.tile(start[:3], (4, 1)), abs=1e-12)
    rear = body[..., :2] - Lr * np.stack([np.cos(body[..., 2]), np.sin(body[..., 2])], -1)
    chord = np.diff(rear, axis=1)
    mean = (body[:, 1:, 2] + body[:, :-1, 2]) / 2
    sideways = (np.cos(mean) * chord[..., 1] - np.sin(mean) * chord[..., 0]) \
        / np.hypot(*np.moveaxis(chord, -1, 0))
    assert np.abs(sideways).max() < 2e-3


def test_the_expansion_budget_ends_in_the_closest_node():
    scenario = load_scenario("wall_between")
    config = make_config(max_expansions=5)
    result = finder_for(scenario, config).plan(scenario.start, scenario.goal)
    assert (result.status, result.cause, result.expansions) == ("approximate", "budget", 5)
    assert result.budget_bound == "max_expansions"
    ends = np.array([e[-1, :2] for e in result.tree])
    closest = np.hypot(*(ends - scenario.goal[:2]).T).min()
    assert np.hypot(*(result.path_edges[-1][-1, :2] - scenario.goal[:2])) == closest


def test_a_blown_up_shooting_is_discarded_not_a_crash():
    scenario = load_scenario("open_field")
    # Forward Euler at 0.05 s on the default car at 0.25 m/s: h*lambda is about -43, far
    # outside its stability interval [-2, 0]; 200 steps grow it past the float64 range.
    # (Tight moves, on the kinematic bicycle, would not blow up: off, to test the tree's own.)
    config = make_config("euler", 0.05, horizon=10.0, tight_moves=0)
    finder = PathFinder(scenario.omap, config, scenario.vehicle, 0.25)
    state = np.array([*scenario.start, 0.0, 0.0])
    points = point_selector(state, 4.0, finder.shooter.batch, np.pi / 4)
    shots = finder.shooter.shoot(state, points, np.array(scenario.goal))
    assert not np.isfinite(shots.states).all(axis=(1, 2)).any()
    assert not shots.valid.any()
    # Only straight-ahead shootings (steer 0 leaves the lateral states at rest) stay finite.
    result = finder.plan(scenario.start, scenario.goal)
    assert (result.status, result.cause) == ("no_path", "exhausted")
    assert all(np.isfinite(edge).all() for edge in result.tree)


# --- point selection and shooting -------------------------------------------------------------

def test_point_selector_spreads_n_points_on_the_arc_within_the_steer_limit():
    state = np.array([3.0, -2.0, 0.7])
    points = point_selector(state, 5.0, 7, np.pi / 4)
    rel = points - state[:2]
    np.testing.assert_allclose(np.hypot(*rel.T), 5.0)
    angles = np.arctan2(rel[:, 1], rel[:, 0]) - 0.7
    np.testing.assert_allclose(angles, np.linspace(-np.pi / 4, np.pi / 4, 7), atol=1e-12)


def test_random_points_fill_the_disc_around_the_destination_reproducibly():
    a = random_points(np.random.default_rng(3), (10.0, 20.0), 2000, 3.0)
    b = random_points(np.random.default_rng(3), (10.0, 20.0), 2000, 3.0)
    np.testing.assert_array_equal(a, b)
    r = np.hypot(*(a - (10.0, 20.0)).T)
    assert r.max() <= 3.0 and np.mean(r <= 1.5) == pytest.approx(0.25, abs=0.03)


def test_pure_pursuit_steers_onto_the_circle_through_the_point():
    L = 2.6
    state = np.array([1.0, 2.0, 0.4])
    points = state[:2] + 6.0 * np.column_stack([np.cos(0.4 + np.array([-0.3, 0.0, 0.2])),
                                                np.sin(0.4 + np.array([-0.3, 0.0, 0.2]))])
    steer = pure_pursuit(state, points, L, np.pi / 4)
    for delta, point in zip(steer, points):
        # The kinematic circle of curvature tan(delta)/L tangent to the heading contains it.
        kappa = np.tan(delta) / L
        local = point - state[:2]
        ahead = local @ [np.cos(0.4), np.sin(0.4)]
        left = local @ [-np.sin(0.4), np.cos(0.4)]
        assert kappa * (ahead ** 2 + left ** 2) == pytest.approx(2 * left, abs=1e-9)
    far_side = state[:2] + [np.cos(0.4 + 2.5), np.sin(0.4 + 2.5)]
    assert pure_pursuit(state, far_side[None], L, np.pi / 4)[0] == pytest.approx(np.pi / 4)


def test_all_shootings_of_an_expansion_match_one_by_one_integration():
    scenario = load_scenario("open_field")
    shooter: Shooter = finder_for(scenario).shooter
    state = np.array([*scenario.start, 0.1, 0.05])
    points = point_selector(state, 4.0, shooter.batch, np.pi / 4)
    # From a standstill (NaN) each shooting holds one steer; at steer 0.1 rad it ramps.
    shots = shooter.shoot(state, points, np.array(scenario.goal), np.nan)
    ramps = shooter.shoot(state, points, np.array(scenario.goal), 0.1)
    model = dynamics.model("dynamic5")
    p = model.params(scenario.vehicle, scenario.speed)
    for k in (0, shooter.batch - 1):
        one = np.asarray(integrate(shooter.method, model.rhs, state, shots.steer[k:k + 1], p,
                                   shooter.h, shooter.n_steps).x)
        np.testing.assert_allclose(shots.states[k], one, rtol=1e-12, atol=1e-12)
        rate = (ramps.steer[k] - 0.1) / (shooter.h * shooter.n_steps)
        assert abs(rate) <= dynamics.vehicles.limits()["max_steer_rate"] + 1e-12
        ramp = np.asarray(integrate(shooter.method, steered(model.rhs), np.r_[state, 0.1],
                                    np.array([rate]), p, shooter.h, shooter.n_steps).x)
        np.testing.assert_allclose(ramps.states[k], ramp[:, :5], rtol=1e-12, atol=1e-12)
        assert ramp[-1, 5] == pytest.approx(ramps.steer[k], abs=1e-12)
        assert shots.g[k] == pytest.approx(np.hypot(*np.diff(one[:, :2], axis=0).T).sum(),
                                           rel=1e-12)
        assert shots.H[k] == pytest.approx(np.hypot(*(one[-1, :2] - scenario.goal[:2])))
    assert shots.valid.all()


# --- every shared map -------------------------------------------------------------------------

CELL_SIZE = {".map": 1.5, ".png": 1.0, ".pgm": 0.05}  # [m/cell]; .yaml files store their own


def free_query(omap):
    """A deterministic query: the start at the point farthest from obstacles, the goal the
    point of its free region (clearance >= 2.5 m) nearest 40 m away, both facing the goal."""
    distance = omap.distance
    step = omap.resolution / SUBDIV
    region = label(distance >= 2.5, structure=np.ones((3, 3)))[0]
    i = np.unravel_index(np.argmax(distance), distance.shape)
    candidates = np.argwhere(region == region[i])[:, ::-1] * step + omap.origin
    start = np.array(i[::-1]) * step + omap.origin
    goal = candidates[np.argmin(np.abs(np.hypot(*(candidates - start).T) - 40.0))]
    psi = float(np.arctan2(*(goal - start)[::-1]))
    return (*start, psi), (*goal, psi)


@pytest.mark.parametrize("path", sorted(p for p in MAP_DIR.iterdir() if p.suffix != ".md"),
                         ids=lambda p: p.name)
def test_every_shared_map_loads_and_a_free_query_plans(path):
    omap = load_map(path, cell_size=CELL_SIZE.get(path.suffix))
    start, goal = free_query(omap)
    result = PathFinder(omap, CONFIG, None, 5.0).plan(start, goal)
    assert result.status == "exact", result.reason


# --- reverse gear, narrow passages, the street queries ----------------------------------------

def facing_wall_map():
    """A 30 x 20 m yard; the start 0.6 m from the east wall, facing it."""
    occupied = np.zeros((40, 60), bool)
    occupied[:, -2:] = occupied[:, :2] = occupied[:2] = occupied[-2:] = True
    return from_array(occupied, 0.5)


def test_a_start_facing_a_wall_needs_reverse_gear_and_reports_its_cusps():
    from stepzoo.search.plans.path_metrics import cusps
    from stepzoo.search.plans.files import path_rows
    omap = facing_wall_map()
    start, goal = (26.0, 10.0, 0.0), (8.0, 10.0, np.pi)
    forward = PathFinder(omap, CONFIG, None, 2.0).plan(start, goal)
    assert (forward.status, forward.cause) == ("no_path", "start_boxed_in")
    # Any exact path must back away from the wall: the first one (no improvement).
    config = make_config(reverse=1, improve_expansions=0, max_seconds=3600.0)
    result = PathFinder(omap, config, None, 2.0).plan(start, goal)
    assert result.status == "exact", result.reason
    rows = path_rows(result, dynamics.vehicle(None))
    assert cusps(rows) >= 1
    # The path rows (at most 5 cm apart) never put the car on an obstacle cell.
    vehicle = dynamics.vehicle(None)
    assert not footprint_hits(omap, vehicle, rows[:, 1:4], 0.1).any()
    # Backwards edges are driven backwards: the first one moves against the heading.
    first = result.path_edges[0]
    assert np.cos(first[0, 2]) * (first[-1, 0] - first[0, 0]) < 0


def test_reverse_is_a_setting_that_reads_true_as_one():
    from stepzoo.search.planner.config import PlannerParams, with_params
    assert PlannerParams().reverse == 0 and with_params(CONFIG, reverse=True).params.reverse == 1


@pytest.mark.parametrize("qid", ["Berlin_1_256-01", "Boston_0_256-03", "den312d-02",
                                 "room-64-64-8-01"])
def test_street_queries_plan_exact_paths_that_the_dense_check_accepts(qid):
    from stepzoo.search.world.queries import STREET_QUERIES, load_queries
    from stepzoo.search.world.scenarios import custom_scenario
    query = next(q for q in load_queries(STREET_QUERIES) if q.id == qid)
    scenario = custom_scenario(query.map_path, query.cell_size, query.start, query.goal, 5.0)
    result = finder_for(scenario).plan(scenario.start, scenario.goal)
    assert result.status == "exact", result.reason
    assert result.first_solution_s <= result.solution_s
    assert [length for _, length in result.progress] == sorted(
        (length for _, length in result.progress), reverse=True)
    collisions, joint_gap, miss = dense_check(scenario, result)
    assert (collisions, joint_gap < 1e-3, miss < 1e-3) == (0, True, True)
    # Issue 34's targets, from the path rows alone: a plan the car can drive.
    from stepzoo.search.plans.path_metrics import drivability
    from stepzoo.search.plans.files import path_rows
    limits, car = dynamics.vehicles.limits(), dynamics.vehicle(None)
    wheelbase = car["Lf"] + car["Lr"]
    d = drivability(path_rows(result, car), wheelbase, np.pi / 4, **limits)
    assert d["max_curvature_1pm"] <= 1.1 * np.tan(np.pi / 4) / wheelbase
    assert d["max_steer_rate_radps"] <= 1.25 * limits["max_steer_rate"]
    assert d["max_lateral_acceleration_mps2"] <= 1.15 * limits["max_lateral_acceleration"]


def test_one_call_integrates_the_tree_tight_and_reverse_moves_as_separate_calls_do():
    """An expansion integrates the tree's moves (the dynamic bicycle at 5 m/s), its tight
    moves and its reverse moves (the kinematic bicycle at 2 m/s, forwards and backwards) in
    one compiled call (integrate_together): each shooting is the one the zoo's driver gives
    for that shooter alone, to rounding, from a moving node and from a standstill (NaN)."""
    from stepzoo.integrators import integrate_batch
    from stepzoo.search.planner.shooting import integrate_together
    recorder = Recorder()
    kinds = [dict(vx=5.0), dict(vx=2.0, tight=True), dict(vx=2.0, reverse=True)]
    shooters = [Shooter(recorder, None, k.pop("vx"), "midpoint", 0.02, 30, 4, 0.75,
                        max_steer_rate=0.32, **k) for k in kinds]
    start = np.array([[3.0, -1.0, 0.4, 0.1, 0.05], [0.0, 2.0, -2.0, 0.0, 0.0],
                      [1.0, 1.0, 3.0, -0.2, 0.1], [5.0, 0.0, 0.0, 0.0, 0.0]])
    steer, steer0 = np.array([-0.6, -0.1, 0.3, 0.7]), np.array([-0.4, np.nan, 0.2, np.nan])
    together = integrate_together([(s, start, steer, steer0) for s in shooters])
    for shooter, states in zip(shooters, together):
        x0, inputs = shooter.model_inputs(start, steer, steer0)
        alone = shooter.poses(integrate_batch(shooter.method, shooter.rhs, x0, inputs,
                                              shooter.p, shooter.h, shooter.n_steps).x)
        assert states.shape == (4, 31, 5)
        assert states == pytest.approx(alone, rel=1e-12, abs=1e-12)
        assert np.ptp(states[:, -1, 0]) > 1.0    # the shootings went their own ways
