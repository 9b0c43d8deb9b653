"""Whether a forward-only car can leave a pose: a proof that it cannot (every forward path
collides at once, e.g. a start facing a wall), and a witness that it can (a collision-free
arc), which the seeded query generator requires of every start (and of every goal, turned
round: arriving forwards is leaving backwards).

Both speak of paths that move along the heading and turn at most 1/radius per metre (the
kinematic bicycle of the connection, radius = L / tan(delta_max)), swept by the footprint's
discs, which collide as the planner's check says: an obstacle cell or the map's outside
within a disc's radius (where the check decides by the car's rectangle, the proof's disc is
inside it)."""
from __future__ import annotations

import math

import numpy as np

from stepzoo.search.world.footprint import Footprint, first_collision, rectangle_decides
from stepzoo.search.world.maps import OccupancyMap

DEPARTURE_M = 2.0   # [m] the witness arc's length: half a car, more than a tree node's prefix
N_ARCS = 9          # witness arcs, curvatures evenly from -1/radius to 1/radius
ARC_SPACING = 0.1   # [m] between the witness arc's checked poses
# [m] the proof's sample spacing: a quarter cell, within these bounds (a sparser sample only
# finds fewer proofs, never a false one; on a 5 cm map a quarter cell would be 60 M points).
PROOF_SPACING = (0.02, 0.1)


def unavoidable_points(footprint: Footprint, pose, radius, spacing) -> tuple[np.ndarray, float]:
    """((K, 2) [m] points that the front disc covers on every forward path from `pose`, the
    length [m] a path must have for that), points `spacing` [m] apart.

    In the pose's frame (t ahead, y left) let a be the front disc's offset and r its radius.
    A path of length s turns the heading by at most s/radius, so for s <= d <= radius pi/2 the
    front disc's centre has t >= radius sin(d/radius) + a cos(d/radius) = X at s = d and
    |y| <= radius (1 - cos(d/radius)) + a sin(d/radius) = Y throughout. It starts at t = a,
    so it passes every t in [a, X] with |y| <= Y: the disc covers every (t, y') with
    |y'| <= r - Y there, and, when it passes t = X, every (t', y') with
    (t' - X)^2 + (|y'| + Y)^2 <= r^2. The union over d is covered by every path at least as
    long as the largest d used."""
    a, r = float(footprint.offsets.max()), footprint.radius
    local, longest = [], 0.0
    for d in np.arange(spacing, radius * math.pi / 2, spacing):
        turn = d / radius
        X = radius * math.sin(turn) + a * math.cos(turn)
        Y = radius * (1 - math.cos(turn)) + a * math.sin(turn)
        if Y >= r:
            break
        longest = d
        for y in np.arange(-(r - Y), r - Y, spacing):
            far = X + math.sqrt(max(r * r - (abs(y) + Y) ** 2, 0.0))
            for t in np.r_[np.arange(a, far, spacing), far]:
                local.append((t, y))
    ahead = np.array(local).reshape(-1, 2)
    x, y, psi = (float(v) for v in pose[:3])
    c, s = math.cos(psi), math.sin(psi)
    world = np.column_stack([x + c * ahead[:, 0] - s * ahead[:, 1],
                             y + s * ahead[:, 0] + c * ahead[:, 1]])
    return world, longest


def boxed_in(omap: OccupancyMap, footprint: Footprint, pose, radius) -> tuple[bool, float]:
    """(True only if every forward path from `pose` [X, Y, psi] longer than the returned
    length [m] collides, that length). A point of unavoidable_points inside an obstacle cell
    (or off the map) is inside the front disc of every such path, hence a collision. Where the
    check decides by the rectangle (rectangle_decides), the disc cover sticks out of what
    collides: the front disc is then the inscribed one (Footprint.inscribed), inside the
    rectangle."""
    if rectangle_decides(omap, footprint):
        footprint = footprint.inscribed()
    a, r = float(footprint.offsets.max()), footprint.radius
    # Every point lies within this of the pose (t <= d + a + r with d <= radius pi/2,
    # |y| <= r): with more room than that around the pose no obstacle can be among them.
    if omap.clearance(np.asarray(pose[:2], float)) > math.hypot(radius * math.pi / 2 + a + r, r):
        return False, 0.0
    spacing = min(max(omap.resolution / 4, PROOF_SPACING[0]), PROOF_SPACING[1])
    points, longest = unavoidable_points(footprint, pose, radius, spacing)
    if not len(points):
        return False, 0.0
    return bool(omap.disc_hits(points[:, 0], points[:, 1], 0.0).any()), longest


def arc_poses(pose, curvature, length, spacing) -> np.ndarray:
    """(K, 3) [X, Y, psi] along the arc of `curvature` [1/m] from `pose`, `length` [m] long,
    at most `spacing` [m] apart, both ends included."""
    s = np.linspace(0.0, length, max(2, math.ceil(length / spacing) + 1))
    x, y, psi = (float(v) for v in pose[:3])
    heading = psi + curvature * s
    if abs(curvature) < 1e-12:
        return np.column_stack([x + s * math.cos(psi), y + s * math.sin(psi), heading])
    return np.column_stack([x + (np.sin(heading) - math.sin(psi)) / curvature,
                            y - (np.cos(heading) - math.cos(psi)) / curvature, heading])


def witness_arcs(pose, radius, length, spacing=ARC_SPACING) -> np.ndarray:
    """(N_ARCS, n, 3) poses of N_ARCS forward arcs from `pose`, curvatures evenly in
    [-1/radius, 1/radius], `length` [m] long, sampled every `spacing` [m]."""
    return np.stack([arc_poses(pose, k, length, spacing)
                     for k in np.linspace(-1 / radius, 1 / radius, N_ARCS)])


def free_departure(omap: OccupancyMap, footprint: Footprint, pose, radius,
                   length=DEPARTURE_M) -> bool:
    """Whether one of N_ARCS arcs of curvature in [-1/radius, 1/radius], `length` [m] long,
    leaves `pose` forwards without collision (first_collision, interpolation included)."""
    arcs = witness_arcs(pose, radius, length)
    return bool((first_collision(omap, footprint, arcs) < 0).any())


def turned(pose) -> np.ndarray:
    """The pose facing the other way: a forward arrival at `pose` is a forward departure from
    it (the footprint is symmetric about its centre)."""
    return np.r_[pose[0], pose[1], pose[2] + math.pi]
