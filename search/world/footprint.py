"""Vehicle-footprint collision check: a rectangle covered by equal discs along the heading.

Discs are tested against the map's distance field at every pose, and paths are densified so
that no disc centre moves more than one disc radius between checked poses. Poses far from
every obstacle are cleared by one distance read at their centre before any disc is placed;
where a disc touches an obstacle, the rectangle itself decides (the discs stick out past its
corners and ends).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stepzoo.search.world.maps import EXACT_CELLS, SUBDIV, OccupancyMap


@dataclass(frozen=True, eq=False)
class Footprint:
    """A length x width rectangle, aligned with psi, covered by discs along its axis; centred
    on (X, Y) unless seen from another point (`seen_from`). With `rectangle`, the discs
    circumscribe equal slices of it (from_vehicle), and a pose some disc collides at collides
    only if the rectangle does; without, the discs are the shape."""

    length: float  # [m] along the heading
    width: float  # [m] across the heading
    offsets: np.ndarray  # (n,) [m] disc centres along the heading axis from (X, Y)
    radius: float  # [m] every disc's radius
    rectangle: bool = False  # whether the rectangle decides where the discs collide
    reach: float = field(init=False)  # [m] the largest |offset|: no disc centre is farther

    def __post_init__(self):
        offsets = np.array(self.offsets, dtype=float).reshape(-1)
        if offsets.size == 0 or not np.all(np.isfinite(offsets)):
            raise ValueError(f"footprint needs at least one finite disc offset [m], "
                             f"got {self.offsets!r}")
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"disc radius must be finite and > 0 [m], got {self.radius!r}")
        offsets.setflags(write=False)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "radius", float(self.radius))
        object.__setattr__(self, "reach", float(np.abs(offsets).max()))

    @classmethod
    def from_vehicle(cls, length, width, n_discs=None, rectangle=True) -> "Footprint":
        """Cover the rectangle with n equal discs, each circumscribing an equal slice of it.

        By default n = ceil(length / width): near-square slices keep the discs' overhang past
        the sides small without a long list of discs. `rectangle`: whether the rectangle
        decides where the discs collide (else the discs are the shape).
        """
        length, width = float(length), float(width)
        if not (math.isfinite(length) and math.isfinite(width) and length > 0 and width > 0):
            raise ValueError(f"vehicle length and width must be finite and > 0 [m], "
                             f"got {length} x {width}")
        if n_discs is None:
            n_discs = max(1, math.ceil(length / width))
        if int(n_discs) != n_discs or n_discs < 1:
            raise ValueError(f"n_discs must be a whole number >= 1, got {n_discs!r}")
        n_discs = int(n_discs)
        piece = length / n_discs
        offsets = -length / 2 + piece * (np.arange(n_discs) + 0.5)
        return cls(length, width, offsets, math.hypot(piece / 2, width / 2), rectangle)

    @property
    def centre(self) -> float:
        """[m] the rectangle's centre along the heading from (X, Y): midway between the end
        discs."""
        return float(self.offsets.min() + self.offsets.max()) / 2

    def rectangle_hits(self, omap: OccupancyMap, x, y, psi, grow: float = 0.0) -> np.ndarray:
        """Poses as arrays (...) [m, m, rad] of (X, Y) -> bool (...): the rectangle, grown by
        `grow` [m] on every side (shrunk for grow < 0), overlaps an obstacle cell or leaves
        the grid (OccupancyMap.rectangle_hits at its centre)."""
        ahead = self.centre
        return omap.rectangle_hits(x + ahead * np.cos(psi), y + ahead * np.sin(psi), psi,
                                   self.length + 2 * grow, self.width + 2 * grow)

    def inscribed(self) -> "Footprint":
        """As many discs inside the rectangle, of radius half its shorter side, end to end:
        a shape every pose of the car covers, for proofs that every path collides."""
        radius = min(self.length, self.width) / 2
        ends = self.length / 2 - radius
        return Footprint(self.length, self.width,
                         self.centre + np.linspace(-ends, ends, len(self.offsets)), radius)

    def seen_from(self, length: float) -> "Footprint":
        """The same discs with their offsets measured from the point `length` [m] behind
        (X, Y) along the heading (ahead for length < 0): the rigid car's from its rear axle,
        Lr behind its centre of gravity."""
        return Footprint(self.length, self.width, self.offsets + length, self.radius,
                         self.rectangle)

    def turned(self) -> "Footprint":
        """The same discs seen facing the other way (offsets negated)."""
        return Footprint(self.length, self.width, -self.offsets, self.radius, self.rectangle)

    def disc_centres(self, poses) -> np.ndarray:
        """(..., 3+) [X, Y, psi] (extra columns ignored) -> (..., n, 2) [m]."""
        poses = np.asarray(poses, dtype=float)
        # An infinite heading (blown-up integration) gives NaN centres, which the map treats as
        # obstacles; the warning would only be noise.
        with np.errstate(invalid="ignore"):
            heading = np.stack([np.cos(poses[..., 2]), np.sin(poses[..., 2])], axis=-1)
        return poses[..., None, :2] + self.offsets[:, None] * heading[..., None, :]


def poses_collide(omap: OccupancyMap, footprint: Footprint, poses) -> np.ndarray:
    """(..., 3+) [X, Y, psi] -> bool (...): any disc touches an obstacle or leaves the map,
    and where the rectangle decides (rectangle_decides), so does the rectangle.

    Non-finite poses (a blown-up integration) collide.
    """
    poses = np.asarray(poses, dtype=float)
    return _collide(omap, footprint, poses[..., 0], poses[..., 1], poses[..., 2])


def _collide(omap, footprint, x, y, psi) -> np.ndarray:
    """poses_collide of poses given as arrays (...) [m, m, rad]: the answer of discs_collide,
    paid for only by the poses that roomy cannot clear, and where the rectangle decides, of
    the rectangle at the poses where a disc collides (the discs cover it)."""
    hit = np.asarray(~roomy(omap, footprint, x, y, psi))  # an array even for one pose
    if hit.any():
        hit[hit] = discs_collide(omap, footprint, x[hit], y[hit], psi[hit])
    if hit.any() and rectangle_decides(omap, footprint):
        x, y, psi = x[hit], y[hit], psi[hit]
        with np.errstate(invalid="ignore"):  # an infinite heading: rectangle_hits says hit
            hit[hit] = footprint.rectangle_hits(omap, x, y, psi)
    return hit


def rectangle_decides(omap: OccupancyMap, footprint: Footprint) -> bool:
    """Whether poses_collide decides by `footprint`'s rectangle on `omap` (where a disc
    collides): a rectangle footprint on cells coarse enough that its bounding box spans at
    most EXACT_CELLS a side. Else the discs decide, and they are the car's shape."""
    return footprint.rectangle and (
        math.hypot(footprint.length, footprint.width) / omap.resolution + 1 <= EXACT_CELLS)


