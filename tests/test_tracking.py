"""The tracking replay against answers known without it: Stanley's loop (forwards) and the
rear-wheel feedback (backwards) from an offset start on a straight line match their linearised
closed loops (matrix exponential, with the steering servo); on a circle its steady offset
is the one solved from the car's steady-state cornering equations, written here from the
tyre law and the geometry of a turning car."""
import numpy as np
import pytest
from scipy.linalg import expm
from scipy.optimize import fsolve

from stepzoo import dynamics
from stepzoo.search.plans import tracking as T
from stepzoo.search.plans.path_metrics import cusps
from stepzoo.search.plans.tracking import track

VEHICLE = dynamics.vehicle(None)
LF, LR = VEHICLE["Lf"], VEHICLE["Lr"]
L = LF + LR
G = 9.81


def line(v, length, way=1):
    """Rows [t, X, Y, psi] along the X axis at speed v [m/s], forwards (way 1: +X, facing
    +X) or backwards (way -1: towards -X, facing +X)."""
    s = np.arange(0.0, length, 0.05)
    return np.column_stack([s / v, way * s, np.zeros_like(s), np.zeros_like(s)])


def linear_response(A, x0, times):
    """States of dx/dt = A x from x0 at `times`."""
    return np.array([expm(A * t) @ x0 for t in times])


def servo_row(gains):
    """The steering servo's row: d delta/dt = (gains . [e, psi] - delta) / tau."""
    tau = T.STEER_SERVO_S
    return [gains[0] / tau, gains[1] / tau, -1 / tau]


@pytest.mark.parametrize("way", [1, -1])
def test_an_offset_start_decays_as_the_linearised_stanley_loop(way):
    """At 0.8 m/s the car is the kinematic single track (below the blend); from 1 cm off a
    straight line the controlled axle's error follows the linear loop of states [e, psi,
    delta]: forwards the front axle, e' = v (psi + delta), delta -> -psi - k e / (k_soft + v),
    whose e decays at Stanley's rate k v / (k_soft + v) (the steer's servo adds a fast pole);
    backwards the rear axle under rear-wheel feedback of length l = BACK_L_M, e' = -v psi,
    psi' = -v delta / L, delta -> 2 L psi / l - L e / l^2 (critically damped)."""
    v, e0 = 0.8, 0.01
    out = track(line(v, 12.0, way), [0.0, e0, 0.0], VEHICLE)
    poses = out["poses"]
    assert out["done"] and abs(out["end"][0] - way * 11.95) < 0.05
    times = np.arange(1, 601) * T.H_S          # 6 s, before it brakes for the end
    X, Y, psi = poses[:600].T
    if way > 0:
        c = T.GAIN_K / (T.K_SOFT + v)
        e = Y + LF * np.sin(psi)
        A = np.array([[0, v, v], [0, 0, v / L], servo_row([-c, -1])])
    else:
        length = T.BACK_L_M
        e = Y - LR * np.sin(psi)
        A = np.array([[0, -v, 0], [0, 0, -v / L],
                      servo_row([-L / length**2, 2 * L / length])])
    expected = linear_response(A, np.array([e0, 0.0, 0.0]), times)[:, 0]
    # The linear loop in continuous time against the sampled one (steps of 0.01 s): within 1%
    # of the offset all along, where the offset itself falls by 90% or more.
    assert np.abs(e - expected).max() < 0.01 * e0
    assert abs(e[-1]) < 0.1 * e0
    if way > 0:     # Stanley's own rate, the servo's delay aside: within 10%
        rate = np.log(e[99] / e[299]) / 2.0
        assert rate == pytest.approx(T.GAIN_K * v / (T.K_SOFT + v), rel=0.1)


def fiala(alpha, C, grip):
    """Fiala's brush tyre (Pacejka 2012, ch. 3): lateral force [N] at slip angle alpha."""
    z = np.tan(alpha)
    if abs(z) >= 3 * grip / C:
        return -grip * np.sign(alpha)
    return -C * z + C**2 / (3 * grip) * abs(z) * z - C**3 / (27 * grip**2) * z**3


