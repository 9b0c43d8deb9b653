"""Footprint collision: the disc cover contains the car, paths cannot jump walls, and the
centre screen that spares most poses the per-disc check never changes an answer."""


import math

import numpy as np
import pytest

from stepzoo.search.world.footprint import (Footprint, discs_collide, first_collision,
                                            poses_collide, rectangle_clearance, roomy)
from stepzoo.search.world.maps import MAP_DIR, SUBDIV, from_array, load_map



def grid_with(cells, shape=(200, 200), resolution=0.1):
    """A map of `shape` cells with the given (row, col) cells occupied, origin (0, 0)."""
    occupied = np.zeros(shape, bool)
    for row, col in cells:
        occupied[row, col] = True
    return from_array(occupied, resolution)


def rectangle_points(length, width, pose, n=41):
    """World points [m] on a grid over the rectangle, its edges and corners included."""
    u, v = np.meshgrid(np.linspace(-length / 2, length / 2, n),
                       np.linspace(-width / 2, width / 2, n))
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.stack([pose[0] + c * u - s * v, pose[1] + s * u + c * v], -1).reshape(-1, 2)


@pytest.mark.parametrize("length, width, n_discs", [
    (4.5, 1.8, None), (4.5, 1.8, 1), (4.5, 1.8, 5), (1.0, 2.0, None), (3.0, 3.0, 2)])
def test_the_disc_cover_contains_the_rectangle(length, width, n_discs):
    footprint = Footprint.from_vehicle(length, width, n_discs)
    for pose in np.random.default_rng(3).uniform([-5, -5, -4], [5, 5, 4], (5, 3)):
        points = rectangle_points(length, width, pose)
        centres = footprint.disc_centres(pose)
        gap = np.linalg.norm(points[:, None, :] - centres[None], axis=-1).min(axis=1)
        assert np.all(gap <= footprint.radius + 1e-9)


def test_default_cover_uses_near_square_slices():
    footprint = Footprint.from_vehicle(4.5, 1.8)
    assert footprint.offsets.tolist() == pytest.approx([-1.5, 0.0, 1.5])
    assert footprint.radius == pytest.approx(np.hypot(0.75, 0.9))


def test_disc_centres_follow_the_heading():
    footprint = Footprint.from_vehicle(4.0, 2.0, 2)
    centres = footprint.disc_centres(np.array([[1.0, 2.0, np.pi / 2], [0.0, 0.0, 0.0]]))
    assert centres.shape == (2, 2, 2)
    assert centres[0] == pytest.approx(np.array([[1.0, 1.0], [1.0, 3.0]]))
    assert centres[1] == pytest.approx(np.array([[-1.0, 0.0], [1.0, 0.0]]))


def test_a_corner_over_an_obstacle_collides_and_the_same_pose_shifted_clear_does_not():
    # Car 4 m x 2 m at (10, 10) heading +x: front-left corner at (12, 11). The obstacle cell
    # [11.9, 12.0] x [10.9, 11.0] sits just inside that corner.
    omap = grid_with([(109, 119)])
    footprint = Footprint.from_vehicle(4.0, 2.0)
    poses = np.array([[10.0, 10.0, 0.0],   # corner on the obstacle
                      [10.0, 8.5, 0.0],    # shifted 1.5 m to the car's right
                      [6.0, 10.0, 0.0]])   # shifted 4 m back
    assert poses_collide(omap, footprint, poses).tolist() == [True, False, False]


def test_turning_the_car_onto_an_obstacle_collides():
    # An obstacle left of a car heading +x is hit once the car heads +y.
    omap = grid_with([(120, 100)])  # cell [10.0, 10.1] x [12.0, 12.1]
    footprint = Footprint.from_vehicle(4.5, 1.8)
    poses = np.array([[10.0, 10.0, 0.0], [10.0, 10.0, np.pi / 2]])
    assert poses_collide(omap, footprint, poses).tolist() == [False, True]


def test_poses_off_the_map_or_not_finite_collide():
    omap = grid_with([])
    footprint = Footprint.from_vehicle(4.5, 1.8)
    poses = np.array([[10, 10, 0], [1.0, 10, 0], [30, 10, 0], [np.nan, 10, 0], [10, 10, np.inf]])
    assert poses_collide(omap, footprint, poses).tolist() == [False, True, True, True, True]


