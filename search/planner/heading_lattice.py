"""A guide with heading: the car's cost to go over a coarse (x, y, heading) lattice, solved by
Dijkstra from the goal, as Hybrid A*'s heuristics are precomputed. Its moves are arcs of one
length that turn at most as tightly as the car (a little tighter), driven forwards (and with
reverse gear backwards, at reverse_penalty per metre, cusps free), whose centre keeps the
corridor proof's clearance (guide.corridors) at every lattice point it passes. So a pose
beside the goal facing away ranks by the loop it needs where there is room for one, and by
the way round where there is not. A move's end is rounded to the lattice, so the cost to go
is the lattice's, not a bound of the car's: it orders the tree, it never prunes it."""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from stepzoo.search.world.footprint import Footprint
from stepzoo.search.world.maps import OccupancyMap, fine_distance

HEADINGS = 16     # heading cells of the lattice: pi/8, the pruning cell's default
FINE = 0.375      # [m] about the spacing of the lattice the moves are checked on
SPACING = 1.5     # [m] about the lattice's spacing: a multiple of FINE's
MOVE_SPACINGS = 3  # a move's length in spacings: long enough that its end's rounding is small


class Move(NamedTuple):
    """A forward move from a coarse lattice point: its start heading cell, the fine lattice
    (row, col) offsets its footprint covers, its end's coarse (row, col) offset and heading
    cell, and its length [m] (what it costs)."""
    heading: int
    samples: np.ndarray
    rows: int
    cols: int
    end_heading: int
    length: float


