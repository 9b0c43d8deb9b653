"""Hybrid A* (Dolgov, Thrun, Montemerlo, Diebel 2008; IJRR 2010), the planner car-planning
users pick, as a baseline for PathFinder on the same map, car and collision check: A* over
(x, y, heading) cells whose nodes keep the continuous pose of the kinematic bicycle's rear
axle, arcs at a few steers as moves, the larger of the Dubins (Reeds-Shepp) length and the
grid's geodesic as heuristic, and a Dubins (Reeds-Shepp) shot to the goal every few
expansions. Defaults are Nav2 Smac Hybrid-A*'s (docs.nav2.org, "Smac Hybrid-A* Planner");
no smoother: the path is the search's own."""
from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from time import perf_counter
from typing import TYPE_CHECKING

import numpy as np

from stepzoo.dynamics.kinematic import shifted
from stepzoo.search.planner.connection_ocp import dubins_paths, path_poses, reeds_shepp_paths
from stepzoo.search.planner.endpoints import bad_endpoint, walled_off
from stepzoo.search.planner.guide import corridors, geodesic
from stepzoo.search.planner.status import Cause, PlannerStatus
from stepzoo.search.proofs.car_bounds import dubins_length, reeds_shepp_length
from stepzoo.search.world.maps import SUBDIV, OccupancyMap
from stepzoo.search.world.validity import ValidityChecker

if TYPE_CHECKING:
    from stepzoo.search.planner.pathfinder import PathFinder


@dataclass(frozen=True)
class HybridAStarParams:
    """The search's settings; Smac's name and default in brackets where it has one."""
    heading_bins: int = 72              # [1] heading cells: 5 deg (angle_quantization_bins 72)
    cell_m: float | None = None         # [m] x, y cells; None: the map's cell size
    steers: tuple[float, ...] = (-1.0, -0.5, 0.0, 0.5, 1.0)  # [1] each move's delta_max share
    move_cells: float = math.sqrt(2)    # [cells] every move's arc length: it leaves its cell
    non_straight_penalty: float = 1.2   # [1] cost per metre turning (non_straight_penalty 1.2)
    change_penalty: float = 0.0         # [1] added where the turn changes (change_penalty 0)
    reverse: bool = False               # backwards moves too (motion_model REEDS_SHEPP)
    reverse_penalty: float = 2.0        # [1] cost per metre backwards (reverse_penalty 2.0)
    analytic_expansion_ratio: float = 3.5   # [cells] (analytic_expansion_ratio 3.5)
    analytic_max_length_m: float | None = None  # [m] a longer shot is refused; None: any
    check_spacing_m: float = 0.05       # [m] pose spacing checked along moves and shots
    max_expansions: int = 1_000_000     # (max_iterations 1000000)
    max_seconds: float = 5.0            # [s] wall clock (max_planning_time 5.0)


def rear_radius(wheelbase: float, lr: float, delta: float) -> float:
    """[m] the radius the rear axle turns on at steer `delta` [rad] (not 0) when the centre
    of gravity, `lr` [m] ahead of it, turns on wheelbase / tan|delta| [m]."""
    return math.sqrt((wheelbase / math.tan(abs(delta))) ** 2 - lr ** 2)


@dataclass
class HybridAStarResult:
    """What a search found: `rows` (K, 4) [t s, X m, Y m, psi rad] at the centre of gravity,
    psi the body's heading, t at the plan's speed (as stepzoo's path rows; (0, 4) without a
    path); `length_m` [m] the rear axle's path length, the search's measure."""
    status: PlannerStatus
    cause: Cause
    reason: str
    rows: np.ndarray
    length_m: float | None
    expansions: int
    search_s: float     # [s] wall clock, the endpoint checks and the geodesic included


