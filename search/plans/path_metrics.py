"""Measures of a planned path, as planner benchmarks report them: length, cusps (changes of
the direction of travel), clearance of the car's footprint, curvature and smoothness; and its
drivability, from the path rows alone: the curvature, implied steer rate and lateral
acceleration against the car's limits, and how much of it is driven backwards."""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from stepzoo.dynamics.kinematic import shifted
from stepzoo.search.world.footprint import Footprint
from stepzoo.search.world.maps import OccupancyMap
from stepzoo.search.plans.schema import DRIVABILITY_KEYS, PATH_METRICS

# [s] the time over which the heading's change per metre gives the curvature: longer than the
# path's node spacing (the rows between nodes are linear interpolation, whose curvature jumps
# at each node), short enough to see a steer ramp. In time rather than arc length, so that
# where the car slows to turn the wheel the window does not reach over the turning.
WINDOW_S = 0.25
MIN_TRAVEL_M = 1e-3   # [m] a window with less travel (the car all but stopped) has no curvature
STILL_M = 1e-5        # [m] a step between rows this short is standing still (rows hold 1e-6 m)
COURSE_STEP_M = 0.01  # [m] the least step whose direction gives a course: 0.1 mrad of rounding
# [m] read from the course, a window with less travel has no curvature: the rows' positions
# carry errors of a micrometre (plan.json's rounding) to ten (the connection's rows where it
# stops the car), a course error of 0.1 to 1 mrad over a chord, which over a centimetre of
# travel is an implied steer of 0.03 to 0.3 rad; the path rows are filled to this spacing
# (files.ROW_SPACING_M), so a window with less travel sees a chord or two.
COURSE_MIN_TRAVEL_M = 0.05
# What the rows' finite differences allow above each limit before a plan is not drivable: a
# window straddling a node or a cusp sees a step in curvature as a short ramp.
TOLERANCE = {"curvature_1pm": 1.1, "steer_rate_radps": 1.25, "lateral_acceleration_mps2": 1.15}


def path_metrics(rows, omap: OccupancyMap, footprint: Footprint) -> dict:
    """Of path rows (K, 4) [t s, X m, Y m, psi rad] at most a few cm apart: length [m]; cusps;
    clearance [m] of the footprint's discs (the exact distance from the disc cover, which
    holds the car, to the nearest obstacle cell or the map's edge; <= 0 touches), min and
    mean over rows, the footprint facing psi; |curvature| [1/m], max and length-weighted
    mean; smoothness = integral of curvature^2 ds [1/m]. None for no path."""
    rows = np.asarray(rows, float)
    if len(rows) < 2:
        return dict.fromkeys(PATH_METRICS)
    step = np.diff(rows[:, 1:3], axis=0)
    ds = np.hypot(step[:, 0], step[:, 1])
    turn = np.remainder(np.diff(rows[:, 3]) + np.pi, 2 * np.pi) - np.pi
    moving = ds > 1e-9
    kappa = np.abs(turn[moving]) / ds[moving]
    centres = footprint.disc_centres(rows[:, 1:4])
    clearance = distance_to_obstacles(omap, centres.reshape(-1, 2)).reshape(
        centres.shape[:-1]).min(axis=-1) - footprint.radius
    length = float(ds.sum())
    return {"length_m": length,
            "cusps": cusps(rows),
            "clearance_min_m": float(clearance.min()),
            "clearance_mean_m": float(clearance.mean()),
            "curvature_max": float(kappa.max()) if kappa.size else 0.0,
            "curvature_mean": float((kappa * ds[moving]).sum() / length) if length else 0.0,
            "smoothness": float((kappa ** 2 * ds[moving]).sum())}