class HeadingLattice:
    """The cost to go `cost` [m] (HEADINGS, rows, cols) of the coarse lattice points (every
    `stride`-th of the map's lattice, cell centres where the stride is SUBDIV) to `goal`
    [X, Y, psi] for a car of `width` [m] turning at `radius` [m]; inf where the goal is out
    of reach. Moves backwards cost `reverse_penalty` per metre, or are not taken (None)."""

    def __init__(self, omap: OccupancyMap, goal, footprint: Footprint, radius: float,
                 reverse_penalty: float | None = None):
        self.omap, self.goal, self.footprint = omap, np.asarray(goal, float), footprint
        # The moves are checked on a lattice of about FINE [m]: SUBDIV's is 1.5 m on a map of
        # 3 m cells, as wide as the slack a door leaves a car.
        self.sub = max(1, round(omap.resolution / FINE))
        step = omap.resolution / self.sub
        self.stride = max(1, round(SPACING / step))
        self.step, self.spacing = step, self.stride * step
        self.length = MOVE_SPACINGS * self.spacing
        self.bin = 2 * math.pi / HEADINGS
        # The tightest turn a move takes: its heading change rounded down to whole cells, so
        # no move turns tighter than the car (rounded up, the lattice turned a car beside the
        # goal but facing across it onto the goal's heading in one move the car cannot drive).
        self.turns = max(1, math.floor(self.length / (radius * self.bin)))
        # A disc centre is within step / sqrt(2) of its nearest lattice point.
        distance = fine_distance(omap.occupied, self.sub) * step
        free = (distance >= footprint.radius - step / math.sqrt(2)) & (distance > 0)
        self.shape = (HEADINGS, *((n - 1) // self.stride + 1 for n in free.shape))
        self.moves = self._moves(step)
        src, dst, cost = self._edges(free, step, reverse_penalty)
        self.cost = self._solve(src, dst, cost)
        finite = np.isfinite(self.cost)
        self.largest = float(self.cost[finite].max()) if finite.any() else 0.0

    def _moves(self, step) -> list[Move]:
        """The forward moves from a coarse lattice point: per heading cell, arcs of `length`
        turning -turns..turns heading cells, and a straight move of one spacing (so that a
        straight corridor's every lattice point is reached)."""
        moves = []
        for k in range(HEADINGS):
            for n, length in [(n, self.length) for n in range(-self.turns, self.turns + 1)] + [
                    (0, self.spacing)]:
                moves.append(self._move(k, n, length, step))
        return moves

    def _move(self, k: int, n: int, length: float, step: float) -> Move:
        """The arc of `length` [m] from heading cell k turning n cells, its footprint's disc
        centres sampled every half fine step."""
        s = np.linspace(0.0, length, int(math.ceil(2 * length / step)) + 1)
        th0, kappa = k * self.bin, n * self.bin / length
        if n == 0:
            x, y = s * math.cos(th0), s * math.sin(th0)
        else:
            x = (np.sin(th0 + kappa * s) - math.sin(th0)) / kappa
            y = (math.cos(th0) - np.cos(th0 + kappa * s)) / kappa
        end_r, end_c = round(y[-1] / self.spacing), round(x[-1] / self.spacing)
        th = th0 + kappa * s
        ys = y[:, None] + np.sin(th)[:, None] * self.footprint.offsets
        xs = x[:, None] + np.cos(th)[:, None] * self.footprint.offsets
        fine = np.column_stack([np.rint(ys.ravel() / step), np.rint(xs.ravel() / step)])
        ends = [[end_r * self.stride, end_c * self.stride]]
        # A straight move costs at least the lattice distance it covers (one spacing rounds a
        # diagonal heading's 1.5 m to 2.1 m).
        cost = max(length, math.hypot(end_r, end_c) * self.spacing) if n == 0 else length
        return Move(k, np.unique(np.vstack([fine.astype(int), ends]), axis=0), end_r, end_c,
                    (k + n) % HEADINGS, cost)

    def _edges(self, free, step, reverse_penalty):
        """(sources, destinations, costs) of the lattice's moves, as state indices."""
        _, rows, cols = self.shape
        pad = int(math.ceil((self.length + self.footprint.reach) / step)) + self.stride + 1
        self.framed = framed = np.pad(free, pad, constant_values=False)
        self.r0 = r0 = pad
        index = np.arange(HEADINGS * rows * cols).reshape(self.shape)
        gears = [(1.0, 0)]
        if reverse_penalty is not None:
            # Backwards: the forward move of the opposite heading, arriving facing away (the
            # footprint's discs lie symmetric about its centre).
            gears.append((reverse_penalty, HEADINGS // 2))
        src, dst, cost = [], [], []
        for per_metre, flip in gears:
            for move in self.moves:
                ok = np.ones((rows, cols), bool)
                for dr, dc in move.samples:
                    ok &= framed[r0 + dr: r0 + dr + rows * self.stride: self.stride,
                                 r0 + dc: r0 + dc + cols * self.stride: self.stride][
                                     :rows, :cols]
                r, c = np.nonzero(ok)
                src.append(index[(move.heading - flip) % HEADINGS, r, c])
                dst.append(index[(move.end_heading - flip) % HEADINGS, r + move.rows,
                                 c + move.cols])
                cost.append(np.full(len(r), per_metre * move.length))
        return np.concatenate(src), np.concatenate(dst), np.concatenate(cost)

    def _solve(self, src, dst, cost) -> np.ndarray:
        """(HEADINGS, rows, cols) [m] the cost to go: Dijkstra along the moves reversed from
        the goal's states: the two heading cells about its heading at the lattice points
        within a spacing of it that lie at or behind it (a car a spacing ahead of the goal,
        facing its way, has passed it)."""
        n = int(np.prod(self.shape))
        graph = coo_matrix((cost, (dst, src)), shape=(n, n)).tocsr()   # reversed moves
        _, rows, cols = self.shape
        gy, gx = (v[0] for v in self._coarse(self.goal[None]))
        k = (self.goal[2] / self.bin) % HEADINGS
        ahead = np.array([math.cos(self.goal[2]), math.sin(self.goal[2])])
        goals = set()
        for r in range(max(0, math.floor(gy) - 1), min(rows, math.floor(gy) + 3)):
            for c in range(max(0, math.floor(gx) - 1), min(cols, math.floor(gx) + 3)):
                offset = np.array([c - gx, r - gy])
                if math.hypot(*offset) <= 1 and offset @ ahead <= 1e-9:
                    goals |= {(int(math.floor(k) + dk) % HEADINGS, r, c) for dk in (0, 1)}
        index = [np.ravel_multi_index(g, self.shape) for g in sorted(goals)]
        if not index:
            return np.full(self.shape, np.inf)
        return dijkstra(graph, directed=True, indices=index, min_only=True).reshape(self.shape)

    def _coarse(self, poses) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) of poses (K, 2+) in coarse lattice units (not rounded)."""
        omap, step = self.omap, self.step
        col = (poses[:, 0] - omap.origin[0]) / step / self.stride
        row = (poses[:, 1] - omap.origin[1]) / step / self.stride
        return row, col

    def at(self, poses) -> np.ndarray:
        """(K,) [m] the cost to go of each pose (K, 3+) [X, Y, psi]: at its heading cell, the
        least over the lattice points of the square (one spacing a side) about it of their
        cost to go plus the distance to them; inf where none reaches the goal. (A straight
        corridor is driven in moves that skip lattice points; the square sees past that.)"""
        return self._state(poses)[3]

    def _state(self, poses) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(heading cell, row, col) of the lattice state whose cost to go `at` reads, and
        what it reads [m]."""
        row, col = self._coarse(poses)
        _, rows, cols = self.shape
        k = np.rint(poses[:, 2] / self.bin).astype(int) % HEADINGS
        r0 = np.clip(np.floor(row), 0, rows - 1).astype(int)
        c0 = np.clip(np.floor(col), 0, cols - 1).astype(int)
        best = np.full(len(poses), np.inf)
        r, c = r0.copy(), c0.copy()
        for dr in (0, 1):
            for dc in (0, 1):
                rr, cc = np.minimum(r0 + dr, rows - 1), np.minimum(c0 + dc, cols - 1)
                value = self.cost[k, rr, cc] + np.hypot(rr - row, cc - col) * self.spacing
                better = value < best
                best = np.where(better, value, best)
                r, c = np.where(better, rr, r), np.where(better, cc, c)
        return k, r, c, best

    def descend(self, pose, distance: float) -> np.ndarray | None:
        """[m] (X, Y) `distance` [m] down the cost to go from the pose's best lattice state
        (at's), forwards along the moves that keep to it, or where they stop; None where no
        state near the pose reaches the goal."""
        k, r, c, value = (v[0] for v in self._state(np.asarray(pose, float)[None]))
        if not np.isfinite(value):
            return None
        k, r, c = int(k), int(r), int(c)
        _, rows, cols = self.shape
        travelled = 0.0
        while travelled < distance and self.cost[k, r, c] > 0:
            for move in self.moves:
                rr, cc = r + move.rows, c + move.cols
                if (move.heading == k and 0 <= rr < rows and 0 <= cc < cols
                        and move.length + self.cost[move.end_heading, rr, cc]
                        <= self.cost[k, r, c]
                        and self.framed[self.r0 + r * self.stride + move.samples[:, 0],
                                        self.r0 + c * self.stride + move.samples[:, 1]].all()):
                    k, r, c, travelled = move.end_heading, rr, cc, travelled + move.length
                    break
            else:
                break
        return np.array([c, r]) * self.spacing + self.omap.origin

