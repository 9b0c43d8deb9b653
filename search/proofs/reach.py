"""A proof that a forward-only car cannot get away from a pose: a grid over-approximation of
the poses every collision-free forward path of curvature <= 1/radius can reach, grown until
it closes inside a window around the pose.

On a `Grid`, cells are (x, y) squares of cell_m and heading bins of 2 pi / heading_bins. A
path's poses every step_m of its length lie in cells that the growth reaches: from a cell it
adds every cell that a path of length step_m can end in from any pose of the cell (a box of
displacements bounded per end-heading bin, below), except cells where every pose collides:
some disc of the footprint, moved anywhere the cell allows, still covers an obstacle cell
or the map's outside (`OccupancyMap.disc_hits` decides that exactly), or where the check
decides by the car's rectangle (`rectangle_decides`), the rectangle shrunk by as much as the
cell moves its points still overlaps one (`OccupancyMap.rectangle_hits`). If the growth closes
without reaching the window's edge, no forward path leaves the window; a goal farther than
step_m from every reached cell cannot be reached. The paths are those of the kinematic
bicycle (moving along the heading), as in `departure`. Two grids: COARSE for a pose boxed in
within metres, FINE for a pocket a car's length across."""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from stepzoo.search.proofs.departure import witness_arcs
from stepzoo.search.world.footprint import Footprint, first_collision, rectangle_decides
from stepzoo.search.world.maps import EXACT_CELLS, OccupancyMap

QUADRATURE = 400      # points of the displacement bounds' integrals


class Grid(NamedTuple):
    """The growth's resolution: position cells of `cell_m` [m], `heading_bins` heading bins,
    poses followed every `step_m` [m] of path, within `window_m` [m] (half side) of the pose."""
    cell_m: float
    heading_bins: int
    step_m: float
    window_m: float


# 0.05 m cells, 1-degree bins, a pose every metre, a 7 m window. Measured on
# room-64-64-8-09's start: 0.1 m cells and 2-degree bins do not close (the cells' rounding, a
# cell and a bin per step, lets the set slide along the wall); these do.
COARSE = Grid(cell_m=0.05, heading_bins=360, step_m=1.0, window_m=7.0)
# A pocket a car's length across: COARSE follows a path's poses every metre only, so its
# growth steps past a wall corner that every path collides with on the way (den312d-11's goal,
# the rigid car arriving forwards: its growth slides out along the street); FINE follows them
# every half metre, on cells half and bins a sixth as large, in a window half as wide. Measured
# on den312d-11's goal with the car's rectangle deciding: 720 and 1440 bins let the set drift
# a bin a step through the gap the rectangle leaves by the corner (as do 0.0125 m cells or
# quarter-metre steps on 720 bins); on 1800, 2160 and 2880 it closes, 2.64 m out at most.
FINE = Grid(0.025, 2160, 0.5, 3.5)


class _Box(NamedTuple):
    """[m] bounds of a displacement in the start's frame: ahead and to the left."""
    ahead_lo: float
    ahead_hi: float
    left_lo: float
    left_hi: float


def _displacement_box(turn_lo, turn_hi, step, radius) -> _Box:
    """Bounds of the displacement [m], in the start's
    frame, of every path of length `step` and curvature <= 1/radius whose heading turns by an
    angle in [turn_lo, turn_hi] [rad] (with step / radius <= pi / 2, so sin grows with the
    heading change and cos falls with its size)."""
    t = (np.arange(QUADRATURE) + 0.5) * step / QUADRATURE
    # The heading change at t is at most where the path turns left at once and back at the
    # end to turn_hi, at least the mirror of that: every path lies between.
    top = np.minimum(t / radius, turn_hi + (step - t) / radius)
    low = np.maximum(-t / radius, turn_lo - (step - t) / radius)
    nearest = np.where((low <= 0) & (top >= 0), 0.0, np.minimum(np.abs(low), np.abs(top)))
    farthest = np.maximum(np.abs(low), np.abs(top))
    dt = step / QUADRATURE
    # Midpoint sums of functions with slope <= 1/radius: off by at most step^2/(24 radius N^2)
    # per unit; the pad covers that many times over.
    pad = 1e-6 + step * step / (radius * QUADRATURE)
    return _Box(float(np.cos(farthest).sum() * dt) - pad, float(np.cos(nearest).sum() * dt) + pad,
                float(np.sin(low).sum() * dt) - pad, float(np.sin(top).sum() * dt) + pad)