def steady_circle(R, v):
    """The tracked car's steady state on a left circle of radius R [m] at the plan's speed v
    [m/s]: (radius of its centre of gravity's circle [m], its speed [m/s]). Unknowns: that
    radius, the body slip beta at the centre of gravity, the steer and the forward speed;
    equations: lateral and yaw balance, Stanley's steer with the front slip fed forward
    (the front axle's velocity along the reference's tangent, so atan(k e / (k_soft + vx))
    equals the front slip angle less the slip fed forward for the path's curvature),
    the speed loop supplying the drag of the steered front tyre."""
    mu = 1.0489
    Fzf, Fzr = VEHICLE["m"] * G * LR / L, VEHICLE["m"] * G * LF / L
    Caf, Car, m, Iz = VEHICLE["Caf"], VEHICLE["Car"], VEHICLE["m"], VEHICLE["Iz"]
    # The rows' heading is the path's own: the front axle's path is a circle Lf further out.
    front_ref = np.hypot(R, LF)

    def feedforward(vx, radius):
        """The front slip, solved from Fiala's law here, that carries the front axle's share
        m Lr / L of the steady turn vx^2 / radius: what the controller adds to its steer."""
        share = m * LR / L * vx**2 / radius
        return -fsolve(lambda a: fiala(a[0], Caf, mu * Fzf) - share, [-0.01], xtol=1e-14)[0]

    def equations(z):
        Rc, beta, delta, vx = z
        vy, r = vx * np.tan(beta), vx / np.cos(beta) / Rc
        vf = vy + LF * r
        alpha_f = np.arctan((vf * np.cos(delta) - vx * np.sin(delta))
                            / (vx * np.cos(delta) + vf * np.sin(delta)))
        alpha_r = np.arctan((vy - LR * r) / vx)
        Fyf, Fyr = fiala(alpha_f, Caf, mu * Fzf), fiala(alpha_r, Car, mu * Fzr)
        front = np.hypot(Rc + LF * np.sin(beta), LF * np.cos(beta))
        e = front_ref - front                     # to the left of the way: inwards
        return [(Fyf * np.cos(delta) + Fyr) / m - vx * r,
                (LF * Fyf * np.cos(delta) - LR * Fyr) / Iz,
                np.arctan(T.GAIN_K * e / (T.K_SOFT + vx)) - alpha_f - feedforward(vx, R),
                T.SPEED_GAIN * (v - vx) - (Fyf * np.sin(delta) / m - vy * r)]

    Rc, beta, delta, vx = fsolve(equations, [R, LR / R, L / R, v], xtol=1e-13)
    assert np.abs(equations([Rc, beta, delta, vx])).max() < 1e-9
    return Rc, vx / np.cos(beta)


def test_on_a_circle_the_car_settles_at_the_offset_of_its_steady_cornering():
    """R = 10 m at 6 m/s (0.37 g): the front tyres slip, Stanley's front axle runs outside
    its reference by (k_soft + v) tan(alpha_f - alpha_ff) / k, alpha_ff the front slip fed
    forward, and the body slips less than a rolling car's; the centre of gravity settles where
    the steady-state equations put it. (The rows' heading is the circle's tangent, a body
    without slip, so the front axle's reference lies Lf out along it: with the front slip fed
    forward the front axle keeps to it and the centre of gravity runs 14 cm inside.)"""
    R, v = 10.0, 6.0
    s = np.arange(0.0, 1.25 * 2 * np.pi * R, 0.05)
    a = s / R
    rows = np.column_stack([s / v, R * np.sin(a), R * (1 - np.cos(a)), a])
    out = track(rows, [0.0, 0.0, 0.0], VEHICLE)
    assert out["done"]
    X, Y = out["poses"][:, 0], out["poses"][:, 1]
    radius = np.hypot(X, Y - R)
    settled = slice(int(6.0 / T.H_S), int(10.0 / T.H_S))   # 0.6 to 1 lap
    Rc, speed = steady_circle(R, v)
    assert abs(Rc - R) > 0.05                  # an offset worth predicting
    assert radius[settled] == pytest.approx(Rc, abs=2e-4)
    assert out["deviation"][settled] == pytest.approx(abs(Rc - R), abs=2e-4)
    # Its lateral acceleration there: speed^2 / radius, as the travelled arc says.
    step = np.hypot(np.diff(X[settled]), np.diff(Y[settled])) / T.H_S
    assert step.mean() == pytest.approx(speed, rel=1e-3)
    assert step.mean() ** 2 / radius[settled].mean() == pytest.approx(speed**2 / Rc, rel=2e-3)