def wall_map():
    """A 0.1 m thick wall across the whole map at x in [10, 10.1]."""
    return grid_with([(row, 100) for row in range(200)])


def test_a_jump_over_a_thin_wall_is_caught_by_densification():
    omap, footprint = wall_map(), Footprint.from_vehicle(4.5, 1.8)
    path = np.array([[[5.0, 10.0, 0.0], [15.0, 10.0, 0.0], [16.0, 10.0, 0.0]]])
    # Both ends are clear on their own: only the segment between them crosses the wall.
    assert not np.any(poses_collide(omap, footprint, path))
    assert first_collision(omap, footprint, path).tolist() == [1]


def test_a_turn_in_place_that_sweeps_over_an_obstacle_is_caught():
    # The front disc passes the diagonal halfway through a quarter turn; an obstacle there
    # is clear of both the start and end poses.
    omap = grid_with([(115, 115)])  # cell centre 1.55 m along both axes from (10, 10)
    footprint = Footprint.from_vehicle(4.5, 1.8)
    path = np.array([[[10.0, 10.0, 0.0], [10.0, 10.0, np.pi / 2]]])
    assert not np.any(poses_collide(omap, footprint, path))
    assert first_collision(omap, footprint, path).tolist() == [1]


def test_heading_wraps_the_short_way_between_poses():
    # From psi = 3 to psi = -3 the car turns 0.28 rad through pi, not 6 rad through 0; only
    # the long turn passes psi = pi/2, where the car would hit the obstacle.
    omap = grid_with([(119, 100)])  # cell [10.0, 10.1] x [11.9, 12.0]
    footprint = Footprint.from_vehicle(4.5, 1.8)
    assert poses_collide(omap, footprint, np.array([10.0, 10.0, np.pi / 2]))
    path = np.array([[[10.0, 10.0, 3.0], [10.0, 10.0, -3.0]]])
    assert first_collision(omap, footprint, path).tolist() == [-1]


def test_first_collision_reports_the_first_bad_pose_per_path():
    omap, footprint = wall_map(), Footprint.from_vehicle(4.5, 1.8)
    x = np.linspace(3.0, 16.0, 27)  # 0.5 m apart, below one disc radius
    along = np.stack([x, np.full_like(x, 10.0), np.zeros_like(x)], -1)
    away = along.copy()
    away[:, 0] = 3.0 + (x - 3.0) * 0.2  # stays left of the wall
    starts_inside = along[::-1].copy()
    starts_inside[:, 0] = 10.0
    paths = np.stack([along, away, starts_inside])
    expected_along = np.argmax(poses_collide(omap, footprint, along))
    assert expected_along > 0
    assert first_collision(omap, footprint, paths).tolist() == [expected_along, -1, 0]


def brute_first_collision(omap, footprint, paths, every=50):
    """First colliding pose, checking `every` interpolated poses per segment (pose 0 alone)."""
    steps = np.diff(paths, axis=1)
    steps[..., 2] = (steps[..., 2] + np.pi) % (2 * np.pi) - np.pi
    frac = np.arange(1, every + 1) / every
    dense = paths[:, :-1, None] + frac[:, None] * steps[:, :, None]
    hit = np.concatenate([poses_collide(omap, footprint, paths[:, :1]),
                          poses_collide(omap, footprint, dense).any(axis=-1)], axis=1)
    return np.where(hit.any(axis=1), hit.argmax(axis=1), -1)


