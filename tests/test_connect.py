"""The connection OCP: analytic minimum times on straight lines, the Dubins optimum on random
problems, every bound held, a faithful discretisation, both shootings agreeing, and failure
reported as a result."""
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.dynamics.kinematic import kinematic_bicycle, rigid_bicycle, shifted
from stepzoo.dynamics.models import steered
from stepzoo.dynamics.vehicles import vehicle
from stepzoo.integrators import integrate, method
from stepzoo.search.proofs.car_bounds import reeds_shepp_length
from stepzoo.search.planner.connection_ocp import (A_MAX, _fastest_profile, connect, dubins_paths,
                                    path_poses, reeds_shepp_paths, resimulate, step_function)

CAR = vehicle("bmw320i")
L, M = CAR["Lf"] + CAR["Lr"], CAR["m"]
pi_ = np.pi


def random_problems(n, seed):
    """Start [X, Y, theta, v] and goal [X, Y, theta] 3-30 m apart, arbitrary headings."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        start = np.r_[rng.uniform(-10, 10, 2), rng.uniform(-pi_, pi_), rng.uniform(0, 10)]
        d, bearing = rng.uniform(3, 30), rng.uniform(-pi_, pi_)
        goal = np.r_[start[:2] + d * np.array([np.cos(bearing), np.sin(bearing)]),
                     rng.uniform(-pi_, pi_)]
        out.append((start, goal))
    return out


def test_straight_ahead_from_rest_takes_full_acceleration_time():
    # 30 m from rest at 4 m/s^2 never reaches 25 m/s: t = sqrt(2 D / a).
    c = connect([0, 0, 0, 0], [30, 0, 0], L=L, m=M)
    assert c.success
    assert c.tf == pytest.approx(np.sqrt(2 * 30 / A_MAX), rel=1e-6)
    np.testing.assert_allclose(c.inputs[:, 1], M * A_MAX, rtol=1e-5)


def test_straight_ahead_to_a_stop_is_bang_bang():
    # Accelerate half the way, brake the other half: t = 2 sqrt(D / a); with N even the
    # switch falls on the grid, so the discrete optimum is the continuous one.
    c = connect([0, 0, 0, 0], [30, 0, 0], L=L, m=M, goal_speed=0.0)
    assert c.success
    assert c.tf == pytest.approx(2 * np.sqrt(30 / A_MAX), rel=1e-6)


def test_straight_ahead_at_the_speed_limit_accelerates_cruises_and_brakes():
    # v_max = 5 m/s: 1.25 s up, 23.75 m at 5 m/s, 1.25 s down = 7.25 s. The switches fall
    # inside intervals, so piecewise-constant force may only lose a little time, never gain.
    c = connect([0, 0, 0, 0], [30, 0, 0], L=L, m=M, goal_speed=0.0, v_max=5.0)
    assert c.success
    assert 7.25 * (1 - 1e-7) <= c.tf <= 7.25 * (1 + 2e-3)
    assert c.states[:, 3].max() == pytest.approx(5.0, rel=1e-6)


def test_minimum_time_is_the_fastest_drive_along_the_dubins_path():
    # With free end speed the speed profile only depends on arc length and turning costs no
    # speed, so the continuous optimum drives the shortest path of curvature <= tan(d)/L at
    # full acceleration. The discrete OCP may lose a little (switches off the grid), not gain.
    radius = L / np.tan(pi_ / 4)
    for start, goal in random_problems(10, seed=1):
        c = connect(start, goal, L=L, m=M)
        assert c.success, c.status
        length = sum(q for _, q in dubins_paths(start[:3], goal, radius)[0])
        tf = _fastest_profile(length, start[3], A_MAX, 25.0, None)[2]
        assert tf * (1 - 1e-6) <= c.tf <= tf * (1 + 5e-3)


def test_solution_holds_every_bound_and_the_end_constraint():
    box = (-12.0, 22.0, -8.0, 10.0)
    start, goal = np.array([0.0, 0.0, 2.5, 3.0]), np.array([15.0, 4.0, -2.0])
    c = connect(start, goal, L=L, m=M, bounds=box, goal_speed=2.0, v_max=6.0,
                delta_max=0.6, a_max=3.0, tf_bounds=(0.5, 20.0))
    assert c.success, c.status
    tol = 1e-7
    assert 0.5 <= c.tf <= 20.0
    assert np.all(np.abs(c.inputs[:, 0]) <= 0.6 + tol)
    assert np.all(np.abs(c.inputs[:, 1]) <= M * 3.0 * (1 + tol))
    assert np.all((c.states[:, 3] >= -tol) & (c.states[:, 3] <= 6.0 + tol))
    assert c.states[:, 3].max() > 6.0 - 1e-6  # the speed limit is reached, and held
    assert np.all((box[0] - tol <= c.states[:, 0]) & (c.states[:, 0] <= box[1] + tol))
    assert np.all((box[2] - tol <= c.states[:, 1]) & (c.states[:, 1] <= box[3] + tol))
    np.testing.assert_array_equal(c.states[0], start)
    np.testing.assert_allclose(c.states[-1, :2], goal[:2], atol=1e-6)
    assert np.sin((c.states[-1, 2] - goal[2]) / 2) == pytest.approx(0, abs=1e-6)
    assert c.states[-1, 3] == pytest.approx(2.0, abs=1e-6)
    np.testing.assert_allclose(c.t, np.linspace(0, c.tf, 51))


def test_a_map_bound_across_the_shortest_path_gives_the_other_winding():
    # Unbounded, the fastest path arrives turning right and rises to Y = 7.65 m; below
    # Y = 7 m it must arrive turning left, one turn of the heading further (-2 + 2 pi).
    start, goal = np.array([0.0, 0.0, 2.5, 3.0]), np.array([15.0, 4.0, -2.0])
    free = connect(start, goal, L=L, m=M, bounds=(-12, 22, -2, 12))
    capped = connect(start, goal, L=L, m=M, bounds=(-12, 22, -2, 7))
    assert free.success and capped.success
    assert free.states[:, 1].max() > 7.5
    assert capped.states[:, 1].max() <= 7 + 1e-7
    assert free.states[-1, 2] == pytest.approx(-2.0, abs=1e-6)
    assert capped.states[-1, 2] == pytest.approx(-2.0 + 2 * pi_, abs=1e-6)
    assert capped.tf > free.tf


@pytest.mark.parametrize("v0, behind, braking_s", [(0.0, 6.0, 0.0), (5.0, 4.0, 1.25)])
def test_a_goal_behind_in_a_corridor_is_reached_by_reversing_in_minimum_time(v0, behind,
                                                                               braking_s):
    # A corridor 4 m wide has no room for a loop (turning radius 2.58 m): only reversing
    # arrives. The minimum time is braking to rest (v0 / A_MAX, covering v0^2 / (2 A_MAX)
    # ahead), then the fastest straight drive backwards at most 5 m/s, with a free end speed.
    start, goal = np.array([0.0, 0.0, 0.0, v0]), np.array([-behind, 0.0, 0.0])
    c = connect(start, goal, L=L, m=M, v_min=-5.0, bounds=(-10, 4, -2, 2))
    assert c.success, c.status
    tf = braking_s + _fastest_profile(behind + v0 ** 2 / (2 * A_MAX), 0.0, A_MAX, 5.0, None)[2]
    assert tf * (1 - 1e-6) <= c.tf <= tf * (1 + 5e-3)
    assert c.states[:, 3].min() == pytest.approx(-5.0, abs=1e-6)
    assert np.abs(c.states[:, 1]).max() <= 2 + 1e-7


def test_reeds_shepp_words_drive_to_the_goal_and_the_shortest_is_the_bound():
    rng = np.random.default_rng(4)
    radius = L / np.tan(pi_ / 4)
    for _ in range(40):
        start, goal = rng.uniform([-9, -9, -pi_], [9, 9, pi_], (2, 3))
        paths = reeds_shepp_paths(start, goal, radius)  # each kept only if it arrives
        lengths = [sum(abs(q) for _, q in segs) for segs in paths]
        assert lengths == sorted(lengths)
        assert lengths[0] == pytest.approx(reeds_shepp_length(start[None], goal, radius)[0],
                                           abs=1e-9)


def test_single_shooting_holds_the_map_bound_like_multiple():
    # Multiple shooting bounds its state variables, single shooting constrains the simulated
    # states: under the same cap both must take the other winding, in the same time.
    start, goal = np.array([0.0, 0.0, 2.5, 3.0]), np.array([15.0, 4.0, -2.0])
    box = (-12, 22, -2, 7)
    multiple = connect(start, goal, L=L, m=M, bounds=box)
    single = connect(start, goal, L=L, m=M, bounds=box, shooting="single")
    assert multiple.success and single.success
    assert single.states[:, 1].max() <= 7 + 1e-7
    assert single.states[-1, 2] == pytest.approx(-2.0 + 2 * pi_, abs=1e-6)
    assert single.tf == pytest.approx(multiple.tf, rel=1e-6)


def test_heading_crosses_the_wrap_with_the_short_turn():
    # Start at +3.0 rad, goal ahead at -3.1 rad = 3.18 rad: a 0.18 rad turn, not a loop,
    # which the paper's -pi <= theta <= pi would forbid.
    goal = np.array([20 * np.cos(3.05), 20 * np.sin(3.05), -3.1])
    c = connect([0, 0, 3.0, 5.0], goal, L=L, m=M)
    assert c.success, c.status
    assert c.states[-1, 2] == pytest.approx(2 * pi_ - 3.1, abs=1e-6)
    assert np.all(np.abs(c.states[:, 2] - 3.1) < 0.5)


def test_resimulation_on_a_finer_step_ends_at_the_goal():
    for start, goal in random_problems(5, seed=2):
        c = connect(start, goal, L=L, m=M)
        assert c.success, c.status
        xs = resimulate(c, L=L, m=M, refine=10)
        assert xs.shape == (50 * 10 + 1, 4)
        np.testing.assert_allclose(xs[::10], c.states, atol=1e-3)
        assert np.hypot(*(xs[-1, :2] - goal[:2])) < 1e-3


def test_both_shootings_solve_random_problems_and_agree():
    for start, goal in random_problems(6, seed=3):
        multiple = connect(start, goal, L=L, m=M, shooting="multiple")
        single = connect(start, goal, L=L, m=M, shooting="single")
        assert multiple.success and single.success
        assert (multiple.shooting, single.shooting) == ("multiple", "single")
        assert single.tf == pytest.approx(multiple.tf, rel=1e-6)


def test_goal_outside_the_map_is_a_failure_not_an_exception(capfd):
    c = connect([0, 0, 0, 0], [30, 0, 0], L=L, m=M, bounds=(-5, 20, -5, 5))
    assert not c.success
    assert c.status != "Solve_Succeeded"
    assert c.states.shape == (51, 4) and c.inputs.shape == (50, 2)
    assert capfd.readouterr().out == ""


def test_solving_prints_nothing(capfd):
    connect([0, 0, 1.0, 2.0], [-4, 6, -2.0], L=L, m=M, bounds=(-20, 20, -20, 20))
    assert capfd.readouterr().out == ""


def test_same_inputs_give_the_same_connection():
    a, b = random_problems(2, seed=4)
    first = connect(*a, L=L, m=M)
    connect(*b, L=L, m=M)  # the cached problem is reused in between
    again = connect(*a, L=L, m=M)
    assert (first.success, first.status, first.tf) == (again.success, again.status, again.tf)
    np.testing.assert_array_equal(first.states, again.states)
    np.testing.assert_array_equal(first.inputs, again.inputs)


@pytest.mark.parametrize("name", ["euler", "heun", "midpoint", "rk3", "rk4", "dopri5"])
def test_casadi_step_is_the_zoo_step(name):
    """The OCP's CasADi step is the zoo's JAX step of the same model: the paper's kinematic
    bicycle, and steered, the rigid car (dynamics kinematic_cg) with its steer a state."""
    x, u, h = np.array([1.0, -2.0, 0.7, 8.0]), np.array([0.3, 2500.0]), 0.05
    ours = np.asarray(step_function(name)(x, u, h, L, M, CAR["Lr"])).ravel()
    zoo = integrate(method(name), kinematic_bicycle, jnp.asarray(x), jnp.asarray(u),
                    {"L": L, "m": M}, h, 1).x[1]
    np.testing.assert_allclose(ours, np.asarray(zoo), rtol=1e-13, atol=1e-13)
    x5, rate = np.r_[x, 0.3], np.array([-0.32, 2500.0])
    ours = np.asarray(step_function(name, True)(x5, rate, h, L, M, CAR["Lr"])).ravel()
    zoo = integrate(method(name), steered(rigid_bicycle), jnp.asarray(x5), jnp.asarray(rate),
                    {"L": L, "m": M, "Lr": CAR["Lr"]}, h, 1).x[1]
    np.testing.assert_allclose(ours, np.asarray(zoo), rtol=1e-13, atol=1e-13)


def test_implicit_methods_are_refused():
    with pytest.raises(ValueError, match="implicit"):
        step_function("radau_iia3")


def test_below_the_steer_speed_the_steer_turns_per_metre_not_by_crawling():
    """A goal 3 m ahead and 6 m to the left, facing back: under a steer rate alone the
    minimum-time car crawls (below 1 m/s) to turn the wheel by more than 0.3 rad per metre;
    with steer_speed 2 m/s, between every two nodes (from the states alone) the steer turns
    at most rate / steer_speed per metre travelled, the standstill allowance aside."""
    from stepzoo.search.planner.connection_ocp import STANDSTILL_RATE
    rate, v_steer = 0.32, 2.0
    kwargs = dict(L=L, m=M, N=50, steer0=0.0, max_steer_rate=rate,
                  max_lateral_acceleration=9.2)
    start, goal = [0.0, 0.0, 0.0, 5.0], [3.0, 6.0, pi_]

    def per_metre(conn):
        steer = np.r_[conn.inputs[:, 0], conn.inputs[-1, 0] + conn.steer_rates[-1] * conn.tf
                      / len(conn.inputs)]
        travel = np.hypot(*np.diff(conn.states[:, :2], axis=0).T)
        return np.abs(np.diff(steer)), travel, conn.tf / len(conn.inputs)

    crawl = connect(start, goal, **kwargs)
    turned, travel, _ = per_metre(crawl)
    assert crawl.success and crawl.states[:, 3].min() < 1.0
    assert (turned / travel).max() > 0.3
    bounded = connect(start, goal, steer_speed=v_steer, **kwargs)
    turned, travel, dt = per_metre(bounded)
    assert bounded.success
    assert np.all(turned <= rate / v_steer * travel + STANDSTILL_RATE * rate * dt + 1e-6)
    assert bounded.states[:, 3].min() > 1.0


def test_a_connection_that_would_collide_is_kept_within_its_guess_room():
    """A left turn of 90 degrees at 2 m/s past a block on the inside of the rate-limited
    turn: the Dubins path (left, straight, left, at full lock) clears it, the obstacle-blind
    OCP, whose steer ramps, swings through it. With the corridor the OCP is solved again,
    each disc of the body at each node within its guess disc's clearance: the car's discs
    (the footprint the planner checks) touch nothing at any node or between them."""
    from stepzoo.search.planner.connection_ocp import Corridor
    from stepzoo.search.world.footprint import Footprint, first_collision
    from stepzoo.search.world.maps import from_array
    footprint = Footprint.from_vehicle(CAR["length"] + 0.2, CAR["width"] + 0.2, 6)
    occupied = np.zeros((120, 120), bool)
    occupied[12:24, 40:48] = True      # x 10..12 m, y 3..6 m at 0.25 m/cell
    omap = from_array(occupied, 0.25)
    start, goal = np.array([5.0, 5.0, 0.0, 2.0]), np.array([13.0, 13.0, pi_ / 2])
    limits = dict(L=L, m=M, delta_max=pi_ / 4, max_steer_rate=0.32,
                  max_lateral_acceleration=9.2)

    def first_hit(conn):
        return first_collision(omap, footprint, conn.states[None, :, :3])[0]

    radius = L / np.tan(pi_ / 4)
    guess = path_poses(start[:3], dubins_paths(start[:3], goal, radius)[0], radius, 0.2)
    assert first_collision(omap, footprint, guess[None])[0] < 0
    blind = connect(start, goal, **limits)
    assert blind.success and first_hit(blind) >= 0
    corridor = Corridor(footprint.offsets, footprint.radius, omap.clearance)
    kept = connect(start, goal, **limits, corridor=corridor)
    assert kept.success and first_hit(kept) < 0
    assert np.abs(kept.states[-1, :3] - goal).max() < 1e-6
    # Where the blind solution is free, the corridor changes nothing.
    free = connect(start, goal, **limits, corridor=Corridor(
        footprint.offsets, footprint.radius, from_array(occupied * 0, 0.25).clearance))
    assert free.tf == blind.tf and np.array_equal(free.states, blind.states)


def test_a_rate_limited_guess_starts_its_states_on_the_path():
    """Seeded near-goal problems (2-12 m, any headings, 0-5 m/s, the wheel already turned),
    one IPOPT solve each: the multiple shooting's states started on the guess's path (the
    crawl guess, or before it the path's poses with a ramped steer) solve at least 27 of
    30; started on the rollout of the guess's ramped steer, which lags the path's turns and
    ends metres off the goal, 20 of 30 solved."""
    from stepzoo.search.planner import connection_ocp
    rng = np.random.default_rng(1)
    solved = 0
    for _ in range(30):
        start = np.r_[rng.uniform(-10, 10, 2), rng.uniform(-pi_, pi_), rng.uniform(0, 5)]
        d, bearing = rng.uniform(2, 12), rng.uniform(-pi_, pi_)
        goal = np.r_[start[:2] + d * np.array([np.cos(bearing), np.sin(bearing)]),
                     rng.uniform(-pi_, pi_)]
        steer0 = rng.uniform(-0.5, 0.5)
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(connection_ocp, "MAX_TRIES", 1)
            c = connect(start, goal, L=L, m=M, steer0=steer0, max_steer_rate=0.32,
                        max_lateral_acceleration=9.2)
        solved += c.success
    assert solved >= 27


def _wall_corridor(margin=0.2):
    """A wall filling x < 10 m of a 40 m square map (0.25 m cells), the car's footprint plus
    `margin` [m] on every side and its corridor."""
    from stepzoo.search.planner.connection_ocp import Corridor
    from stepzoo.search.world.footprint import Footprint
    from stepzoo.search.world.maps import from_array
    footprint = Footprint.from_vehicle(CAR["length"] + 2 * margin, CAR["width"] + 2 * margin, 6)
    occupied = np.zeros((160, 160), bool)
    occupied[:, :40] = True
    omap = from_array(occupied, 0.25)
    return omap, footprint, Corridor(footprint.offsets, footprint.radius, omap.clearance)


def _first_hit(conn, omap, footprint):
    from stepzoo.search.world.footprint import first_collision
    return first_collision(omap, footprint, conn.states[None, :, :3])[0]


@pytest.mark.parametrize("speed", [3.0, 5.0])
def test_a_corridor_lets_a_disc_beside_a_wall_move_away_from_it(speed, monkeypatch):
    """A car driving south 6 m from a wall at `speed` [m/s] turns round towards it to stop 3 m
    from it facing north-west: the rate-limited OCP swings into the wall, and each disc of the
    Dubins guess beside the wall has a ball of room about itself no wider than its gap to the
    wall. The corridor's balls may lie beside the disc, as wide as the space allows with the
    disc still inside: solved, the car's footprint touches nothing at any node where the
    guess's discs are free (the corridor's promise; where a guess disc touches the wall, its
    sliver of room keeps it there, and the planner's own collision check refuses the
    connection: where IPOPT's first solve rounds otherwise, the corridor is built from a
    guess that touches at two nodes)."""
    from stepzoo.search.planner import connection_ocp
    from stepzoo.search.planner.connection_ocp import _rooms
    from stepzoo.search.world.footprint import first_collision
    omap, footprint, corridor = _wall_corridor()
    guesses = []
    monkeypatch.setattr(connection_ocp, "_rooms", lambda corridor, centres: (
        guesses.append(np.asarray(centres)) or _rooms(corridor, centres)))
    start, goal = np.array([16.0, 10.0, -pi_ / 2, speed]), np.array([13.0, 10.0, 2.0])
    conn = connect(start, goal, L=L, m=M, delta_max=pi_ / 4, max_steer_rate=0.32,
                   max_lateral_acceleration=9.2, bounds=(0, 40, 0, 40), corridor=corridor)
    assert conn.success
    poses = conn.states[:, :3]
    hit = first_collision(omap, footprint, poses[:, None]) >= 0         # each node alone
    guess_touches = np.zeros(len(poses), bool)                         # node 0 is the start
    if guesses:                                    # the last corridor built: the solution's
        guess_touches[1:] = (corridor.clearance(guesses[-1]) <= corridor.radius).any(axis=1)
    assert not (hit & ~guess_touches).any()
    # Every ball is free of obstacles and holds its disc.
    discs = np.array([[12.0, 5.0], [13.5, 20.0], [22.0, 20.0], [11.2, 30.0]])
    centres, room = _rooms(corridor, discs)
    assert np.all(omap.clearance(centres) - corridor.radius >= room - 1e-12)
    assert np.all(np.hypot(*(centres - discs).T) <= room + 1e-12)
    assert room[2] > omap.clearance(discs[2:3])[0] - corridor.radius - 1e-12


def test_the_corridors_guess_is_the_rigid_car_its_rear_axle_rolling_along_its_body(
        monkeypatch):
    """Steered, the guess drives the rigid car's rear axle (Lr behind its centre of gravity)
    on the Dubins word, and the corridor's discs sit along the body from the centre of
    gravity: between the guess's poses the rear axle moves along the body's heading (it
    rolls without sliding), the centre of gravity does not where the car turns (it moves at
    the slip beside the body), and the guess starts at the start's centre of gravity."""
    from stepzoo.search.planner import connection_ocp
    from stepzoo.search.planner.connection_ocp import Corridor
    from stepzoo.search.world.footprint import Footprint
    from stepzoo.search.world.maps import from_array
    footprint = Footprint.from_vehicle(CAR["length"] + 0.2, CAR["width"] + 0.2, 6)
    occupied = np.zeros((120, 120), bool)
    occupied[12:24, 40:48] = True
    omap = from_array(occupied, 0.25)
    seen = []
    real = connection_ocp._disc_centres
    monkeypatch.setattr(connection_ocp, "_disc_centres", lambda corridor, poses: (
        seen.append(np.asarray(poses, float)) or real(corridor, poses)))
    start = np.array([5.0, 5.0, 0.0, 2.0])
    conn = connect(start, np.array([13.0, 13.0, pi_ / 2]), L=L, m=M, Lr=CAR["Lr"],
                   delta_max=pi_ / 4, max_steer_rate=0.32, max_lateral_acceleration=9.2,
                   corridor=Corridor(footprint.offsets, footprint.radius, omap.clearance))
    assert conn.success and len(seen) >= 2      # the touching check's, then the guess's
    guess = np.vstack([start[:3] - (*start[:2], 0.0), seen[-1]])   # relative to the start

    def drift(points, heading):
        """|direction of each chord between poses that moves - the mean heading|."""
        chord = np.diff(points, axis=0)
        mid = (heading[1:] + heading[:-1]) / 2
        moves = np.hypot(chord[:, 0], chord[:, 1]) > 1e-6
        return np.abs(np.remainder(np.arctan2(chord[:, 1], chord[:, 0]) - mid + pi_, 2 * pi_)
                      - pi_)[moves]

    rear = shifted(guess, -CAR["Lr"])
    assert drift(rear[:, :2], guess[:, 2]).max() < 0.02
    assert drift(guess[:, :2], guess[:, 2]).max() > 0.3
    assert np.abs(guess[0] - (0.0, 0.0, 0.0)).max() < 1e-12


