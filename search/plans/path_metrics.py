"""Measures of a planned path, as planner benchmarks report them: length, cusps (changes of
the direction of travel), clearance of the car's footprint, curvature and smoothness."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from stepzoo.search.world.footprint import Footprint
from stepzoo.search.world.maps import OccupancyMap
from stepzoo.search.plans.schema import PATH_METRICS


def path_metrics(rows, omap: OccupancyMap, footprint: Footprint) -> dict:
    """Of path rows (K, 4) [t s, X m, Y m, psi rad] at most a few cm apart: length [m]; cusps;
    clearance [m] of the footprint's discs (the exact distance from the disc cover, which
    holds the car, to the nearest obstacle cell or the map's edge; <= 0 touches), min and
    mean over rows; |curvature| [1/m], max and
    length-weighted mean; smoothness = integral of curvature^2 ds [1/m]. None for no path."""
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


def cusps(rows) -> int:
    """Changes of the direction of travel (forwards: along the heading) along path rows
    (K, 4) [t, X, Y, psi]."""
    rows = np.asarray(rows, float)
    step = np.diff(rows[:, 1:3], axis=0)
    along = step[:, 0] * np.cos(rows[:-1, 3]) + step[:, 1] * np.sin(rows[:-1, 3])
    direction = np.sign(along[np.hypot(step[:, 0], step[:, 1]) > 1e-9])
    return int(np.count_nonzero(direction[1:] != direction[:-1]))


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