def test_the_car_slows_where_the_path_turns_the_wheel_faster_than_it_can():
    """A plan at 5 m/s whose steer ramps by g rad per metre between 10 and 12 m: there the
    speed is capped at STEER_SHARE of the steer rate over g, reached by braking at A_CAP
    (v^2 = cap^2 + 2 A_CAP d, d to the ramp); elsewhere the plan's speed holds."""
    rate, g = 0.4, 0.5
    s = np.arange(0.0, 20.0 + 1e-9, 0.05)
    steer = np.clip((s - 10.0) * g, 0.0, 2 * g)
    speed = T.steering_speed(np.full(len(s), 5.0), s, steer, rate)
    cap = T.STEER_SHARE * rate / g
    inside = (s > 10.1) & (s < 11.9)
    assert speed[inside] == pytest.approx(cap, rel=1e-9)
    before = s < 9.9
    expected = np.minimum(5.0, np.sqrt(cap**2 + 2 * T.A_CAP * (10.0 - s[before])))
    assert speed[before] == pytest.approx(expected, abs=2 * T.A_CAP * 0.05)
    assert speed[s > 12.1] == pytest.approx(5.0)


def test_a_full_lock_turn_at_the_planners_lateral_limit_is_tracked_within_a_quarter_metre():
    """A kinematic plan round a circle of R = 3 m (about the car's full lock) at the speed
    where v^2 / R is the planner's lateral limit (limit_fraction 0.8 of 11.5 m/s^2: 0.89 of
    the tyres' friction mu g): the Fiala car cannot corner that hard at that steer and ran
    0.5 m wide (room-64-64-8-00's connection touched a wall so). Capped at GRIP_SHARE of mu g,
    reached by braking, it keeps within a quarter metre, and it still drives the plan's speed
    where the path is straight."""
    R = 3.0
    v = np.sqrt(0.8 * VEHICLE["max_lateral_acceleration"] * R)
    s = np.arange(0.0, 0.75 * 2 * np.pi * R, 0.05)
    a = s / R
    rows = np.column_stack([s / v, R * np.sin(a), R * (1 - np.cos(a)), a])
    out = track(rows, [0.0, 0.0, -np.arcsin(LR / R)], VEHICLE, np.ones(len(rows), bool))
    assert out["done"]
    assert out["deviation"].max() < 0.25
    # 10 m straight, then the circle: the cap is sqrt(lateral R) on it, v before braking.
    s = np.arange(0.0, 20.0 + 1e-9, 0.05)
    speed = T.steering_speed(np.full(len(s), v), s, np.zeros(len(s)), 0.4,
                             np.where(s < 10.0, 0.0, 1 / R), 6.0)
    assert speed[0] == pytest.approx(v)
    assert speed[s > 10.0] == pytest.approx(np.sqrt(6.0 * R))


def kinematic_drive(controls, dt=0.01):
    """Rows [t, X, Y, psi] of the planner's kinematic bicycle ((X, Y) along psi, turning at
    v tan(delta) / L) from the origin facing +X, one step of dt [s] under each of `controls`
    (speed [m/s], steer [rad]); every fifth step."""
    x, t, rows = np.zeros(3), 0.0, [[0.0, 0.0, 0.0, 0.0]]
    for speed, delta in controls:
        x = x + dt * np.array([speed * np.cos(x[2]), speed * np.sin(x[2]),
                               speed * np.tan(delta) / L])
        t += dt
        rows.append([t, *x])
    return np.array(rows[::5])


def crawl_ramp_rows(v, peak, rate=0.32, dt=0.01):
    """kinematic_drive's rows: 2 m/s straight ahead braking at 2 m/s^2 to a crawl at v [m/s],
    there the steer ramped at `rate` [rad/s] from 0 to `peak`, to -peak and back to 0 [rad]
    (as a connection turns the wheel while it crawls), then straight on accelerating at
    1 m/s^2 to 2 m/s."""
    def controls():
        speed, delta = 2.0, 0.0
        while speed > v:
            speed = max(v, speed - 2 * dt)
            yield speed, delta
        for target in (peak, -peak, 0.0):
            while abs(delta - target) > 1e-12:
                delta += np.clip(target - delta, -rate * dt, rate * dt)
                yield speed, delta
        while speed < 2.0:
            speed = min(2.0, speed + dt)
            yield speed, delta
    return kinematic_drive(controls(), dt)