def rectangle_clearance(omap: OccupancyMap, footprint: Footprint, poses, discs,
                        tol: float = 1e-3) -> float:
    """[m] the least clearance of `footprint`'s rectangle at `poses` (M, 3+) [X, Y, psi] on
    `omap`, given `discs` (M,) [m], its disc cover's clearance at each pose: the largest g,
    to within `tol`, at which the rectangle grown by g on every side (shrunk for g < 0)
    clears every obstacle at every pose, or the least of `discs` if larger. Both are lower
    bounds of the rectangle's distance E: the grown rectangle holds every point within g of
    the rectangle (and none farther than g sqrt(2): at a corner, E may reach g sqrt(2)), and
    the discs hold the rectangle. The discs stick out of the rectangle by at most `over` on
    any side, so no pose clears by more than its discs plus that, nor by less than its discs
    over sqrt(2)."""
    poses, discs = np.asarray(poses, float), np.asarray(discs, float)
    over = max(footprint.reach + footprint.radius - footprint.length / 2,
               footprint.radius - footprint.width / 2)
    least = float(discs.min())
    floor = tol - min(footprint.length, footprint.width) / 2   # shrunk to nothing
    hi = least + over + tol
    x, y, psi = poses[discs < hi * math.sqrt(2), :3].T

    def clears(g):
        return not footprint.rectangle_hits(omap, x, y, psi, g).any()
    lo = max(least / math.sqrt(2) if least > 0 else least, floor)
    while not clears(lo):   # only where the discs touch: shrink until the rectangle clears
        if lo <= floor:
            return floor
        hi, lo = lo, max(lo - over - tol, floor)
    while hi - lo > tol:
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if clears(mid) else (lo, mid)
    return max(lo, least)


def discs_collide(omap: OccupancyMap, footprint: Footprint, x, y, psi) -> np.ndarray:
    """Poses as arrays (...) [m, m, rad] -> bool (...): the plain check, disc by disc: a disc
    collides if an obstacle lies within its radius (OccupancyMap.disc_hits).

    The disc centres are those of `disc_centres` (the same arithmetic), laid out disc first so
    that every array operation runs along the poses.
    """
    with np.errstate(invalid="ignore"):  # an infinite heading: see disc_centres
        cos, sin = np.cos(psi), np.sin(psi)
    offsets = footprint.offsets.reshape(-1, *(1,) * cos.ndim)
    cx, cy = x + offsets * cos, y + offsets * sin
    clearance = omap.clearance_at(cx, cy)
    hit = clearance <= footprint.radius
    # The bound is below the true distance by at most sqrt(2) lattice steps: a disc it cannot
    # clear within that is decided exactly.
    doubt = hit & (clearance > footprint.radius - math.sqrt(2) * omap.resolution / SUBDIV)
    if doubt.any():
        hit[doubt] = omap.disc_hits(cx[doubt], cy[doubt], footprint.radius)
    return hit.any(axis=0)  # type: ignore[return-value]  # numpy's stub: any(axis) of 2-D is 1-D


