"""A plan a car can drive (issue 34): the drivability block's measures agree with paths whose
curvature and steer rate are known (a circle, a steer ramp driven by SciPy) and with an
independent finite difference of a plan's rows; the default planner's plans keep within the
car's limits where the paper's instant steering does not; reversing is used where it is
needed and priced so that it is not used where it is not."""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stepzoo.dynamics.vehicles import limits, vehicle
from stepzoo.search.world.maps import from_array
from stepzoo.search.plans.path_metrics import TOLERANCE, drivability
from stepzoo.search.planner.pathfinder import PathFinder
from stepzoo.search.plans.files import path_rows
from stepzoo.search.planner.config import load_config, make_config, with_params
from stepzoo.search.world.scenarios import load_scenario

CAR = vehicle()
L = CAR["Lf"] + CAR["Lr"]
LIMITS = limits()


def measure(rows):
    return drivability(rows, L, math.pi / 4, **LIMITS)


def rows_of(ts, poses):
    """Path rows [t, X, Y, psi] as plan.json holds them: rounded to 1e-6."""
    return np.round(np.column_stack([ts, poses]), 6)


def test_a_circle_has_its_curvature_and_lateral_acceleration_and_no_steer_rate():
    radius, v = 8.0, 5.0
    ts = np.arange(0.0, 6.0, 0.01)
    a = v * ts / radius
    rows = rows_of(ts, np.column_stack([radius * np.sin(a), radius * (1 - np.cos(a)),
                                        a]))
    d = measure(rows)
    assert d["max_curvature_1pm"] == pytest.approx(1 / radius, rel=1e-3)
    assert d["max_lateral_acceleration_mps2"] == pytest.approx(v ** 2 / radius, rel=2e-3)
    assert d["max_steer_rate_radps"] < 1e-3
    assert d["reverse_length_m"] == 0.0 and d["cusps"] == 0 and d["drivable"]


@pytest.mark.parametrize("rate", [0.3, 2.0])
def test_a_steer_ramp_driven_by_scipy_shows_its_rate_and_a_fast_one_is_not_drivable(rate):
    """The kinematic bicycle at a speed that slows to a stop and speeds up again, its steer
    ramping at `rate` [rad/s] from -0.5 rad to 0.5 rad, then held for a second: the implied
    steer rate is the ramp's, the curvature the held steer's, read from the heading column
    or from the course of (X, Y)."""
    def f(t, x):
        v = 4.0 * abs(math.cos(0.4 * t))
        delta = min(-0.5 + rate * t, 0.5)
        return [v * math.cos(x[2]), v * math.sin(x[2]), v * math.tan(delta) / L]
    duration = 1.0 / rate + 1.0
    ts = np.linspace(0.0, duration, 2001)
    sol = solve_ivp(f, (0.0, duration), [0.0, 0.0, 0.0], t_eval=ts, rtol=1e-11, atol=1e-12)
    rows = rows_of(ts, sol.y.T)
    # Its (X, Y) moves along its heading: read from either, the same measures.
    for d in (measure(rows), drivability(rows, L, math.pi / 4, **LIMITS, heading="course")):
        assert d["max_steer_rate_radps"] == pytest.approx(rate, rel=0.03)
        assert d["max_curvature_1pm"] == pytest.approx(math.tan(0.5) / L, rel=0.03)
        assert d["drivable"] is (rate <= LIMITS["max_steer_rate"])


def test_the_dynamic_car_shows_its_steer_ramp_in_its_heading_but_its_course_overshoots():
    """The linear-tyre dynamic bicycle (paper eq. 4, written here in plain NumPy) at 5 m/s,
    its steer ramped at 0.3 rad/s from 0 to 0.3 rad, driven by SciPy: read from the heading
    column (its body), the measure shows the ramp's rate; read from the centre of gravity's
    course of (X, Y), nearly twice that, as the front tyre's force moves the centre of
    gravity sideways before the body turns. So the block reads the heading column, and a
    plan's (X, Y) course reads about twice the steer rate wherever its fast moves ramp."""
    from stepzoo.dynamics.models import model
    p = model("dynamic5").params(CAR["name"], 5.0)
    vx, rate = 5.0, 0.3

    def f(t, x):
        _, _, psi, vy, r = x
        delta = rate * min(max(t - 0.5, 0.0), 1.0)
        front = p["Caf"] * (delta - (vy + p["Lf"] * r) / vx)
        rear = p["Car"] * (p["Lr"] * r - vy) / vx
        return [vx * math.cos(psi) - vy * math.sin(psi), vx * math.sin(psi) + vy * math.cos(psi),
                r, (front + rear) / p["m"] - vx * r, (p["Lf"] * front - p["Lr"] * rear) / p["Iz"]]
    ts = np.linspace(0.0, 3.0, 3001)
    sol = solve_ivp(f, (0.0, 3.0), [0.0] * 5, t_eval=ts, rtol=1e-11, atol=1e-12, max_step=0.01)
    rows = rows_of(ts, sol.y[:3].T)
    by_heading = measure(rows)["max_steer_rate_radps"]
    by_course = drivability(rows, L, math.pi / 4, **LIMITS, heading="course")
    assert by_heading == pytest.approx(rate, rel=0.02)
    assert 1.6 * rate < by_course["max_steer_rate_radps"] < 2.2 * rate