def test_a_crawl_through_a_steer_ramp_is_tracked_with_the_plans_steer_fed_forward():
    """At 0.5 m/s a steer ramp of 0.32 rad/s (the car's limit is 0.4) through +-0.7 rad
    turns the path's heading within about a metre: the front axle's course averaged over
    SMOOTH_M ran ahead of the ramp and behind it, and the car, steered by that course alone,
    turned late, then over-steered (0.2 m off). Below the plant's blend the plan's steer is
    fed forward with the body's heading error: the car keeps within 0.1 m."""
    rows = crawl_ramp_rows(0.5, 0.7)
    out = track(rows, rows[0, 1:], VEHICLE, np.ones(len(rows), bool))
    assert out["done"]
    assert out["deviation"].max() < 0.1


def rigid_ramp_rows(v, peak, rate=0.32, dt=0.01):
    """Rows [t, X, Y, psi] of the rigid car (its centre of gravity moving at the slip beta =
    atan(Lr tan(delta) / L) beside its body psi, the body turning at v cos(beta) tan(delta)
    / L): 2 m/s straight ahead braking at 2 m/s^2 to v [m/s], there the steer ramped at
    `rate` [rad/s] from 0 to `peak`, to -peak and back to 0 [rad], then accelerating at
    1 m/s^2 to 2 m/s; every fifth step."""
    x, speed, delta, t, rows = np.zeros(3), 2.0, 0.0, 0.0, [[0.0, 0.0, 0.0, 0.0]]

    def step():
        nonlocal x, t
        beta = np.arctan(LR * np.tan(delta) / L)
        x = x + dt * np.array([speed * np.cos(x[2] + beta), speed * np.sin(x[2] + beta),
                               speed * np.cos(beta) * np.tan(delta) / L])
        t += dt
        rows.append([t, *x])

    while speed > v:
        speed = max(v, speed - 2 * dt)
        step()
    for target in (peak, -peak, 0.0):
        while abs(delta - target) > 1e-12:
            delta += np.clip(target - delta, -rate * dt, rate * dt)
            step()
    while speed < 2.0:
        speed = min(2.0, speed + dt)
        step()
    return np.array(rows[::5])


def test_a_rigid_cars_crawl_through_a_steer_ramp_is_tracked_with_its_rear_axles_steer():
    """The rigid car's rows (the planner's tight moves, reversing and connection) at 0.5 m/s
    ramp the steer at 0.32 rad/s through +-0.7 rad: its centre of gravity's path curves up to
    0.5 1/m while the slip changes, beyond any steady turn's (full lock: 0.34 1/m), so the
    steer fed forward from it saturated and the car strayed 0.39 m. Fed forward from the rear
    axle's path (Lr behind along the body), which turns at tan(delta) / L whatever the steer
    does, the car keeps within 0.1 m."""
    rows = rigid_ramp_rows(0.5, 0.7)
    out = track(rows, rows[0, 1:], VEHICLE)
    assert out["done"]
    assert out["deviation"].max() < 0.1


def test_a_stop_whose_rows_jitter_by_their_rounding_is_no_cusp():
    """20 m along X at 2 m/s with a 1 s stop halfway, its rows then 1e-6 m apart back and
    forth (plan.json's rows are rounded to 1e-6 m; standing still they step so): two pieces
    driven forwards (the car stops where the plan does), tracked as the same path whose stop
    holds one point. Read as moves,
    those steps made pieces of alternating direction, at which the tracked car stopped and
    set off, backwards as forwards."""
    go = line(2.0, 10.0)
    stop = np.column_stack([go[-1, 0] + np.arange(1, 21) * 0.05, np.full(20, go[-1, 1]),
                            np.zeros(20), np.zeros(20)])
    on = line(2.0, 10.0)[1:] + [go[-1, 0] + 1.0, go[-1, 1] + 0.05, 0.0, 0.0]
    held = np.vstack([go, stop, on])
    jitter = held.copy()
    jitter[len(go):len(go) + 20, 1] += 1e-6 * (np.arange(20) % 2)
    # Two pieces, both forwards: cut where the plan stands still (halted), not at each step.
    assert list(T.reference(jitter, T.plant_params(VEHICLE))["way"]) == [1, 1]
    clean, rounded = (track(r, [0.0, 0.0, 0.0], VEHICLE) for r in (held, jitter))
    assert clean["done"] and rounded["done"]
    assert rounded["deviation"].max() == pytest.approx(clean["deviation"].max(), abs=1e-6)