def _dilate(grid, lo, hi, axis) -> np.ndarray:
    """bool grid OR-shifted by every offset lo..hi [cells] along `axis`, grown to hold every
    shift: index m of the result is index m + lo of the grid's frame."""
    width = hi - lo + 1
    n = grid.shape[axis]
    count = np.cumsum(grid, axis=axis)
    m = np.arange(n + width - 1)
    upper = np.take(count, np.minimum(m, n - 1), axis=axis)
    below = np.take(count, np.maximum(m - width, -1), axis=axis)
    # Index -1 stands for "nothing below": the cumulative count there is 0.
    shape = [1] * grid.ndim
    shape[axis] = -1
    below = np.where((m - width < 0).reshape(shape), 0, below)
    return upper > below


def _blocked(omap: OccupancyMap, footprint: Footprint, x, y, heading,
             grid: Grid = COARSE) -> np.ndarray:
    """bool (K,): every pose of the cells of `grid` centred at (x, y) [m] with heading bins
    centred at `heading` [rad] (arrays (K,)) collides: where the check decides by the
    rectangle, the rectangle at the cell's centre, shrunk on every side by
    `rectangle_shrink`, still overlaps an obstacle; else some disc, shrunk by how far the
    cell lets its centre move, still covers one."""
    if rectangle_decides(omap, footprint):
        return footprint.rectangle_hits(omap, x, y, heading,
                                        -(rectangle_shrink(footprint, grid) + 1e-9))
    c, s = np.cos(heading), np.sin(heading)
    out = np.zeros(len(x), bool)
    for offset in footprint.offsets:
        # The centre moves at most half the cell's diagonal and |offset| * half a bin.
        shrink = grid.cell_m / math.sqrt(2) + abs(offset) * math.pi / grid.heading_bins
        out |= omap.disc_hits(x + offset * c, y + offset * s, footprint.radius - shrink - 1e-9)
    return out


def rectangle_shrink(footprint: Footprint, grid: Grid) -> float:
    """[m] the least delta >= cell_m / sqrt(2) + rho pi / heading_bins, rho the largest
    distance from (X, Y) to a corner of `footprint`'s rectangle shrunk by delta on every side:
    every pose of a `grid` cell holds that shrunk rectangle of the cell's centre pose.
    Proof: from the centre pose to any pose of the cell a body point q moves by at most
    cell_m / sqrt(2) + 2 |q| sin(pi / (2 heading_bins)) <= delta, and the points within delta
    of the shrunk rectangle are in the rectangle."""
    move, turn = grid.cell_m / math.sqrt(2), math.pi / grid.heading_bins
    ahead, across = abs(footprint.centre) + footprint.length / 2, footprint.width / 2

    def short(delta):   # the bound not yet met at delta (rho falls as delta grows)
        return delta < move + turn * math.hypot(ahead - delta, across - delta)
    lo, hi = move, move + turn * math.hypot(ahead, across)
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if short(mid) else (lo, mid)
    return hi