@pytest.mark.parametrize("rate", [0.3, 0.6])
def test_a_rigid_car_read_at_its_rear_axle_shows_its_steer_ramp_where_its_course_cannot(rate):
    """A rigid car's kinematic bicycle at its centre of gravity (Rajamani eqs 2.26-2.29,
    written here in plain NumPy), driven by SciPy: 3 m straight at 2 m/s, a stop, the wheel
    turned to 0.3 rad standing, then off at 2 m/s with the steer ramping at `rate` [rad/s] to
    -0.3 rad. Its centre of gravity sets off 0.16 rad aside of where it stopped heading and
    its course turns with the slip, so the course of (X, Y) reads many times the ramp; the
    rear axle's course (lr behind along psi) reads the ramp, and tan(0.3) / L."""
    lr = CAR["Lr"]

    def plan(t):                      # [s] -> (speed [m/s], steer [rad])
        if t < 1.5:
            return 2.0, 0.0
        if t < 2.5:
            return 0.0, 0.3 * (t - 1.5)
        return 2.0, max(0.3 - rate * max(t - 3.5, 0.0), -0.3)

    def f(t, x):
        v, delta = plan(t)
        beta = math.atan(lr * math.tan(delta) / L)
        return [v * math.cos(x[2] + beta), v * math.sin(x[2] + beta),
                v * math.cos(beta) * math.tan(delta) / L]
    duration = 4.0 + 0.6 / rate
    ts = np.linspace(0.0, duration, int(duration * 500) + 1)
    sol = solve_ivp(f, (0.0, duration), [0.0] * 3, t_eval=ts, rtol=1e-11, atol=1e-12,
                    max_step=0.002)
    rows = rows_of(ts, sol.y.T)
    rear = drivability(rows, L, math.pi / 4, **LIMITS, heading="rear_axle", lr=lr)
    course = drivability(rows, L, math.pi / 4, **LIMITS, heading="course")
    # within the noise of plan.json's 1e-6 m rounding over a 2 m/s window (about 0.03 rad/s)
    assert rear["max_steer_rate_radps"] == pytest.approx(rate, abs=0.04)
    assert rear["max_curvature_1pm"] == pytest.approx(math.tan(0.3) / L, rel=0.02)
    assert rear["drivable"] is (rate <= LIMITS["max_steer_rate"])
    assert course["max_steer_rate_radps"] > 3 * rate


def test_a_rigid_car_that_stops_within_a_step_reads_its_steer_ramp_on_both_sides():
    """The rigid car (as above, plain NumPy and SciPy) backing at 6 m/s braking at 3 m/s^2
    to a stop at t = 2 s and on forwards, its steer ramping at 0.3 rad/s from -0.6 rad,
    sampled every 0.0677 s (a connection's intervals) so that the stop falls inside a step:
    the step's chord runs partly back and partly on, its direction neither run's. Read at the
    rear axle, the ramp (within 0.05 rad/s; it read 0.70, twice the limit, when that chord
    and the step from one run's last course to the next's first were read as runs' ends)."""
    lr = CAR["Lr"]

    def f(t, x):
        v, delta = 3.0 * (t - 2.0), -0.6 + 0.3 * t
        beta = math.atan(lr * math.tan(delta) / L)
        return [v * math.cos(x[2] + beta), v * math.sin(x[2] + beta),
                v * math.cos(beta) * math.tan(delta) / L]
    ts = np.arange(0.01, 4.0, 0.0677)
    assert not np.isclose(ts, 2.0, atol=0.005).any()        # the stop is inside a step
    sol = solve_ivp(f, (0.0, 4.0), [0.0] * 3, t_eval=ts, rtol=1e-11, atol=1e-12,
                    max_step=0.002)
    rear = drivability(rows_of(ts, sol.y.T), L, math.pi / 4, **LIMITS, heading="rear_axle",
                       lr=lr)
    assert rear["cusps"] == 1
    assert rear["max_steer_rate_radps"] == pytest.approx(0.3, abs=0.05)
    assert rear["drivable"]