def halt_rows(v, lock=0.785, rate=0.32, dt=0.01, accel=2.0):
    """kinematic_drive's rows: from rest on full lock left up to v [m/s] at `accel` [m/s^2],
    2 s on, braking to rest; the wheel turned standing at `rate` [rad/s] to full lock right
    (as the connection turns it); the same to the right."""
    def controls():
        speed, delta = 0.0, lock
        for turning in (True, False):
            while speed < v:
                speed = min(v, speed + accel * dt)
                yield speed, delta
            for _ in range(int(2.0 / dt)):
                yield speed, delta
            while speed > 0:
                speed = max(0.0, speed - accel * dt)
                yield speed, delta
            while turning and delta > -lock:
                delta = max(-lock, delta - rate * dt)
                yield speed, delta
    return kinematic_drive(controls(), dt)


def test_where_the_plan_stops_to_turn_the_wheel_the_car_stops_too(monkeypatch):
    """A plan that stops between two full-lock turns at 2 m/s and turns the wheel lock to
    lock standing (as the connection does): the reference is cut there (halted), so the car
    brakes to a stop where the plan stands and turns its wheel before it sets off, within
    0.27 m of the path; read as one piece it crawled on through the stop while its wheel
    lagged and strayed 0.3 m."""
    rows = halt_rows(2.0)
    start = [0.0, 0.0, -np.arcsin(LR * np.tan(0.785) / L)]    # the rolling car's body
    kinematic = np.ones(len(rows), bool)
    assert len(T.reference(rows, T.plant_params(VEHICLE), kinematic)["first"]) == 2
    stopped = track(rows, start, VEHICLE, kinematic)
    monkeypatch.setattr(T, "HALT_S", np.inf)
    crawled = track(rows, start, VEHICLE, kinematic)
    assert stopped["done"] and crawled["done"]
    assert stopped["deviation"].max() < 0.27 < 0.28 < crawled["deviation"].max()


@pytest.mark.parametrize("turn", [0.0, 0.5])
def test_a_body_turned_standing_at_the_end_is_a_final_heading_deviation(turn):
    """12 m straight at 0.8 m/s, then a second standing at the end while the rows' heading turns
    by `turn` [rad] (the paper's kinematic bicycle drew its body so when its wheel turned at a
    standstill): no car turns standing, so the tracked car stops facing as it came, and the
    tracking block's final_heading_deviation_rad reads -turn; its position is where the rows
    end."""
    from stepzoo.search.world.maps import from_array
    rows = line(0.8, 12.0)
    still = rows[-1, 0] + np.linspace(0.05, 1.0, 20)
    rows = np.vstack([rows, np.column_stack([still, np.full(20, rows[-1, 1]), np.zeros(20),
                                             np.linspace(0.0, turn, 21)[1:]])])
    plan = {"path": rows.tolist(), "start": [0.0, 0.0, 0.0], "controls": [],
            "vehicle": dict(VEHICLE, wheelbase=L), "params": {"margin": 0.1}}
    block = T.tracking(plan, from_array(np.zeros((20, 40), bool), 1.0))
    assert block["final_heading_deviation_rad"] == pytest.approx(-turn, abs=0.01)
    assert block["final_deviation_m"] < 0.05