def test_a_rate_limited_connection_ends_on_the_goal_pose_with_its_wheel_turned():
    """The rigid car's state is its centre of gravity and its body's heading: a connection
    that arrives turning (a goal 6 m ahead and 4 m to the left, facing left, from 3 m/s) ends
    with them on the goal pose, its wheel still turned; re-integrated finely on the rigid
    car (resimulate, rk4 on a 10 times finer step) it ends within a centimetre of it, as
    the same problem on the paper's bicycle (Lr = 0, the rear axle's point) does, at
    another end steer."""
    start, goal = [0.0, 0.0, 0.0, 3.0], np.array([6.0, 4.0, pi_ / 2])
    limits = dict(L=L, m=M, max_steer_rate=0.32, max_lateral_acceleration=9.2)
    conn = connect(start, goal, Lr=CAR["Lr"], **limits)
    end_steer = conn.inputs[-1, 0] + conn.steer_rates[-1] * conn.tf / len(conn.inputs)
    assert conn.success and abs(end_steer) > 0.1
    assert np.abs(conn.states[-1, :3] - goal).max() < 1e-6
    fine = resimulate(conn, L=L, m=M, Lr=CAR["Lr"])
    assert np.abs(fine[-1, :2] - goal[:2]).max() < 0.01
    axle = connect(start, goal, **limits)
    assert axle.success and np.abs(axle.states[-1, :3] - goal).max() < 1e-6
    assert np.abs(resimulate(axle, L=L, m=M)[-1, :2] - goal[:2]).max() < 0.01
    assert abs(axle.inputs[-1, 0] - conn.inputs[-1, 0]) > 0.01


