"""The search's sense of direction on the lattice of the occupancy map: which lattice points
the car's centre may use (corridors), the geodesic distance from each to the goal (Hybrid
A*'s obstacle heuristic), a guide geodesic that keeps out of alleys narrower than the car,
and the car's obstacle-blind bound (Dubins, Reeds-Shepp)."""
from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import label, minimum_filter
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from stepzoo.search.planner.heading_lattice import HeadingLattice
from stepzoo.search.proofs.car_bounds import dubins_length, reeds_shepp_length
from stepzoo.search.world.maps import SUBDIV, OccupancyMap


def corridors(omap: OccupancyMap, width: float) -> np.ndarray:
    """Connected components of the lattice points where the centre of a car `width` [m] wide
    may be.

    The footprint contains the disc of radius width/2 about its centre, so a collision-free
    path keeps the centre that far from obstacles; each of its points is within step/sqrt(2)
    of a lattice point, whose exact distance is then >= width/2 - step/sqrt(2) (distance is
    1-Lipschitz), and those nearest lattice points form an 8-connected chain. Different
    components therefore prove that no path exists; the same one proves nothing."""
    step = omap.resolution / SUBDIV
    room = omap.distance >= width / 2 - step / math.sqrt(2)
    return label(room, structure=np.ones((3, 3)))[0]


def lattice(omap: OccupancyMap, pose) -> tuple[int, int]:
    """(row, col) of the lattice point nearest `pose` [X, Y, ...] [m], clipped to the map."""
    step = omap.resolution / SUBDIV
    col, row = np.rint((pose[:2] - omap.origin) / step).astype(int)
    rows, cols = omap.distance.shape
    return min(max(row, 0), rows - 1), min(max(col, 0), cols - 1)


def geodesic(omap: OccupancyMap, labels: np.ndarray, goal, allowed=None) -> np.ndarray:
    """[m] the shortest 8-connected path over free lattice points of the goal's corridor
    component (`labels`, from `corridors`) from every lattice point to the goal's, the guide H
    of the search (Hybrid A*'s obstacle heuristic); a point just outside takes its best
    neighbour's value plus a diagonal step, and inf marks points with no way to the goal."""
    step = omap.resolution / SUBDIV
    target = lattice(omap, goal)
    mask = (labels == labels[target]) & (omap.distance > 0)
    if allowed is not None:
        mask &= allowed
    mask[target] = True
    index = np.full(mask.shape, -1)
    index[mask] = np.arange(mask.sum())
    rows, cols = mask.shape
    src, dst, weight = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = index[:rows - dr, max(0, -dc):cols - max(0, dc)]
        b = index[dr:, max(0, dc):cols - max(0, -dc) if dc < 0 else cols]
        both = (a >= 0) & (b >= 0)
        src.append(a[both])
        dst.append(b[both])
        weight.append(np.full(both.sum(), step * math.hypot(dr, dc)))
    n = int(mask.sum())
    graph = coo_matrix((np.concatenate(weight), (np.concatenate(src), np.concatenate(dst))),
                       shape=(n, n)).tocsr()
    field = np.full(mask.shape, np.inf)
    field[mask] = dijkstra(graph, directed=False, indices=int(index[target]))
    near = minimum_filter(field, size=3, mode="constant", cval=np.inf) + step * math.sqrt(2)
    return np.where(np.isfinite(field), field, near)


def guide_field(omap: OccupancyMap, labels: np.ndarray, goal, plain: np.ndarray, room: float,
                near_m: float) -> np.ndarray:
    """[m] the search's guide: the geodesic over lattice points where the car's centre has
    `room` [m] of clearance (half its width + margin) or that lie within `near_m` [m] of the
    goal, so the search is not led into alleys narrower than the car; points off it rank
    after every point on it, by the `plain` geodesic."""
    step = omap.resolution / SUBDIV
    rows, cols = np.indices(omap.distance.shape)
    near = np.hypot(cols * step + omap.origin[0] - goal[0],
                    rows * step + omap.origin[1] - goal[1])
    tight = geodesic(omap, labels, goal, (omap.distance >= room) | (near <= near_m))
    finite = np.isfinite(tight)
    return np.where(finite, tight, plain + (tight[finite].max() if finite.any() else 0))


class Guide:
    """The fields of one goal and the bounds read from them for the tree's nodes; with a
    `heading` lattice (heading_lattice.HeadingLattice) the guide reads the pose's heading too."""

    def __init__(self, omap: OccupancyMap, labels: np.ndarray, goal, room: float,
                 near_m: float, radius: float, reverse: bool,
                 heading: HeadingLattice | None = None):
        self.omap, self.goal, self.radius, self.reverse = omap, goal, radius, reverse
        self.near_m, self.heading = near_m, heading
        self.geodesic = geodesic(omap, labels, goal)
        self.field = guide_field(omap, labels, goal, self.geodesic, room, near_m)

    def rest(self, xy, field=None) -> np.ndarray:
        """(K,) [m] the lattice field (default: the geodesic distance to the goal, inf: none)
        at the lattice points nearest points (K, 2+)."""
        omap = self.omap
        step = omap.resolution / SUBDIV
        col, row = omap.nearest_lattice((xy[:, 0] - omap.origin[0]) / step,
                                        (xy[:, 1] - omap.origin[1]) / step)
        return (self.geodesic if field is None else field)[row, col]

    def guide(self, poses) -> np.ndarray:
        """(K,) [m] the guide field at poses (K, 3+); with a heading lattice, the larger of it
        and the lattice's cost to go (inf there: the guide field plus the lattice's largest
        finite cost, after every pose the lattice leads)."""
        field = self.rest(poses, self.field)
        if self.heading is None:
            return field
        lattice = self.heading.at(poses)
        far = self.heading.largest + field
        return np.where(np.isfinite(lattice), np.maximum(field, lattice), far)

    def car_bound(self, poses) -> np.ndarray:
        """(K,) [m] the shortest path of the car from poses (K, 3+) to the goal ignoring
        obstacles, a lower bound of the rest: Dubins forwards, Reeds-Shepp with reverse gear;
        0 (a weaker bound) beyond 2 near_m (connect_radius) of the goal, where the geodesic
        leads and the turning radius hardly adds to it."""
        bound = reeds_shepp_length if self.reverse else dubins_length
        out = np.zeros(len(poses))
        near = np.hypot(*(poses[:, :2] - self.goal[:2]).T) <= 2 * self.near_m
        if near.any():
            out[near] = bound(poses[near], self.goal, self.radius)
        return out

    def descend(self, state, distance: float) -> np.ndarray:
        """[m] the lattice point `distance` [m] down the guide field from the state's
        (steepest descent), or where the descent stops; with a heading lattice, down its cost
        to go from the state's pose where it leads."""
        if self.heading is not None:
            point = self.heading.descend(state, distance)
            if point is not None:
                return point
        omap = self.omap
        step = omap.resolution / SUBDIV
        cols, rows = omap.nearest_lattice((state[0] - omap.origin[0]) / step,
                                          (state[1] - omap.origin[1]) / step)
        row, col = int(rows), int(cols)
        field = self.field
        for _ in range(max(1, round(distance / step))):
            r0, c0 = max(row - 1, 0), max(col - 1, 0)
            window = field[r0:row + 2, c0:col + 2]
            k = int(np.argmin(window))
            if not window.flat[k] < field[row, col]:
                break
            row, col = r0 + k // window.shape[1], c0 + k % window.shape[1]
        return np.array([col, row]) * step + omap.origin