def test_driving_backwards_is_counted_and_a_cusp_splits_the_measures():
    ts = np.linspace(0.0, 8.0, 801)
    x = np.where(ts < 4.0, 5.0 * ts, 20.0 - 2.0 * (ts - 4.0))  # 20 m on, 8 m back
    rows = rows_of(ts, np.column_stack([x, np.zeros_like(x), np.zeros_like(x)]))
    d = measure(rows)
    assert d["reverse_length_m"] == pytest.approx(8.0, abs=0.02)
    assert d["cusps"] == 1 and d["max_curvature_1pm"] == 0 and d["max_steer_rate_radps"] == 0


def test_turning_the_wheel_at_a_cusp_is_no_steer_rate():
    """10 m straight on at 2 m/s, a stop, the wheel turned to 0.3 rad while stopped, then 4 m
    back on the arc of that steer: the centre of gravity sets off asin(Lr tan(0.3) / L)
    aside of the heading it stopped with (0.2 rad here). The runs' curvatures are 0 and tan(0.3) / L; the
    steer is constant in each run, so no steer rate, whatever the cusp's row holds."""
    kappa = math.tan(0.3) / L
    on = np.linspace(0.0, 5.0, 501)
    back = np.linspace(0.0, 2.0, 201)[1:]
    theta = 0.2 - kappa * 2.0 * back      # backwards at 2 m/s, turning right
    x = 10.0 - np.r_[0.0, np.cumsum(2.0 * 0.01 * np.cos(theta))][1:]
    y = -np.r_[0.0, np.cumsum(2.0 * 0.01 * np.sin(theta))][1:]
    rows = np.vstack([rows_of(on, np.column_stack([2.0 * on, 0 * on, 0 * on])),
                      rows_of(5.0 + back, np.column_stack([x, y, theta]))])
    d = measure(rows)
    assert d["cusps"] == 1 and d["reverse_length_m"] == pytest.approx(4.0, abs=0.01)
    assert d["max_curvature_1pm"] == pytest.approx(kappa, rel=0.02)
    assert d["max_steer_rate_radps"] < 0.05 and d["drivable"]


def finite_difference(rows, dt=0.1):
    """(max |curvature| [1/m], max implied steer rate [rad/s]) of path rows, by a route of
    its own: the rows resampled every `dt` s, the heading's and the position's central
    differences over two samples (where the car moves at least 1 cm), np.gradient of the
    implied steer over the samples' times."""
    t = np.arange(rows[0, 0], rows[-1, 0], dt)
    heading = np.interp(t, rows[:, 0], np.unwrap(rows[:, 3]))
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(rows[:, 1:3], axis=0).T))]
    s = np.interp(t, rows[:, 0], s)
    travel, turn = s[2:] - s[:-2], heading[2:] - heading[:-2]
    moving = travel > 0.01
    kappa = turn[moving] / travel[moving]
    steer = np.arctan(L * kappa)
    return np.abs(kappa).max(), np.abs(np.gradient(steer, t[1:-1][moving])).max()


@pytest.fixture(scope="module")
def plans():
    """wall_between with the default (rate-limited) planner and the paper's instant one."""
    scenario = load_scenario("wall_between")
    out = {}
    for steering in ("rate_limited", "instant"):
        config = with_params(load_config(), steering=steering, max_seconds=3600.0)
        finder = PathFinder(scenario.omap, config, scenario.vehicle, scenario.speed)
        result = finder.plan(scenario.start, scenario.goal, scenario.goal_speed)
        assert result.status == "exact", result.reason
        out[steering] = path_rows(result, finder.vehicle)
    return out


def test_the_rows_finite_difference_agrees_and_only_the_rate_limited_plan_is_drivable(plans):
    d = measure(plans["rate_limited"])
    kappa, rate = finite_difference(plans["rate_limited"])
    assert d["max_curvature_1pm"] == pytest.approx(kappa, rel=0.05)
    assert d["max_steer_rate_radps"] == pytest.approx(rate, rel=0.25)
    assert d["drivable"]
    assert d["max_curvature_1pm"] <= TOLERANCE["curvature_1pm"] * math.tan(math.pi / 4) / L
    # The paper's instant steering jumps between edges: many times the car's steer rate.
    instant = measure(plans["instant"])
    assert finite_difference(plans["instant"])[1] > 4 * LIMITS["max_steer_rate"]
    assert instant["max_steer_rate_radps"] > 4 * LIMITS["max_steer_rate"]
    assert not instant["drivable"]