def test_the_rate_limited_guess_is_a_motion_of_the_car():
    """_crawl_guess drives each Dubins word from rest at its first steer: at its turns'
    steers, the wheel turned at the rate limit standing. Its states at N+1 equal times are
    a motion of the steered kinematic bicycle: driven from each node under the guess's
    interval rates (steer rate, acceleration), each interval ends within 1 cm of the next
    node at N = 200 (the nodes sample a finer table: the gap shrinks as N grows), every
    steer rate within the limit; it ends at the goal at rest, the wheel straight."""
    from stepzoo.search.planner.connection_ocp import _crawl_guess
    radius, start, goal = L, np.zeros(3), np.array([8.0, 6.0, 2.5])
    for segs in dubins_paths(start, goal, radius)[:3]:
        gaps = {}
        for N in (50, 200):
            tf, Z = _crawl_guess(N, start, 0.0, segs[0][0] * pi_ / 4, segs, radius, pi_ / 4,
                                 0.32, A_MAX, 25.0, 0.0, 9.2, None)
            dt, gap = tf / N, 0.0
            rates = np.diff(Z[3:], axis=1) / dt
            assert np.abs(rates[1]).max() <= 0.32 + 1e-9
            for k in range(N):
                x = jnp.asarray(np.r_[Z[:4, k], Z[4, k]])
                traj = integrate(method("rk4"), _steered_rhs, x, jnp.asarray(rates[::-1, k]),
                                 {"L": L, "m": M}, dt / 20, 20)
                gap = max(gap, float(np.abs(np.asarray(traj.x[-1, :2]) - Z[:2, k + 1]).max()))
            gaps[N] = gap
            np.testing.assert_allclose(Z[:, -1], np.r_[goal[:2], Z[2, -1], 0.0, 0.0],
                                       atol=1e-9)
            assert np.sin((Z[2, -1] - goal[2]) / 2) == pytest.approx(0, abs=1e-9)
        assert gaps[200] < 0.01 and gaps[200] < gaps[50] / 4