def test_first_collision_is_bracketed_by_dense_checks_with_shrunk_and_grown_discs():
    # Every point of a segment lies within half a radius of a checked pose, and the clearance
    # errs by at most 0.71 cell. So a dense check with discs shrunk by both margins can only
    # find collisions first_collision also finds (no later), and one with discs grown by the
    # clearance error plus half the dense spacing finds all that first_collision finds.
    rng = np.random.default_rng(11)
    resolution = 0.25
    omap = from_array(rng.random((120, 120)) < 0.002, resolution)
    footprint = Footprint.from_vehicle(2.0, 1.0)
    start = rng.uniform([8, 8, -np.pi], [22, 22, np.pi], (40, 1, 3))
    steps = rng.uniform([-1.5, -1.5, -0.6], [1.5, 1.5, 0.6], (40, 29, 3))
    paths = np.concatenate([start, start + np.cumsum(steps, axis=1)], axis=1)
    error = np.sqrt(2) / 2 * resolution
    smaller = Footprint(2.0, 1.0, footprint.offsets, footprint.radius / 2 - error)
    larger = Footprint(2.0, 1.0, footprint.offsets, footprint.radius + error + 0.05)
    got = first_collision(omap, footprint, paths)
    inner = brute_first_collision(omap, smaller, paths)
    outer = brute_first_collision(omap, larger, paths)
    assert np.any(inner > 0) and np.any(got == -1)
    assert np.all((inner == -1) | ((got >= 0) & (got <= inner)))
    assert np.all((got == -1) | ((outer >= 0) & (outer <= got)))
    # Checking the poses alone, without densification, finds some collisions late or never.
    plain = poses_collide(omap, footprint, paths)
    plain_first = np.where(plain.any(axis=1), plain.argmax(axis=1), -1)
    assert np.any((got >= 0) & ((plain_first == -1) | (plain_first > got)))


def test_blown_up_states_and_extra_columns():
    omap, footprint = grid_with([]), Footprint.from_vehicle(4.5, 1.8)
    path = np.zeros((2, 5, 5))  # [X, Y, psi, vy, r]
    path[:, :, 0] = np.linspace(8.0, 10.0, 5)
    path[:, :, 1] = 10.0
    path[:, :, 3:] = 1e6  # vy, r are not part of the pose
    path[1, 3, :2] = np.nan
    assert first_collision(omap, footprint, path).tolist() == [-1, 3]
    assert first_collision(omap, footprint, np.zeros((3, 0, 3))).tolist() == [-1, -1, -1]


def per_disc_check(omap, footprint, poses):
    """The check without any screen or bound: every disc against the cells around it."""
    centres = footprint.disc_centres(poses)
    return np.any(omap.disc_hits(centres[..., 0], centres[..., 1], footprint.radius), axis=-1)