def test_the_steer_fed_forward_does_not_pick_up_the_rows_rounding():
    """On a circle of 20 m, rows 5 cm apart rounded to 1e-6 m as plan.json holds them: the
    steer the path's curvature feeds forward stays within 2.5e-4 rad of the unrounded rows'
    (a second difference of rows 5 cm apart turns 1e-6 m into 5e-4 rad of steer; averaged
    over FF_SMOOTH_M it is a quarter of that), so plan.json's rows and the planner's are
    tracked alike."""
    R = 20.0
    s = np.arange(0.0, 60.0, 0.05)
    # The rigid car's body faces asin(Lr / R) inside the circle's tangent.
    rows = np.column_stack([s / 5.0, R * np.sin(s / R), R * (1 - np.cos(s / R)),
                            s / R - np.arcsin(LR / R)])
    p = T.plant_params(VEHICLE)
    exact, rounded = (T.reference(r, p)["steer_ff"] for r in (rows, np.round(rows, 6)))
    assert exact[100] == pytest.approx(np.arctan(L / np.sqrt(R ** 2 - LR ** 2)), rel=1e-3)
    assert np.abs(rounded - exact)[40:-40].max() < 2.5e-4


def test_backwards_on_a_circle_the_rear_wheel_feedback_keeps_the_car_on_it():
    """Backing round a circle of R = 8 m at 0.8 m/s (the kinematic single track), from a
    pose on it (the centre of gravity on the circle, the body turned by the rolling car's
    slip asin(Lr / R) from its tangent, the wheel at its steer): the rear axle's curvature
    fed forward holds its own circle, so once it has settled (within 2.5 cm before: the
    path's first point reads half its turn, from one-sided differences) the car stays on
    the path within 1 mm to its end. Pure pursuit settled on it too, but left it by 0.13 m
    where its lookahead passed the path's end; the law before that (Stanley's terms on the
    rear axle and a heading term) settled 2 cm off it."""
    R, v = 8.0, 0.8
    s = np.arange(0.0, 0.75 * 2 * np.pi * R, 0.05)
    a = s / R
    # Backwards: the body faces +X at the start and the car moves towards -X, turning left.
    rows = np.column_stack([s / v, -R * np.sin(a), R * (1 - np.cos(a)), -a])
    out = track(rows, [0.0, 0.0, -np.arcsin(LR / R)], VEHICLE, np.ones(len(rows), bool))
    assert out["done"]
    X, Y = out["poses"][:, 0], out["poses"][:, 1]
    off = np.abs(np.hypot(X, Y - R) - R)
    settled = int(10.0 / v / T.H_S)                       # after its first 10 m
    assert off.max() < 0.025 and off[settled:].max() < 0.001
    assert np.hypot(*(out["end"][:2] - rows[-1, 1:3])) < 0.05    # it stops at the end


def plan_record_of(scenario_name=None, omap=None, start=None, goal=None, vx=None, **params):
    """plan.json's record (through JSON) of a repository scenario, or of a map and ends, with
    the default planner (its steering rate-limited), stopping at the first exact path."""
    import json

    from stepzoo.search.planner.pathfinder import PathFinder
    from stepzoo.search.plans.files import plan_record
    from stepzoo.search.planner.config import load_config, with_params
    from stepzoo.search.world.scenarios import Scenario, load_scenario
    config = with_params(load_config(), improve_expansions=0, max_seconds=3600.0, **params)
    if scenario_name is not None:
        scenario = load_scenario(scenario_name)
    else:
        scenario = Scenario("generated", "", omap, "generated", start, goal, None, None, vx)
    finder = PathFinder(scenario.omap, config, scenario.vehicle, scenario.speed)
    result = finder.plan(scenario.start, scenario.goal, scenario.goal_speed, seed=0)
    record = plan_record(result, scenario, config, finder.vehicle, 0, 0.0)
    return json.loads(json.dumps(record)), scenario.omap


def test_a_scenarios_plan_is_tracked_within_a_quarter_metre_without_collision():
    from stepzoo.search.plans.schema import TRACKING_KEYS
    record, omap = plan_record_of("wall_between")
    block = record["tracking"]
    assert record["status"] == "exact" and list(block) == list(TRACKING_KEYS)
    assert (block["controller"], block["model"]) == ("stanley", "single_track_fiala")
    assert block["max_deviation_m"] < 0.25 and block["final_deviation_m"] < 0.25
    assert abs(block["final_heading_deviation_rad"]) < 0.05    # facing as the goal asks
    assert block["collides"] is False and block["clearance_min_m"] > 0
    # The record's own path, tracked again from plan.json alone, gives the same block.
    assert T.tracking(record, omap) == block