def forward_reach(omap: OccupancyMap, footprint: Footprint, pose, radius,
                  grid: Grid = COARSE):
    """The grown cells (bins, ny, nx) bool and the window's lower-left corner (x, y) [m], or
    None if the growth reaches the window's edge (nothing proved), for forward paths of
    curvature <= 1/radius [1/m] from `pose` [X, Y, psi], on `grid`."""
    cell_m, bins, step_m, window_m = grid
    if (not rectangle_decides(omap, footprint)
            and 2 * math.ceil(footprint.radius / omap.resolution) + 1 > EXACT_CELLS):
        return None  # disc_hits would answer from a lower bound: no proof from it
    if step_m / radius > math.pi / 2:
        return None  # the displacement bounds need a step's turn within a quarter turn
    n = int(round(2 * window_m / cell_m))
    corner = np.asarray(pose[:2], float) - window_m
    bin_size = 2 * math.pi / bins
    headings = (np.arange(bins) + 0.5) * bin_size
    # Collision is decided once per cell, when the growth first reaches it.
    checked = np.zeros((bins, n, n), bool)
    blocked = np.zeros((bins, n, n), bool)
    reach = np.zeros((bins, n, n), bool)
    start_bin = int((pose[2] % (2 * math.pi)) // bin_size) % bins
    reach[start_bin, n // 2, n // 2] = True
    most = math.ceil(step_m / radius / bin_size) + 1
    boxes = {d: _displacement_box(max((d - 1) * bin_size, -step_m / radius),
                                  min((d + 1) * bin_size, step_m / radius), step_m, radius)
             for d in range(-most, most + 1)
             if (d - 1) * bin_size < step_m / radius and (d + 1) * bin_size > -step_m / radius}
    # Per heading bin a and bin change d: the cells a step can shift by, (x_lo, x_hi, y_lo,
    # y_hi), from the box rotated to the bin's middle heading and padded by what any heading
    # of the bin (within half a bin of the middle) adds; a pose anywhere in its cell adds
    # one cell on the high side.
    shifts = {}
    for d, box in boxes.items():
        corners = np.array([(u, v) for u in (box.ahead_lo, box.ahead_hi)
                            for v in (box.left_lo, box.left_hi)])
        pad = np.hypot(*corners.T).max() * bin_size / 2
        x = np.cos(headings)[:, None] * corners[:, 0] - np.sin(headings)[:, None] * corners[:, 1]
        y = np.sin(headings)[:, None] * corners[:, 0] + np.cos(headings)[:, None] * corners[:, 1]
        shifts[d] = np.stack([np.floor((x.min(axis=1) - pad) / cell_m),
                              np.floor((x.max(axis=1) + pad) / cell_m) + 1,
                              np.floor((y.min(axis=1) - pad) / cell_m),
                              np.floor((y.max(axis=1) + pad) / cell_m) + 1], axis=1).astype(int)
    # A step moves at most `margin` cells: a reached cell nearer the edge could leave unseen.
    margin = int(max(np.abs(v).max() for v in shifts.values())) + 2
    # A free arc that gets as near the edge is a path the growth would follow there: say so
    # at once instead of growing the whole window (an open start costs seconds otherwise).
    arcs = witness_arcs(pose, radius, 2 * window_m, cell_m)
    hit = first_collision(omap, footprint, arcs)
    for arc, first in zip(arcs, hit):
        free = arc[:first] if first >= 0 else arc
        if np.abs(free[:, :2] - pose[:2]).max() >= window_m - (margin + 1) * cell_m:
            return None
    frontier = {start_bin: reach[start_bin].copy()}
    while frontier:
        grown = {}
        for a, cells in frontier.items():
            rows, cols = np.nonzero(cells)
            r0, c0 = rows.min(), cols.min()
            part = cells[r0:rows.max() + 1, c0:cols.max() + 1]
            for d, table in shifts.items():
                x_lo, x_hi, y_lo, y_hi = table[a]
                shifted = _dilate(_dilate(part, x_lo, x_hi, axis=1), y_lo, y_hi, axis=0)
                # Inside the grid: every reached cell is over `margin` from the edge.
                top, left = r0 + y_lo, c0 + x_lo
                b = (a + d) % bins
                if b not in grown:
                    grown[b] = np.zeros((n, n), bool)
                grown[b][top:top + shifted.shape[0], left:left + shifted.shape[1]] |= shifted
        frontier = {}
        for b, cells in grown.items():
            cells &= ~reach[b]
            new = np.nonzero(cells & ~checked[b])
            blocked[b][new] = _blocked(omap, footprint, corner[0] + (new[1] + 0.5) * cell_m,
                                       corner[1] + (new[0] + 0.5) * cell_m, headings[b], grid)
            checked[b][new] = True
            cells &= ~blocked[b]
            if not cells.any():
                continue
            rows, cols = np.nonzero(cells)
            if min(rows.min(), cols.min()) < margin or max(rows.max(), cols.max()) >= n - margin:
                return None
            reach[b] |= cells
            frontier[b] = cells
    return reach, corner


def misses(grown, target, grid: Grid = COARSE) -> bool:
    """Whether every cell of `grown` (forward_reach's result on `grid`) is over a step from
    the point `target` [X, Y] [m]: then no path whose poses every step lie in it ends there."""
    reach, corner = grown
    cell_m, step_m = grid.cell_m, grid.step_m
    rows, cols = np.nonzero(reach.any(axis=0))
    # The nearest point of each reached cell to the target.
    x = np.clip(target[0], corner[0] + cols * cell_m, corner[0] + (cols + 1) * cell_m)
    y = np.clip(target[1], corner[1] + rows * cell_m, corner[1] + (rows + 1) * cell_m)
    return bool(np.hypot(x - target[0], y - target[1]).min() > step_m)


def unreachable(omap: OccupancyMap, footprint: Footprint, pose, radius, target,
                grid: Grid = COARSE) -> bool:
    """Whether no collision-free forward path of curvature <= 1/radius goes from `pose` to
    the point `target` [X, Y] [m] (proved by `forward_reach` on `grid`; False: nothing
    proved)."""
    grown = forward_reach(omap, footprint, pose, radius, grid)
    return grown is not None and misses(grown, target, grid)
