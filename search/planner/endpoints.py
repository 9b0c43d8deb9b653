"""Whether a search can start: the start and goal on the map and valid (the caller's input,
checked before anything is compiled), joined by a corridor as wide as the car, and, forward
only, not boxed in. Each check gives (cause, reason), (None, '') when it passes."""
from __future__ import annotations

import numpy as np

from stepzoo.dynamics.kinematic import shifted
from stepzoo.search.proofs.departure import boxed_in, turned
from stepzoo.search.world.footprint import Footprint
from stepzoo.search.planner.guide import lattice
from stepzoo.search.world.maps import OccupancyMap
from stepzoo.search.planner.status import Cause
from stepzoo.search.proofs.reach import COARSE, FINE, unreachable
from stepzoo.search.world.validity import ValidityChecker


def bad_endpoint(omap: OccupancyMap, checker: ValidityChecker, start, goal,
                 car: str) -> tuple[Cause | None, str]:
    """Cause and reason if `start` or `goal` [X, Y, psi] is off the map or not valid: one of
    BAD_ENDPOINT, the caller's input; `car` describes the footprint in the reason."""
    xmin, xmax, ymin, ymax = omap.bounds()
    for name, pose in (("start", start), ("goal", goal)):
        if not (np.all(np.isfinite(pose)) and xmin <= pose[0] <= xmax
                and ymin <= pose[1] <= ymax):
            return Cause(f"{name}_off_map"), (
                f"{name} ({pose[0]:g}, {pose[1]:g}) is off the map "
                f"(x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g} m)")
        if not checker.is_valid(pose):
            return Cause(f"{name}_in_collision"), (
                f"{name} pose ({pose[0]:g}, {pose[1]:g}, {pose[2]:g}) is in collision: the "
                f"{car} overlaps an obstacle")
    return None, ""


def walled_off(omap: OccupancyMap, labels: np.ndarray, start, goal) -> tuple[Cause | None, str]:
    """WALLED_OFF if no corridor (`labels`, guide.corridors) joins start and goal."""
    a, b = (labels[lattice(omap, p)] for p in (start, goal))
    if a == 0 or a != b:
        return Cause.WALLED_OFF, ("goal walled off from the start: no corridor as wide as the "
                                  "vehicle joins them")
    return None, ""


def departure_boxed_in(omap: OccupancyMap, footprint: Footprint, start, goal,
                       radius: float, lever: float = 0.0) -> tuple[Cause | None, str]:
    """START_BOXED_IN (GOAL_BOXED_IN) if, forward only, every way out of the start (into the
    goal: the way out of the goal turned round) of curvature <= 1/radius [1/m] collides at
    once. Forward only: with reverse gear short moves to and fro can turn a car round where
    neither way is free for long. The paths are those of the point `lever` [m] behind the
    poses' (X, Y) (the rigid car's rear axle), which carries the footprint along (`seen`)."""
    gap = float(np.hypot(*(goal[:2] - start[:2])))
    for name, (pose, car), leave in (("start", seen(footprint, start, lever), "departure"),
                                     ("goal", seen(footprint, goal, lever, True), "arrival")):
        boxed, longest = boxed_in(omap, car, pose, radius)
        # A path shorter than the proof's length could end before it collides.
        if boxed and gap > longest:
            return Cause(f"{name}_boxed_in"), (
                f"{name} boxed in: no collision-free forward {leave} (every path of "
                f"curvature <= 1/{radius:.2f} m collides within {longest:.2f} m); "
                "try --reverse")
    return None, ""


def enclosed(omap: OccupancyMap, footprint: Footprint, start, goal,
             radius: float, lever: float = 0.0) -> tuple[Cause | None, str]:
    """START_BOXED_IN (GOAL_BOXED_IN) if, forward only, no forward path gets from the start
    near the goal (or from the goal turned round near the start), proved by growing every
    pose such a path can reach (`reach.unreachable`, on the coarse grid, then on the fine
    one for a pocket), the paths those of the point `lever` [m] behind the poses' (X, Y)
    (`seen`). It costs seconds: run once a search has ended without a path."""
    for name, (pose, car), other in (("start", seen(footprint, start, lever), goal),
                                     ("goal", seen(footprint, goal, lever, True), start)):
        for grid in (COARSE, FINE):
            if unreachable(omap, car, pose, radius, other[:2], grid):
                far = "goal" if name == "start" else "start"
                return Cause(f"{name}_boxed_in"), (
                    f"{name} boxed in: every pose a forward path of curvature <= "
                    f"1/{radius:.2f} m can reach from it (grown on {grid.cell_m:g} m and "
                    f"{360 / grid.heading_bins:g} degree cells) stays within "
                    f"{grid.window_m:g} m of it and over {grid.step_m:g} m from the {far}"
                    "; try --reverse")
    return None, ""


def seen(footprint: Footprint, pose, lever: float, back: bool = False) -> tuple:
    """(pose, footprint) of the car at `pose` [X, Y, psi] seen from the point `lever` [m]
    behind (X, Y) (the rigid car's rear axle); `back`: turned round, the way out of a goal
    that the car arrives at forwards."""
    pose = shifted(np.asarray(pose, float)[:3], -lever)
    car = footprint.seen_from(lever)
    return (turned(pose), car.turned()) if back else (pose, car)