def _steered_rhs(t, x, u, p):
    """The kinematic bicycle with its steer a state, driven by u = [steer rate, acceleration]
    ([rad/s, m/s^2])."""
    return jnp.r_[kinematic_bicycle(t, x[:4], jnp.r_[x[4], u[1] * p["m"]], p), u[0]]


def test_a_solve_whose_line_search_keeps_cutting_the_step_is_given_up(monkeypatch):
    """The stall watch stops IPOPT once SHORT_STEPS of its iterations took a primal step
    below SHORT_STEP: counted short at every step (SHORT_STEP above 1), a problem that
    otherwise solves is given up after that many iterations, status STALLED."""
    from stepzoo.search.planner import connection_ocp
    start, goal = [0, 0, 0, 0], [30, 0, 0]
    assert connect(start, goal, L=L, m=M).success
    monkeypatch.setattr(connection_ocp, "SHORT_STEP", 1.5)
    monkeypatch.setattr(connection_ocp, "SHORT_STEPS", 2)
    c = connect(start, goal, L=L, m=M)
    assert not c.success and c.status == connection_ocp.STALLED


def test_a_ctrl_c_during_a_solve_stops_it_and_comes_out_of_connect(monkeypatch):
    """A KeyboardInterrupt raised in IPOPT's iteration callback (the one place Python runs
    during a solve, so where a Ctrl-C lands) stops the solve at once and comes out of
    connect, where CasADi swallowed it and solved on; the next solve runs as usual."""
    from stepzoo.search.planner import connection_ocp
    calls = []

    def interrupted(self):
        calls.append(1)
        raise KeyboardInterrupt

    monkeypatch.setattr(connection_ocp._StallWatch, "_stop", interrupted)
    with pytest.raises(KeyboardInterrupt):
        connect([0, 0, 0, 0], [30, 5, 0.5], L=L, m=M)
    assert len(calls) == 1
    monkeypatch.undo()
    assert connect([0, 0, 0, 0], [30, 5, 0.5], L=L, m=M).success