def test_reverse_gear_and_its_cusp_are_tracked():
    """A start facing a wall (as test_planner's): the plan backs away, then drives forwards;
    the car stops at the cusp, changes direction and reaches the end without collision,
    within a quarter metre of the path all the way: the plan's moves set off from a
    standstill as the car does, its wheel turned, the rigid car's centre of gravity aside of
    the body's heading (set off along the body's heading instead, the plan asked the car to slide, and the
    tracked car strayed 1.1 m from it backing round its tight turn)."""
    from stepzoo.search.world.maps import from_array
    occupied = np.zeros((40, 60), bool)
    occupied[:, -2:] = occupied[:, :2] = occupied[:2] = occupied[-2:] = True
    omap = from_array(occupied, 0.5)
    record, _ = plan_record_of(omap=omap, start=(26.0, 10.0, 0.0), goal=(8.0, 10.0, np.pi),
                               vx=2.0, reverse=1)
    assert record["status"] == "exact" and record["stats"]["cusps"] >= 1
    rows = np.asarray(record["path"])
    out = track(rows, record["start"], record["vehicle"],
                T.kinematic_rows(rows, record["controls"]))
    assert out["done"]
    # The car changes its direction of travel where the plan does, and only there.
    poses = out["poses"]
    assert cusps(np.column_stack([np.arange(len(poses)) * T.H_S, poses])) == \
        record["stats"]["cusps"]
    assert record["tracking"]["max_deviation_m"] < 0.25
    assert record["tracking"]["collides"] is False


def test_a_plan_without_a_path_has_a_tracking_block_of_nulls():
    from stepzoo.search.world.maps import from_array
    block = T.tracking({"path": [], "start": [0.0, 0.0, 0.0], "controls": [],
                        "vehicle": dict(VEHICLE, wheelbase=L), "params": {"margin": 0.1}},
                       from_array(np.zeros((4, 4), bool), 1.0))
    assert block == {"controller": "stanley", "model": "single_track_fiala",
                     "max_deviation_m": None, "final_deviation_m": None,
                     "final_heading_deviation_rad": None, "collides": None,
                     "clearance_min_m": None}