def plan_on(occupied, start, goal, **params):
    omap = from_array(occupied, 0.5)
    config = make_config(reverse=1, max_seconds=3600.0, **params)
    finder = PathFinder(omap, config, None, 2.0)
    result = finder.plan(start, goal)
    assert result.status == "exact", result.reason
    rows = path_rows(result, finder.vehicle)
    return measure(rows), result, rows


def test_a_dead_end_is_left_backwards():
    """A corridor 3.2 m wide, closed ahead of the car: the goal behind it, facing the other
    way, is reached only by backing out of it (all the way, or with a cusp: the start is a
    standstill, so setting off backwards is none)."""
    grid = np.zeros((60, 80), bool)
    grid[:, :2] = grid[:, -2:] = grid[:2] = grid[-2:] = True
    grid[:24, 40:] = grid[30:, 40:] = True  # the corridor: rows 24..29 (y 12..15 m), x >= 20 m
    d, result, rows = plan_on(grid, (34.0, 13.5, 0.0), (8.0, 20.0, math.pi / 2),
                              improve_expansions=100)
    assert d["reverse_length_m"] >= 10.0  # out of the corridor, whose mouth is 14 m behind
    # The plan's cost is its length, a metre backwards counting reverse_penalty (3) metres,
    # and cusp_cost (5 m) per change of direction. The planner tells a step's direction by
    # its speeds, the rows by its displacement: at a cusp the speed passes zero inside one
    # step, which each may count the other way ((3 - 1) times that step's length apart).
    # The rows between the connection's nodes are the model's own states, so their length
    # passes the nodes' chords by a little, each metre counted at most 3 times.
    steps = np.hypot(*np.diff(rows[:, 1:3], axis=0).T)
    forwards = result.path_length() - d["reverse_length_m"]
    cost = forwards + 3.0 * d["reverse_length_m"] + 5.0 * d["cusps"]
    assert result.progress[-1][1] == pytest.approx(
        cost, rel=1e-9, abs=(3.0 - 1.0) * d["cusps"] * steps.max()
        + 3.0 * abs(steps.sum() - result.path_length()))


def test_an_open_field_is_crossed_forwards():
    """Goal 25 m ahead, turned a quarter: forwards is the way a driver goes, from the first
    exact path on (no improvement)."""
    grid = np.zeros((80, 100), bool)
    grid[:, :2] = grid[:, -2:] = grid[:2] = grid[-2:] = True
    d, _, _ = plan_on(grid, (10.0, 20.0, 0.0), (35.0, 28.0, math.pi / 2), improve_expansions=0)
    assert d["reverse_length_m"] == 0.0 and d["cusps"] == 0


def test_a_goal_straight_behind_is_reached_forwards_at_5_mps():
    """Goal 25 m straight behind the car, facing its way, in an open field, the tree at
    5 m/s: backing there costs reverse_penalty (3) x 25 = 75 m, turning round less, so the
    plan turns round forwards; the rigid car, its wheel ramped and straight where it changes
    speed, turns in three points (a few metres back at walking pace), not backing all the way.
    (At reverse_penalty 2 = h_weight each metre backwards left the search order f = g + 2 H
    unchanged and this plan backed all 25 m.) The search's first exact path is the plan: no
    improvement, which the order alone decides."""
    grid = np.zeros((80, 120), bool)
    grid[:, :2] = grid[:, -2:] = grid[:2] = grid[-2:] = True
    omap = from_array(grid, 0.5)
    config = make_config(reverse=1, improve_expansions=0, max_seconds=3600.0)
    finder = PathFinder(omap, config, None, 5.0)
    result = finder.plan((40.0, 20.0, 0.0), (15.0, 20.0, 0.0))
    assert result.status == "exact", result.reason
    d = measure(path_rows(result, finder.vehicle))
    assert config.params.reverse_penalty > config.params.h_weight
    assert d["cusps"] <= 2 and d["reverse_length_m"] < 0.2 * result.path_length()
    forwards = result.path_length() - d["reverse_length_m"]
    assert result.progress[-1][1] == pytest.approx(
        forwards + config.params.reverse_penalty * d["reverse_length_m"]
        + config.params.cusp_cost * d["cusps"], rel=0.02)
    assert result.progress[-1][1] < config.params.reverse_penalty * 25.0


def test_a_car_that_stands_still_has_nothing_to_measure():
    rows = rows_of(np.linspace(0.0, 1.0, 11), np.tile([3.0, 4.0, 0.5], (11, 1)))
    d = measure(rows)
    assert (d["max_curvature_1pm"], d["max_steer_rate_radps"], d["reverse_length_m"],
            d["cusps"], d["drivable"]) == (0.0, 0.0, 0.0, 0, True)