def test_improve_attempts_ends_the_improvement_after_that_many_attempts_without_a_shorter_path():
    """improve_attempts = K ends a plan once K connection attempts in a row after its best
    path have not shortened it: the plan is the unbounded one cut there (its shorter paths a
    prefix of the unbounded plan's), and a K the unbounded plan's longest run of fruitless
    attempts never reaches (as many as it makes) changes nothing. open_field with the
    regression plans' config (no clock: its plans end by themselves) finds its first path at
    the 1st attempt and a shorter one later, not at the 2nd."""
    from pathlib import Path
    from stepzoo.search.planner.config import load_config, with_params
    from stepzoo.search.planner.pathfinder import PathFinder
    from stepzoo.search.world.scenarios import load_scenario
    scenario = load_scenario("open_field")
    # The regression plans' config: `stepzoo run`'s tuned step, and no clock.
    config = load_config(Path(__file__).parent / "data" / "plan_regression" / "config.toml")

    def plan(**params):
        finder = PathFinder(scenario.omap, with_params(config, **params), scenario.vehicle,
                            scenario.speed)
        return finder.plan(scenario.start, scenario.goal, scenario.goal_speed, seed=0)

    free, one = plan(), plan(improve_attempts=1)
    lengths = [length for _, length in free.progress]
    assert len(lengths) >= 2 and "(attempt 1)" in free.reason
    assert [length for _, length in one.progress] == lengths[:1]
    assert one.connect_attempts == 2 and one.status == "exact"
    assert one.reason.endswith("no shorter path in 1 connection attempts")
    assert one.path_length() > free.path_length()
    never = plan(improve_attempts=free.connect_attempts)
    assert [length for _, length in never.progress] == lengths
    assert never.connect_attempts == free.connect_attempts
    assert all(np.array_equal(a, b) for a, b in zip(never.path_edges, free.path_edges))
    assert len(never.path_edges) == len(free.path_edges)