def poses_over(omap, footprint, rng, n=20000):
    """Poses [X, Y, psi] all over the map and a little off it, a fifth of them placed where the
    centre screen's margin is nearly used up, plus non-finite ones."""
    xmin, xmax, ymin, ymax = omap.bounds()
    spread = rng.uniform([xmin - 3, ymin - 3, -4], [xmax + 3, ymax + 3, 4], (n, 3))
    step = omap.resolution / SUBDIV
    need = footprint.radius + footprint.reach + 1.5 * np.sqrt(2) * step
    rows, cols = np.nonzero((omap.distance > need) & (omap.distance < need + 2 * step))
    pick = rng.integers(0, rows.size, n // 5)
    edge = np.column_stack([cols[pick] * step + omap.origin[0], rows[pick] * step + omap.origin[1],
                            rng.uniform(-4, 4, pick.size)])
    edge[:, :2] += rng.uniform(-step / 2, step / 2, (pick.size, 2))
    broken = np.array([[np.nan, ymin + 1, 0], [xmin + 1, np.inf, 0], [xmin + 1, ymin + 1, np.inf],
                       [xmin + 1, ymin + 1, np.nan], [-np.inf, -np.inf, 0]])
    return np.concatenate([spread, edge, broken])


@pytest.mark.parametrize("name, cell_size", [("nav2_depot.yaml", None), ("Berlin_1_256.map", 1.5)])
@pytest.mark.parametrize("length, width", [(4.708, 1.81), (1.0, 2.0)])
def test_the_centre_screen_agrees_exactly_with_the_per_disc_check_on_a_real_map(
        name, cell_size, length, width):
    real = load_map(MAP_DIR / name, cell_size=cell_size)
    omap = from_array(real.occupied, real.resolution, (-3.25, 7.1))  # an origin off zero
    cover = Footprint.from_vehicle(length, width)
    footprint = Footprint(length, width, cover.offsets, cover.radius)  # the discs decide
    poses = poses_over(omap, footprint, np.random.default_rng(5))
    truth = per_disc_check(omap, footprint, poses)
    screened = roomy(omap, footprint, *poses.T)
    # Conservative: nothing the screen clears collides ...
    assert not np.any(screened & truth)
    # ... and poses_collide, which checks discs only where the screen says nothing, agrees
    # with the plain check everywhere, as does its per-disc check alone.
    assert np.array_equal(poses_collide(omap, footprint, poses), truth)
    assert np.array_equal(discs_collide(omap, footprint, *poses.T), truth)
    grid = poses[:24000].reshape(100, 240, 3)  # the shape of a batch of paths
    assert np.array_equal(poses_collide(omap, footprint, grid), truth[:24000].reshape(100, 240))
    assert [bool(poses_collide(omap, footprint, p)) for p in poses[:50]] == truth[:50].tolist()
    # Both branches ran: the screen cleared poses, and left free ones to the discs.
    assert screened.mean() > 0.05 and np.any(~screened & ~truth) and np.all(truth[-5:])


def test_bad_input_raises_value_error():
    with pytest.raises(ValueError, match="length and width"):
        Footprint.from_vehicle(0.0, 1.8)
    with pytest.raises(ValueError, match="n_discs"):
        Footprint.from_vehicle(4.5, 1.8, 0)
    with pytest.raises(ValueError, match="shape"):
        first_collision(grid_with([]), Footprint.from_vehicle(4.5, 1.8), np.zeros((5, 3)))


def dense_rectangle_hits(omap, length, width, poses, n=61):
    """Whether any of n x n points over the length x width rectangle at each pose lies in an
    obstacle cell or off the grid: a sample, so it finds no overlap that is not there."""
    pts = np.stack([rectangle_points(length, width, p, n) for p in poses])
    u = (pts[..., 0] - omap.origin[0]) / omap.resolution
    v = (pts[..., 1] - omap.origin[1]) / omap.resolution
    rows, cols = omap.occupied.shape
    off = ~((u > 0) & (u < cols) & (v > 0) & (v < rows))
    col = np.clip(np.floor(u), 0, cols - 1).astype(int)
    row = np.clip(np.floor(v), 0, rows - 1).astype(int)
    return (off | omap.occupied[row, col]).any(axis=-1)


def test_the_rectangle_check_is_bracketed_by_dense_points_of_the_rectangle_and_a_grown_one():
    """On a real 1.5 m map, near its obstacles: every pose where a point of the rectangle lies
    in an obstacle cell hits, and every pose that hits has a point of the rectangle grown by
    more than the points' spacing over sqrt(2) in one."""
    real = load_map(MAP_DIR / "Berlin_1_256.map", cell_size=1.5)
    omap = from_array(real.occupied, real.resolution, (-3.25, 7.1))
    length, width = 4.708, 1.81
    poses = poses_over(omap, Footprint.from_vehicle(length, width), np.random.default_rng(7),
                       5000)[:-5]
    near = omap.clearance(poses[:, :2]) < 3.5
    poses = poses[near]
    got = omap.rectangle_hits(*poses.T, length, width)
    grow = 2 * 0.1   # points 4.9 / 60 = 0.08 m apart: 0.06 m from any point of the rectangle
    assert not np.any(dense_rectangle_hits(omap, length, width, poses) & ~got)
    assert not np.any(got & ~dense_rectangle_hits(omap, length + grow, width + grow, poses))
    assert 0.2 < got.mean() < 0.9   # near obstacles, both answers are common
    assert omap.rectangle_hits(np.nan, 10.0, 0.0, length, width)


def test_where_a_disc_collides_the_rectangle_decides_and_clears_corners_the_discs_stick_out_at():
    real = load_map(MAP_DIR / "Berlin_1_256.map", cell_size=1.5)
    omap = from_array(real.occupied, real.resolution, (-3.25, 7.1))
    cover = Footprint.from_vehicle(4.708, 1.81)
    discs = Footprint(4.708, 1.81, cover.offsets, cover.radius)
    poses = poses_over(omap, cover, np.random.default_rng(8), 20000)
    by_discs = poses_collide(omap, discs, poses)
    got = poses_collide(omap, cover, poses)
    assert np.array_equal(got, by_discs & omap.rectangle_hits(*poses.T, 4.708, 1.81))
    assert np.any(by_discs & ~got)   # the discs' overshoot, cleared
    # Seen from the rear axle, the same rectangle, Lr ahead.
    finite = np.isfinite(poses).all(axis=1)
    rear = poses[finite]
    rear[:, :2] -= 1.422 * np.column_stack([np.cos(rear[:, 2]), np.sin(rear[:, 2])])
    assert np.array_equal(poses_collide(omap, cover.seen_from(1.422), rear), got[finite])


def test_the_inscribed_discs_lie_inside_the_rectangle_and_reach_its_ends():
    cover = Footprint.from_vehicle(4.708, 1.81).seen_from(1.422)
    inner = cover.inscribed()
    assert not inner.rectangle and inner.radius == pytest.approx(1.81 / 2)
    along = inner.offsets - cover.centre
    assert along.min() - inner.radius == pytest.approx(-4.708 / 2)
    assert along.max() + inner.radius == pytest.approx(4.708 / 2)


def test_a_rigid_cars_full_lock_turn_clears_a_wall_the_disc_cover_touches():
    """room-64-64-8-09's start: 4.5 m from a wall, facing it at 15 degrees. The rigid car at
    full lock (its rear axle on a circle of L / tan(pi / 4)) turns away with its corners 4.8 cm
    clear of the wall (the corners' lowest point, in closed form); its front disc reaches 5
    cm past the wall. The check says what the rectangle does."""
    occupied = np.zeros((20, 20), bool)
    occupied[:2] = True                        # the wall: y < 6 m
    omap = from_array(occupied, 3.0)
    L, Lr, length, width = 2.578, 1.422, 4.708, 1.81   # the planner's car, 0.1 m margin
    psi0 = -1.84
    rear = np.array([30.0, 10.5]) - Lr * np.array([np.cos(psi0), np.sin(psi0)])
    centre = rear + L * np.array([-np.sin(psi0), np.cos(psi0)])     # on the left
    psi = np.linspace(psi0, 0.3, 400)
    axle = centre + L * np.column_stack([np.sin(psi), -np.cos(psi)])
    poses = np.column_stack([axle + Lr * np.column_stack([np.cos(psi), np.sin(psi)]), psi])
    corner = np.hypot(L + width / 2, Lr + length / 2)   # the outer front corner's radius
    assert centre[1] - corner - 6.0 == pytest.approx(0.048, abs=1e-3)
    lowest = min(rectangle_points(length, width, p)[:, 1].min() for p in poses)
    assert lowest > 6.04
    cover = Footprint.from_vehicle(length, width, 6)
    assert first_collision(omap, cover, poses[None]).tolist() == [-1]
    discs = Footprint(length, width, cover.offsets, cover.radius)
    assert first_collision(omap, discs, poses[None])[0] > 0


@pytest.mark.parametrize("turn", [0.0, 0.3, math.pi / 4])
def test_the_rectangles_clearance_from_a_wall_is_its_growth_until_it_touches(turn):
    """A rectangle whose nearest point to a straight wall is d away: grown by g on every side,
    its reach towards the wall grows by g (|cos| + |sin|) of its turn, so it clears by
    d / (|cos turn| + |sin turn|): d square to the wall, d / sqrt(2) at 45 degrees, where the
    disc cover's clearance is nearer d and is taken instead; neither exceeds d."""
    occupied = np.zeros((20, 20), bool)
    occupied[:4] = True                              # the wall: y < 6 m
    omap = from_array(occupied, 1.5)
    cover = Footprint.from_vehicle(4.708, 1.81)
    d = 0.37
    reach = 4.708 / 2 * abs(math.sin(turn)) + 1.81 / 2 * abs(math.cos(turn))
    pose = np.array([[15.0, 6.0 + reach + d, turn]])
    discs = np.array([cover_clearance(omap, cover, pose[0])])
    got = rectangle_clearance(omap, cover, pose, discs, tol=1e-4)
    grown = d / (abs(math.cos(turn)) + abs(math.sin(turn)))
    assert got == pytest.approx(max(grown, discs[0]), abs=1e-4) and got <= d
    if turn == 0.0:
        assert got == pytest.approx(d, abs=1e-4) and discs[0] < d - 0.25   # the discs' 0.29 m


def cover_clearance(omap, footprint, pose):
    """[m] the disc cover's clearance at `pose`, by dense points on each disc's circle."""
    centres = footprint.disc_centres(pose)
    angle = np.linspace(0, 2 * np.pi, 2000)
    ring = centres[:, None, :] + footprint.radius * np.stack([np.cos(angle), np.sin(angle)], -1)
    return float(ring[..., 1].min() - 6.0)