def roomy(omap: OccupancyMap, footprint: Footprint, x, y, psi) -> np.ndarray:
    """Poses as arrays (...) [m, m, rad] -> bool (...): True only where no disc can touch an
    obstacle, from one distance read at the pose's centre; False says nothing.

    Every disc centre d lies within reach = max |offset| of the centre c, and the lattice point
    nearest an on-map point is within s / sqrt(2) of it (s the lattice step). With dist the
    exact distance to the obstacles (1-Lipschitz) and D the field at lattice points, the
    clearance at d is >= dist(d) - sqrt(2) s >= dist(c) - reach - sqrt(2) s >= D(nearest to c)
    - reach - 1.5 sqrt(2) s; so D(nearest to c) > radius + reach + 1.5 sqrt(2) s clears every
    disc, each of whose centres is then inside the map (dist(d) > 0, and all off the map is
    obstacle). A centre off the map reads the boundary, where D = 0; a non-finite pose reads
    D = 0 or fails the heading test.
    """
    step = omap.resolution / SUBDIV
    # 1 um absorbs the rounding of the sums above (maps are far smaller than 1e6 m).
    need = footprint.radius + footprint.reach + 1.5 * math.sqrt(2) * step + 1e-6
    col, row = omap.nearest_lattice((x - omap.origin[0]) / step, (y - omap.origin[1]) / step)
    room = omap.distance.take(row * omap.distance.shape[1] + col)
    return (room > need) & np.isfinite(psi)


def first_collision(omap: OccupancyMap, footprint: Footprint, paths) -> np.ndarray:
    """paths (B, N, 3+) [X, Y, psi] -> int (B,): first colliding pose index, -1 if none.

    Pose k counts as colliding if its footprint does or if the straight interpolation from
    pose k-1 to k (X, Y linear, psi along the shorter turn) does.
    """
    paths = np.asarray(paths, dtype=float)
    if paths.ndim != 3 or paths.shape[-1] < 3:
        raise ValueError(f"paths must have shape (B, N, 3) [X, Y, psi], got {paths.shape}")
    n_paths, n_poses = paths.shape[:2]
    if n_poses == 0:
        return np.full(n_paths, -1)
    # One copy with X, Y, psi each contiguous (B, N) makes every operation below run along N.
    xyp = np.ascontiguousarray(paths[..., :3].transpose(2, 0, 1))
    hit = _collide(omap, footprint, *xyp)
    first = np.where(hit.any(axis=1), hit.argmax(axis=1), n_poses)
    # max |dX| + max |dY| + reach max |dpsi| bounds every segment's sweep (see _cut_segments:
    # hypot <= |dX| + |dY| and |turn| <= |dpsi|), so while it stays below one radius (less a
    # relative 1e-9 for rounding) no segment is cut, whatever its path's first hit.
    largest = np.abs(xyp[..., 1:] - xyp[..., :-1]).max(axis=(1, 2), initial=0.0)
    if not largest @ (1.0, 1.0, footprint.reach) < footprint.radius * (1 - 1e-9):
        _cut_segments(omap, footprint, paths, first)
    return np.where(first < n_poses, first, -1)


def _cut_segments(omap, footprint, paths, first):
    """Lower `first` (B,) to k where the interpolation from pose k-1 to k of paths (B, N, 3+)
    [X, Y, psi] collides."""
    n_poses = paths.shape[1]
    # Only segments before each path's first colliding pose can move its answer earlier. Both
    # ends of such a segment are inside the map, which bounds its subdivision count.
    step = np.diff(paths[..., :3], axis=1)
    turn = (step[..., 2] + np.pi) % (2 * np.pi) - np.pi
    # A disc centre at offset o moves at most |dXY| + |o| |dpsi| along the interpolation
    # (translation plus the arc its rotation sweeps), so cutting the segment into
    # ceil(that / radius) equal parts keeps every gap within one radius.
    sweep = np.hypot(step[..., 0], step[..., 1]) + footprint.reach * np.abs(turn)
    live = np.arange(1, n_poses)[None, :] < first[:, None]
    parts = np.ceil(np.where(live, sweep, 0.0) / footprint.radius).astype(np.intp)
    parts = np.where(parts > 1, parts, 0)

    seg = np.flatnonzero(parts)  # flat index b * (N - 1) + (k - 1) of the segment to pose k
    if seg.size:
        count = parts.ravel()[seg] - 1  # interior points only: the ends are checked above
        owner = np.repeat(seg, count)
        # j = 1 .. count within each segment, built without a Python loop.
        start = np.cumsum(count) - count
        j = np.arange(owner.size) - np.repeat(start, count) + 1
        frac = j / parts.ravel()[owner]
        b, k = np.divmod(owner, n_poses - 1)
        base = paths[b, k, :3]
        delta = np.column_stack([step[b, k, :2], turn[b, k]])
        inner = base + frac[:, None] * delta
        bad = poses_collide(omap, footprint, inner)
        np.minimum.at(first, b[bad], k[bad] + 1)