class HybridAStar:
    """Hybrid A* on `omap` for a car of `wheelbase` [m] and `width` [m] whose centre of
    gravity (the footprint's centre, the rows' (X, Y)) is `lr` [m] ahead of its rear axle,
    steering up to `delta_max` [rad]; `checker` decides which poses and motions of the centre
    of gravity are allowed (HybridAStar.like: PathFinder's footprint and margin). The car is
    stepzoo's kinematic bicycle: at steer delta its centre of gravity curves at
    tan(delta) / wheelbase [1/m] (the drivability measure's limit), so its rear axle, which
    does not slide, turns on the radius sqrt((wheelbase / tan(delta))^2 - lr^2) [m]."""

    def __init__(self, omap: OccupancyMap, checker: ValidityChecker, wheelbase: float,
                 lr: float, delta_max: float, width: float,
                 params: HybridAStarParams = HybridAStarParams()):
        self.omap, self.checker, self.lr, self.params = omap, checker, float(lr), params
        # [m] the rear axle's tightest turn: the Dubins radius of the shots and the bound
        self.radius = rear_radius(wheelbase, lr, delta_max)
        self.cell = params.cell_m or omap.resolution
        self.move_m = params.move_cells * self.cell
        self.labels = corridors(omap, width)
        n = max(1, math.ceil(self.move_m / params.check_spacing_m))
        s = self.move_m * np.arange(1, n + 1) / n
        gears, sides, local = [], [], []
        for gear in ((1, -1) if params.reverse else (1,)):
            for share in params.steers:
                kappa = math.copysign(1 / rear_radius(wheelbase, lr, share * delta_max),
                                      share) if share else 0.0   # [1/m] the rear axle's
                yaw = kappa * gear * s
                gears.append(gear)
                sides.append(int(np.sign(share)))
                local.append(np.column_stack(
                    [np.sin(yaw) / kappa, (1 - np.cos(yaw)) / kappa, yaw] if kappa
                    else [gear * s, 0 * s, 0 * s]))
        self.gears, self.sides = np.array(gears), np.array(sides)
        self.local = np.stack(local)   # (moves, n, 3) [x, y, yaw] from the move's start

    @classmethod
    def like(cls, finder: PathFinder,
             params: HybridAStarParams = HybridAStarParams()) -> HybridAStar:
        """Hybrid A* with PathFinder `finder`'s map, car, steer limit and validity checker."""
        car = finder.vehicle
        return cls(finder.omap, finder.checker, car["Lf"] + car["Lr"], car["Lr"],
                   finder.config.params.delta_max, car["width"], params)

    def centred(self, rear) -> np.ndarray:
        """Rear-axle poses (..., 3) [x, y, yaw] -> centre-of-gravity poses (..., 3)."""
        return shifted(rear, self.lr)

    def rear(self, pose) -> np.ndarray:
        """A centre-of-gravity pose [X, Y, psi] -> its rear axle's [x, y, yaw]."""
        return shifted(np.asarray(pose, float)[:3], -self.lr)

    def plan(self, start, goal, vx: float = 5.0) -> HybridAStarResult:
        """Plan from `start` to `goal`, centre-of-gravity poses [X, Y, psi] ([m, m, rad]) as
        stepzoo's queries give them; the rows timed at `vx` [m/s]. Exact (a shot reached the
        goal) or no_path: a bad endpoint, walled off, exhausted, or the budget spent."""
        t0 = perf_counter()
        prm = self.params
        start, goal = np.asarray(start, float)[:3], np.asarray(goal, float)[:3]
        cause, reason = bad_endpoint(self.omap, self.checker, start, goal,
                                     "car footprint (+ margin)")
        first, last = self.rear(start), self.rear(goal)
        if cause is None:
            cause, reason = walled_off(self.omap, self.labels, first, last)
        if cause is not None:
            return self._result(PlannerStatus.NO_PATH, cause, reason, None, 0, t0)
        field = geodesic(self.omap, self.labels, last)
        poses, g, parent, moved = [first], [0.0], [-1], [-1]
        best = {self._cell(first): 0}     # cell -> the node holding it
        closed: set = set()
        heap = [(float(self._heuristic(first[None], last, field)[0]), 0)]
        closest, countdown, expansions = math.inf, 0, 0
        while heap:
            if expansions >= prm.max_expansions or perf_counter() - t0 > prm.max_seconds:
                return self._result(PlannerStatus.NO_PATH, Cause.BUDGET,
                                    "the budget ended the search", None, expansions, t0)
            f, i = heapq.heappop(heap)
            key = self._cell(poses[i])
            if key in closed or best[key] != i:
                continue
            closed.add(key)
            expansions += 1
            # Smac's schedule: a shot every (closest heuristic [cells] / ratio) expansions,
            # at least every ceil(ratio), and at the first.
            closest = min(closest, (f - g[i]) / self.cell)
            desired = max(int(closest / prm.analytic_expansion_ratio),
                          math.ceil(prm.analytic_expansion_ratio))
            countdown = min(countdown, desired)
            if countdown <= 0:
                countdown = desired
                shot = self._shot(poses[i], last)
                if shot is not None:
                    path = self._chain(i, poses, parent, moved) + [shot[0][1:]]
                    return self._result(PlannerStatus.EXACT, Cause.CONNECTED, "",
                                        (np.vstack(path), vx), expansions, t0,
                                        (len(path) - 2) * self.move_m + shot[1])
            countdown -= 1
            ends = self._placed(poses[i], self.local)
            paths = self.centred(np.concatenate([np.broadcast_to(poses[i], (len(ends), 1, 3)),
                                                 ends], axis=1))
            free = np.flatnonzero(self.checker.first_invalid(paths) < 0)
            children = ends[free, -1]
            for p, child, h in zip(free.tolist(), children,
                                   self._heuristic(children, last, field)):
                cell = self._cell(child)
                if not math.isfinite(h) or cell in closed or cell == key:
                    continue
                cost = g[i] + self._cost(moved[i], p)
                j = best.get(cell)
                if j is not None and g[j] <= cost:
                    continue
                best[cell] = len(poses)
                heapq.heappush(heap, (cost + float(h), len(poses)))
                poses.append(child)
                g.append(cost)
                parent.append(i)
                moved.append(p)
        return self._result(PlannerStatus.NO_PATH, Cause.EXHAUSTED,
                            "every reachable cell was expanded", None, expansions, t0)

    def _cell(self, pose) -> tuple[int, int, int]:
        """The (column, row, heading bin) of a rear-axle pose [x, y, yaw]."""
        bins = self.params.heading_bins
        return (math.floor((pose[0] - self.omap.origin[0]) / self.cell),
                math.floor((pose[1] - self.omap.origin[1]) / self.cell),
                round(pose[2] * bins / (2 * math.pi)) % bins)

    def _heuristic(self, poses, goal, field) -> np.ndarray:
        """(K,) [m] the larger of the obstacle-blind car bound (Dubins; Reeds-Shepp with
        reverse) and the geodesic `field` at the lattice point nearest each rear-axle pose
        (K, 3); inf where the geodesic finds no way."""
        omap, step = self.omap, self.omap.resolution / SUBDIV
        col, row = omap.nearest_lattice((poses[:, 0] - omap.origin[0]) / step,
                                        (poses[:, 1] - omap.origin[1]) / step)
        bound = reeds_shepp_length if self.params.reverse else dubins_length
        return np.maximum(field[row, col], bound(poses, goal, self.radius))

    def _cost(self, before: int, move: int) -> float:
        """[m] the cost of `move` after move `before` (-1 at the start), as Smac prices it:
        its length, times non_straight_penalty turning (plus change_penalty where the turn
        is not the one before), times reverse_penalty backwards."""
        prm = self.params
        cost = self.move_m
        if self.sides[move]:
            same = before >= 0 and (self.sides[before], self.gears[before]) == (
                self.sides[move], self.gears[move])
            cost *= prm.non_straight_penalty + (0.0 if same else prm.change_penalty)
        return cost * (prm.reverse_penalty if self.gears[move] < 0 else 1.0)

    @staticmethod
    def _placed(pose, local) -> np.ndarray:
        """Poses (..., 3) [x, y, yaw] relative to the rear-axle pose `pose`, in the world."""
        c, s = math.cos(pose[2]), math.sin(pose[2])
        return np.stack([pose[0] + c * local[..., 0] - s * local[..., 1],
                         pose[1] + s * local[..., 0] + c * local[..., 1],
                         pose[2] + local[..., 2]], -1)

    def _shot(self, pose, goal) -> tuple[np.ndarray, float] | None:
        """(rear-axle poses (K, 3), length [m]) of the shortest Dubins (Reeds-Shepp) path
        from `pose` to `goal` if it is allowed all along, else None."""
        prm = self.params
        paths = (reeds_shepp_paths if prm.reverse else dubins_paths)(pose, goal, self.radius)
        if not paths:
            return None
        length = sum(abs(q) for _, q in paths[0])
        if prm.analytic_max_length_m is not None and length > prm.analytic_max_length_m:
            return None
        rear = path_poses(pose, paths[0], self.radius, prm.check_spacing_m)
        if self.checker.first_invalid(self.centred(rear)[None])[0] >= 0:
            return None
        return rear, length

    def _chain(self, i, poses, parent, moved) -> list:
        """Rear-axle poses from the start to node `i`: the start, then each move's."""
        chain = []
        while parent[i] >= 0:
            chain.append(self._placed(poses[parent[i]], self.local[moved[i]]))
            i = parent[i]
        return [poses[0][None]] + chain[::-1]

    def _result(self, status, cause, reason, path, expansions, t0,
                length=None) -> HybridAStarResult:
        """The result; `path` (rear-axle poses (K, 3), speed [m/s]) becomes the rows."""
        rows = np.zeros((0, 4))
        if path is not None:
            rear, vx = path
            cog = self.centred(rear)
            s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(cog[:, :2], axis=0).T))]
            rows = np.column_stack([s / vx, cog])
        return HybridAStarResult(status, cause, reason, rows, length, expansions,
                                 perf_counter() - t0)