def drivability(rows, wheelbase, delta_max, max_steer_rate, max_lateral_acceleration,
                window=WINDOW_S, heading="psi", lr=None) -> dict:
    """plan.json's `drivability` block of path rows (K, 4) [t s, X m, Y m, psi rad]: in each run
    between cusps, windows of `window` [s] centred every window/4; in each, the curvature
    kappa [1/m] is the heading's change over the distance travelled, the implied steer angle
    atan(wheelbase * kappa) (its sign by the direction of travel), the lateral acceleration
    v^2 |kappa| [m/s^2] at the window's mean speed v; the steer rate [rad/s] is the implied
    steer's change between windows over that of their times weighted by distance (the
    curvature's weights: exact for a steer ramp at any speed, also where the car slows to
    turn the wheel; the heading a run after a cusp sets off with is its own, the wheel turned
    at the standstill). reverse_length_m [m] driven backwards and cusps, both of the rows'
    own (X, Y) whatever the heading read. `drivable`:
    every measure within TOLERANCE times the car's limit (curvature: tan(delta_max) /
    wheelbase, delta_max [rad]; max_steer_rate [rad/s]; max_lateral_acceleration [m/s^2]). A
    run shorter than a window adds no measure. `heading`: "psi", the rows' heading column
    (plan.json's block: the dynamic bicycle's body, the kinematic bicycle's direction of
    travel), or "course", the direction of travel of (X, Y) on every row (course_rows), which
    reads a steer ramp of the dynamic bicycle at about twice its rate (its centre of gravity
    moves sideways before its body turns) and a change of the slip in one row as a kink, and
    has no curvature in a window with less than COURSE_MIN_TRAVEL_M of travel; or
    "rear_axle", the direction of travel of the rear axle's centre, `lr` [m] behind (X, Y)
    along psi (rear_axle_rows): a rigid car's point that moves along its body, on curvature
    tan(delta) / wheelbase, whatever its speed or the rate of its steer."""
    rows = own = np.asarray(rows, float)
    by_course = heading in ("course", "rear_axle")
    if by_course and len(rows) >= 2:
        rows, way = course_rows(rear_axle_rows(rows, lr) if heading == "rear_axle" else rows)
    out = dict.fromkeys(DRIVABILITY_KEYS)
    limit = {"curvature_1pm": math.tan(delta_max) / wheelbase,
             "steer_rate_radps": max_steer_rate,
             "lateral_acceleration_mps2": max_lateral_acceleration}
    out.update(heading=heading, window_s=window, limits=limit, tolerance=dict(TOLERANCE))
    if len(rows) < 2:
        return out
    ds, along = steps(rows)
    along = np.sign(along)
    moving = np.flatnonzero(ds > STILL_M)
    kappa, rate, lateral = [0.0], [0.0], [0.0]
    if by_course:
        # From the last chord before a cusp to the first after it is in neither run: each run
        # holds its own chords' courses only (the step read as the later run's first, and
        # its first row as the earlier run's last course, 3.28 rad/s where the rows ramp at
        # 0.32).
        moving = moving[way[moving] == way[moving + 1]]
    # Runs of one direction of travel: the moving steps, split where the direction flips.
    runs = np.split(moving, np.flatnonzero(np.diff(along[moving]) != 0) + 1)
    for k, run in enumerate(runs):
        if not run.size:
            continue
        # Every row of the run, its stops included: the time stood still is time steered.
        span = rows[run[0]:run[-1] + 2]
        t = span[:, 0]
        if t[-1] - t[0] < window:
            continue
        s = np.r_[0.0, np.cumsum(ds[run[0]:run[-1] + 1])]
        weighted = np.r_[0.0, np.cumsum((t[1:] + t[:-1]) / 2 * np.diff(s))]  # of t ds
        heading = np.unwrap(span[:, 3])
        if k and len(heading) > 2 and not by_course:
            # A cusp's row holds the heading the car stopped with; it sets off with its wheel
            # turned at the standstill, along the run's own heading: extrapolated back from
            # the next two rows, so that turning the wheel while stopped is not read as a
            # steer rate. (A course's first row is already the run's own: its first chord.)
            heading[0] = 2 * heading[1] - heading[2]
        centre = np.arange(t[0] + window / 2, t[-1] - window / 2 + 1e-12, window / 4)
        travel = np.interp(centre + window / 2, t, s) - np.interp(centre - window / 2, t, s)
        turn = (np.interp(centre + window / 2, t, heading)
                - np.interp(centre - window / 2, t, heading))
        seen = travel > (COURSE_MIN_TRAVEL_M if by_course else MIN_TRAVEL_M)
        if not seen.any():
            continue
        k, travel, centre = turn[seen] / travel[seen], travel[seen], centre[seen]
        when = (np.interp(centre + window / 2, t, weighted)
                - np.interp(centre - window / 2, t, weighted)) / travel
        steer = np.arctan(wheelbase * k * along[run[0]])
        kappa.append(float(np.abs(k).max()))
        lateral.append(float(((travel / window) ** 2 * np.abs(k)).max()))
        apart = np.diff(when) > 1e-6
        if apart.any():
            rate.append(float((np.abs(np.diff(steer))[apart] / np.diff(when)[apart]).max()))
    measured = {"max_curvature_1pm": max(kappa), "max_steer_rate_radps": max(rate),
                "max_lateral_acceleration_mps2": max(lateral)}
    # The path's own (X, Y): the reading's course rows drop the chords beside a cusp.
    ds, along = steps(own)
    backwards = (ds > STILL_M) & (along < 0)
    out.update(measured, reverse_length_m=float(ds[backwards].sum()),
               cusps=cusps(own), drivable=all(
                   measured[f"max_{name}"] <= TOLERANCE[name] * limit[name] for name in limit))
    return out