def test_the_shared_program_sizes_give_the_rows_and_the_tracking_of_the_plans_own(
        monkeypatch):
    """The path rows filled in between nodes, padded to FILL_LEAST, and the closed loop,
    compiled for more periods and rows than a plan needs (LEAST_STEPS, LEAST_ROWS: so that
    plans share programs), are bit for bit those of the plan's own power-of-two sizes, and
    the tracked car gets the plan's own time allowed (the periods past it cut off)."""
    import stepzoo.integrators as zoo
    from stepzoo.search.planner.config import load_config, with_params
    from stepzoo.search.planner.pathfinder import PathFinder
    from stepzoo.search.plans import replay as R
    from stepzoo.search.world.scenarios import load_scenario
    scenario = load_scenario("wall_between")
    config = with_params(load_config(), improve_expansions=0, max_seconds=3600.0)
    finder = PathFinder(scenario.omap, config, scenario.vehicle, scenario.speed)
    result = finder.plan(scenario.start, scenario.goal, scenario.goal_speed, seed=0)
    batches = []
    run = zoo.integrate_batch
    monkeypatch.setattr(zoo, "integrate_batch",
                        lambda method, f, x0, *a: batches.append(len(x0)) or run(method, f, x0, *a))
    shared = R.model_rows(result, finder.vehicle, 0.05)
    small, least = R.FILL_SMALL, R.FILL_LEAST
    monkeypatch.setattr(R, "FILL_LEAST", small)
    own = R.model_rows(result, finder.vehicle, 0.05)
    assert any(small < n < least for n in batches[len(batches) // 2:])
    assert np.array_equal(shared, own)
    start, kinematic = result.start, T.kinematic_rows(own, R.controls(result))
    lengths, scan = [], T._scan
    monkeypatch.setattr(T, "_scan", lambda n: lengths.append(n) or scan(n))
    # Sizes above this plan's own, whatever the defaults: the extra periods are cut off.
    monkeypatch.setattr(T, "LEAST_STEPS", 65536)
    monkeypatch.setattr(T, "LEAST_ROWS", 8192)
    tracked = track(own, start, finder.vehicle, kinematic)
    monkeypatch.setattr(T, "LEAST_STEPS", 1024)
    monkeypatch.setattr(T, "LEAST_ROWS", 256)
    alone = track(own, start, finder.vehicle, kinematic)
    assert lengths[1] < lengths[0] and alone["done"]
    for key in ("poses", "deviation", "end"):
        assert np.array_equal(tracked[key], alone[key]), key
    assert tracked["done"] == alone["done"]
    # A time allowed shorter than the plan needs: the car is cut off there, not at the
    # compiled length.
    bucket = T._bucket
    monkeypatch.setattr(T, "_bucket", lambda n, least: 1024 if least == 1024 else
                        bucket(n, least))
    monkeypatch.setattr(T, "LEAST_STEPS", 65536)
    short = track(own, start, finder.vehicle, kinematic)
    assert not short["done"] and len(short["poses"]) == 1024


def cusp_rows(v=2.0, steer=-0.6, back_m=3.0, on_m=20.0, v_on=5.0, dt=0.01):
    """A rigid car's rows [t, X, Y, psi]: backing `back_m` [m] at `v` [m/s] and `steer` [rad]
    (its rear axle on a circle of L / tan(steer), in closed form), then at once forwards at
    `v_on` along a straight line from there, the wheel straight: the plan's steer jumps at
    the cusp (as where a tight move meets the tree's 5 m/s moves)."""
    t1 = np.arange(0.0, back_m / v, dt)
    psi = -v * np.tan(steer) / L * t1             # psi' = v tan(delta) / L, v < 0
    rate = -v * np.tan(steer) / L
    rear = np.column_stack([-np.sin(psi) / rate * v, (np.cos(psi) - 1) / rate * v])
    back = np.column_stack([t1, rear + LR * np.column_stack([np.cos(psi), np.sin(psi)]), psi])
    t2 = np.arange(dt, on_m / v_on, dt)
    end = back[-1]
    on = np.column_stack([end[0] + t2, end[1] + v_on * t2 * np.cos(end[3]),
                          end[2] + v_on * t2 * np.sin(end[3]), np.full(len(t2), end[3])])
    return np.vstack([back, on])


def test_at_a_cusp_the_car_turns_its_wheel_standing_before_it_moves_off(monkeypatch):
    """Backing on a circle at steer -0.6 rad, then straight on at 5 m/s: the plan's steer
    jumps by 0.6 rad at the cusp, which takes the wheel (0.6 - START_LAG_RAD) /
    max_steer_rate = 1.375 s. The tracked car stands there most of that (the wheel starts
    turning as it brakes to the stop) and keeps within 4 cm of the path; a car that moves
    off with its wheel still turning (creeping at a tenth of the plan's speed) stands under
    0.2 s and strays more than twice as far."""
    rows = cusp_rows()
    cusp = rows[np.argmax(np.diff(rows[:, 1]) > 0), 1:3]     # where X turns to growing

    def tracked():
        out = track(rows, rows[0, 1:], VEHICLE)
        poses = out["poses"]
        away = np.hypot(*(poses[:, :2] - rows[-1, 1:3]).T) > 0.2    # before it stops
        step = np.r_[np.hypot(*np.diff(poses[:, :2], axis=0).T), 1.0]
        standing = (step < 1e-3) & (np.hypot(*(poses[:, :2] - cusp).T) < 0.2)
        assert out["done"]
        return out["deviation"][away].max(), standing.sum() * T.H_S

    deviation, standing = tracked()
    turning = (0.6 - T.START_LAG_RAD) / VEHICLE["max_steer_rate"]     # [s] 1.375
    assert standing > 0.6 * turning and deviation < 0.04
    monkeypatch.setattr(T, "START_LAG_RAD", np.inf)
    T._scan.cache_clear()
    try:
        hasty, stood = tracked()
    finally:
        T._scan.cache_clear()
    assert stood < 0.2 and hasty > 2 * deviation