def rear_axle_rows(rows, lr) -> np.ndarray:
    """Path rows (K, 4) [t, X, Y, psi] of a car's centre of gravity -> the same rows of its
    rear axle's centre, lr [m] behind along psi."""
    rows = np.asarray(rows, float)
    return np.column_stack([rows[:, 0], shifted(rows[:, 1:4], -lr)])


def course_rows(rows) -> tuple[np.ndarray, np.ndarray]:
    """Path rows (K, 4) [t, X, Y, psi] -> (one row per chord of about COURSE_STEP_M between
    them, at its middle, whose heading is the chord's direction of travel (turned by pi where
    it runs backwards); each chord's way, +1 forwards or -1). None across a cusp, nor on
    either side of one: the rows' step that ends there may hold the stop itself (a
    connection's interval in which the car stops and sets off again), its direction then
    neither run's."""
    ds, along = steps(rows)
    along = np.sign(along)
    s = np.r_[0.0, np.cumsum(ds)]
    moving = np.flatnonzero(ds > STILL_M)
    flips = moving[1:][np.diff(along[moving]) != 0]   # the first step of each later run
    ends = np.unique(np.r_[0, np.searchsorted(s, np.arange(0.0, s[-1], COURSE_STEP_M)),
                           flips, len(rows) - 1])
    a, b = ends[:-1], ends[1:]
    chord = rows[b, 1:3] - rows[a, 1:3]
    angle = np.arctan2(chord[:, 1], chord[:, 0])
    back = chord[:, 0] * np.cos(rows[a, 3]) + chord[:, 1] * np.sin(rows[a, 3]) < 0
    mid = (rows[a, :3] + rows[b, :3]) / 2
    keep = (np.hypot(chord[:, 0], chord[:, 1]) > STILL_M) & ~np.isin(a, flips) & ~np.isin(b, flips)
    return (np.column_stack([mid, angle + np.where(back, np.pi, 0.0)])[keep],
            np.where(back, -1, 1)[keep])


def cusps(rows) -> int:
    """Changes of the direction of travel (forwards: along the heading) along path rows
    (K, 4) [t, X, Y, psi]."""
    ds, along = steps(np.asarray(rows, float))
    direction = np.sign(along[ds > STILL_M])
    return int(np.count_nonzero(direction[1:] != direction[:-1]))


def steps(rows) -> tuple[np.ndarray, np.ndarray]:
    """(K-1,) lengths [m] of the steps between path rows (K, 4) [t, X, Y, psi] and (K-1,)
    their projections [m] on the heading of the row each sets off from (> 0 forwards)."""
    step = np.diff(rows[:, 1:3], axis=0)
    return (np.hypot(step[:, 0], step[:, 1]),
            step[:, 0] * np.cos(rows[:-1, 3]) + step[:, 1] * np.sin(rows[:-1, 3]))


def distance_to_obstacles(omap: OccupancyMap, xy) -> np.ndarray:
    """(K,) [m] exact distance from points (K, 2) to the occupied cells and the outside of
    the grid (0 inside either). Candidates are the nearest cell centres: the nearest square's
    centre is at most half a cell diagonal farther than the square, so once the farthest
    candidate centre is that much beyond the best square found, no other square is nearer."""
    xy = np.asarray(xy, float)
    res = omap.resolution
    u, v = (xy[:, 0] - omap.origin[0]) / res, (xy[:, 1] - omap.origin[1]) / res
    rows, cols = omap.occupied.shape
    best = np.maximum(np.minimum.reduce([u, cols - u, v, rows - v]), 0.0)
    cells = np.argwhere(omap.occupied)  # (row, col)
    if len(cells):
        tree = cKDTree(cells[:, ::-1] + 0.5)
        k = min(CANDIDATES, len(cells))
        found = np.full(len(xy), np.inf)
        done = np.zeros(len(xy), bool)
        while True:
            todo = np.flatnonzero(~done)
            if not todo.size:
                break
            reach, idx = tree.query(np.column_stack([u[todo], v[todo]]), k=k)
            reach, idx = reach.reshape(len(todo), -1), idx.reshape(len(todo), -1)
            c, r = cells[idx, 1], cells[idx, 0]
            du = np.maximum(np.maximum(c - u[todo, None], u[todo, None] - (c + 1)), 0.0)
            dv = np.maximum(np.maximum(r - v[todo, None], v[todo, None] - (r + 1)), 0.0)
            found[todo] = np.hypot(du, dv).min(axis=1)
            done[todo] = (k == len(cells)) | (reach[:, -1] >= found[todo] + np.sqrt(0.5))
            k = min(4 * k, len(cells))
        best = np.minimum(best, found)
    return best * res


CANDIDATES = 16  # nearest cell centres examined first per point
