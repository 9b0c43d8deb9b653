"""PathFinder (paper Algorithm 1): best-first growth of a tree of shootings ordered by
f = g + H, duplicates pruned by (x, y, heading) cells as in Hybrid A*, under budgets of
expansions and seconds; the connection (Section 2.4) from the nodes nearest the goal; then,
anytime, shorter connections until no node can shorten the path or the budget ends."""
from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from time import perf_counter

import numpy as np
from scipy.ndimage import label, minimum_filter
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from stepzoo import dynamics
from stepzoo.search.car_bounds import dubins_length, reeds_shepp_length
from stepzoo.search.connect import (Connection, connect, dubins_paths, guess_paths,
                                    path_poses)
from stepzoo.search.departure import boxed_in, turned
from stepzoo.search.footprint import Footprint, first_collision, poses_collide
from stepzoo.search.maps import SUBDIV, OccupancyMap
from stepzoo.search.planner_config import PlannerConfig
from stepzoo.search.point_selector import point_selector, random_points
from stepzoo.search.reach import CELL_M, HEADING_BINS, STEP_M, WINDOW_M, unreachable
from stepzoo.search.shooting import Shooter, Shots

EXACT, APPROXIMATE, NO_PATH = "exact", "approximate", "no_path"
REFINE = 2              # times the pruning cells are halved when the heap empties unsolved
PREFIX_FRACTION = 4     # a colliding shooting's free first part is kept from 1/4 of its rows
IMPROVE_TOL = 1e-3      # a path counts as shorter when it is shorter by this fraction
DUBINS_SPACING = 0.5    # [m] between the poses of a Dubins path checked before an OCP
OCTILE_EXCESS = 1.0824  # the 8-connected lattice metric's largest ratio to Euclidean length
# Why a plan ended. Bad endpoints are the caller's input: no search was run.
BAD_ENDPOINT = ("start_off_map", "start_in_collision", "goal_off_map", "goal_in_collision")
# A boxed-in end is a true result for this car, not a bad input: no_path, no search run.
BOXED_IN = ("start_boxed_in", "goal_boxed_in")
CAUSES = (*BAD_ENDPOINT, "walled_off", *BOXED_IN, "exhausted", "budget", "connections_failed",
          "connected")


@dataclass
class PlanResult:
    """What a plan found. `path_edges` are the tree shootings from the start to the node the
    path ends at (each (n_steps+1, 5) [X, Y, psi, vy, r] at steps of h), `path_steers` their
    constant steers [rad], `path_tight` whether each is a tight move (kinematic bicycle),
    `path_directions` the way each was driven (+1 forwards, -1 backwards: reverse gear, on the
    kinematic bicycle), `connection` the OCP segment to the goal (exact plans only); with
    `vx` they are the controls that produce the path (search/replay.py)."""
    status: str                   # exact | approximate | no_path
    reason: str
    start: np.ndarray             # [X, Y, psi]
    goal: np.ndarray              # [X, Y, psi]
    h: float                      # [s] step of the tree shootings
    vx: float = 0.0               # [m/s] the tree's constant speed
    path_edges: list = field(default_factory=list)
    path_steers: list = field(default_factory=list)
    connection: Connection | None = None
    tree: list = field(default_factory=list)   # every edge's (n_steps+1, 5) trajectory
    expansions: int = 0
    nodes: int = 0
    search_s: float = 0.0         # [s] wall time of the search, connections excluded
    connect_s: float = 0.0        # [s] wall time of all connection attempts
    connect_attempts: int = 0
    cause: str = ""               # the reason as a word for programs, one of CAUSES
    first_solution_s: float | None = None  # [s] from the search's start to the first exact path
    solution_s: float | None = None        # [s] ... to the path returned (the shortest found)
    progress: list = field(default_factory=list)  # (time [s], length [m]) of each better path
    # The budget that cut the search short: "max_seconds" (then the result depends on the
    # machine's speed and load), "max_expansions", or None (it ended by itself: the same
    # inputs and seed give the same plan anywhere).
    budget_bound: str | None = None
    # [m] no path from start to goal is shorter (geodesic and the car's turning bound):
    # path_length / lower_bound_m bounds how far from the shortest a plan can be.
    lower_bound_m: float = 0.0
    # Whether the tree, exhausted with its own moves, was widened by tight moves (the
    # kinematic bicycle at parking speed, full lock included), and which path edges are.
    widened: bool = False
    path_tight: list = field(default_factory=list)
    path_directions: list = field(default_factory=list)

    def path_length(self) -> float:
        """[m] along the tree edges and the connection."""
        pieces = [e[:, :2] for e in self.path_edges]
        if self.connection is not None:
            pieces.append(self.connection.states[:, :2])
        return float(sum(np.hypot(*np.diff(p, axis=0).T).sum() for p in pieces))


class PathFinder:
    """The planner on one map for one vehicle at constant speed `vx` [m/s]."""

    def __init__(self, omap: OccupancyMap, config: PlannerConfig, vehicle: str | None = None,
                 vx: float = 5.0):
        if not (math.isfinite(vx) and vx > 0):
            raise ValueError(f"speed must be a finite number > 0 [m/s], got {vx!r}")
        self.omap, self.config, self.vx = omap, config, float(vx)
        prm = config.params
        self.vehicle = dynamics.vehicle(vehicle)
        grow = 2 * prm["margin"]
        length, width = self.vehicle["length"] + grow, self.vehicle["width"] + grow
        # Slices half as long as the car is wide: the discs stick out 12% past the sides
        # instead of 32%, which is what lets a car through a door 0.6 m wider than itself.
        self.footprint = Footprint.from_vehicle(length, width, 2 * math.ceil(length / width))
        self.vehicle_footprint = Footprint.from_vehicle(  # the car itself, for measures
            self.vehicle["length"], self.vehicle["width"], len(self.footprint.offsets))
        self.wheelbase = self.vehicle["Lf"] + self.vehicle["Lr"]
        batch = prm["batch_nodes"] * (prm["n_arc"] + prm["n_random"])
        self.shooter = Shooter(omap, self.footprint, self.vehicle["name"], self.vx, config.method,
                               config.h, config.n_steps, batch, prm["delta_max"])
        self._components = None
        # Reverse gear: a second shooter drives backwards from every node, towards an arc
        # behind it and the random points.
        self.back_shooter = Shooter(
            omap, self.footprint, self.vehicle["name"], self.vx, config.method, config.h,
            config.n_steps, batch, prm["delta_max"], reverse=True) if prm["reverse"] else None
        # Tight moves, for when the tree exhausts unsolved: forwards on the kinematic bicycle
        # at a fan of steers out to full lock (compiled only if a search needs them).
        self.tight_shooter = Shooter(omap, self.footprint, self.vehicle["name"], self.vx,
                                     config.method, config.h, config.n_steps, batch,
                                     prm["delta_max"], tight=True)

    def warm_up(self, goal_speed_fixed=False) -> float:
        """Compile the driver and build the OCP once, so timed plans measure planning [s]."""
        t0 = perf_counter()
        batch = self.shooter.batch
        self.shooter.integrate(np.zeros((batch, 5)), np.zeros(batch))
        if self.back_shooter is not None:
            self.back_shooter.integrate(np.zeros((batch, 5)), np.zeros(batch))
        self._connect(np.array([0.0, 0.0, 0.0, 0.0, 0.0]), np.array([8.0, 2.0, 0.0]),
                      1.0 if goal_speed_fixed else None, bounds=(-50.0, 50.0, -50.0, 50.0))
        return perf_counter() - t0

    def plan(self, start, goal, goal_speed=None, seed=0) -> PlanResult:
        """Plan from `start` [X, Y, psi] to `goal` [X, Y, psi] ([m, m, rad]); goal_speed [m/s]
        or None (free) is the speed the connection must end at. Deterministic for a seed."""
        start, goal = np.asarray(start, float)[:3], np.asarray(goal, float)[:3]
        result = PlanResult(NO_PATH, "", start, goal, self.config.h, self.vx)
        result.cause, result.reason = self._check_endpoints(start, goal)
        if result.cause:
            return result
        return _Search(self, start, goal, goal_speed, np.random.default_rng(seed), result).run()

    def _check_endpoints(self, start, goal) -> tuple[str, str]:
        """(cause, reason) why no search can start, ('', '') if it can."""
        cause, reason = self.bad_endpoint(start, goal)
        if cause:
            return cause, reason
        labels = self._corridors()
        a, b = (labels[self._lattice(p)] for p in (start, goal))
        if a == 0 or a != b:
            return "walled_off", ("goal walled off from the start: no corridor as wide as the "
                                  "vehicle joins them")
        return self._check_boxed_in(start, goal)

    def bad_endpoint(self, start, goal) -> tuple[str, str]:
        """(cause, reason) if `start` or `goal` is off the map or its footprint (+ margin)
        collides: one of BAD_ENDPOINT, the caller's input; ('', '') if both are free."""
        xmin, xmax, ymin, ymax = self.omap.bounds()
        for name, pose in (("start", start), ("goal", goal)):
            if not (np.all(np.isfinite(pose)) and xmin <= pose[0] <= xmax
                    and ymin <= pose[1] <= ymax):
                return f"{name}_off_map", (
                    f"{name} ({pose[0]:g}, {pose[1]:g}) is off the map "
                    f"(x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g} m)")
            if poses_collide(self.omap, self.footprint, pose):
                return f"{name}_in_collision", (
                    f"{name} pose ({pose[0]:g}, {pose[1]:g}, {pose[2]:g}) is in collision: the "
                    f"{self.vehicle['length']:g} x {self.vehicle['width']:g} m footprint "
                    f"(+{self.config.params['margin']:g} m margin) overlaps an obstacle")
        return "", ""

    def turn_radius(self) -> float:
        """[m] the kinematic bicycle's tightest turn, wheelbase / tan(delta_max): the radius of
        the connection's car, the car bounds and the boxed-in proofs."""
        return self.wheelbase / math.tan(self.config.params["delta_max"])

    def _check_boxed_in(self, start, goal) -> tuple[str, str]:
        """(cause, reason) if, forward only, every way out of the start (or into the goal, the
        way out of the goal turned round) collides at once; ('', '') otherwise. With reverse
        gear nothing is claimed: short moves to and fro can turn a car round where neither
        way is free for long."""
        if self.config.params["reverse"]:
            return "", ""
        radius = self.turn_radius()
        gap = float(np.hypot(*(goal[:2] - start[:2])))
        for name, pose, leave in (("start", start, "departure"),
                                  ("goal", turned(goal), "arrival")):
            boxed, longest = boxed_in(self.omap, self.footprint, pose, radius)
            # A path shorter than the proof's length could end before it collides.
            if boxed and gap > longest:
                return f"{name}_boxed_in", (
                    f"{name} boxed in: no collision-free forward {leave} (every path of "
                    f"curvature <= 1/{radius:.2f} m collides within {longest:.2f} m); "
                    "try --reverse")
        return "", ""

    def _check_enclosed(self, start, goal) -> tuple[str, str]:
        """(cause, reason) if, forward only, no forward path gets from the start near the goal
        (or from the goal turned round near the start), proved by growing every pose such a
        path can reach (`reach.unreachable`); ('', '') otherwise. Run once the search has
        exhausted: it costs seconds."""
        if self.config.params["reverse"]:
            return "", ""
        radius = self.turn_radius()
        for name, pose, other in (("start", start, goal), ("goal", turned(goal), start)):
            if unreachable(self.omap, self.footprint, pose, radius, other[:2]):
                return f"{name}_boxed_in", (
                    f"{name} boxed in: every pose a forward path of curvature <= 1/{radius:.2f} "
                    f"m can reach from it (grown on {CELL_M:g} m and "
                    f"{360 / HEADING_BINS:g} degree cells) stays within {WINDOW_M:g} m of it "
                    f"and over {STEP_M:g} m from the {'goal' if name == 'start' else 'start'}"
                    "; try --reverse")
        return "", ""

    def _corridors(self) -> np.ndarray:
        """Connected components of the lattice points where the vehicle's centre may be.

        The footprint contains the disc of radius width/2 about its centre, so a collision-free
        path keeps the centre that far from obstacles; each of its points is within step/sqrt(2)
        of a lattice point, whose exact distance is then >= width/2 - step/sqrt(2) (distance is
        1-Lipschitz), and those nearest lattice points form an 8-connected chain. Different
        components therefore prove that no path exists; the same one proves nothing."""
        if self._components is None:
            step = self.omap.resolution / SUBDIV
            room = self.omap.distance >= self.vehicle["width"] / 2 - step / math.sqrt(2)
            self._components = label(room, structure=np.ones((3, 3)))[0]
        return self._components

    def _guide_field(self, goal, geodesic) -> np.ndarray:
        """[m] the search's guide: the geodesic over lattice points where the car's centre
        has room on both sides (clearance >= half its width + margin) or near the goal (within
        connect_radius), so the search is not led into alleys narrower than the car; points
        off it rank after every point on it, by the plain geodesic."""
        room = self.vehicle["width"] / 2 + self.config.params["margin"]
        step = self.omap.resolution / SUBDIV
        rows, cols = np.indices(self.omap.distance.shape)
        near = np.hypot(cols * step + self.omap.origin[0] - goal[0],
                        rows * step + self.omap.origin[1] - goal[1])
        tight = self._geodesic(goal, (self.omap.distance >= room)
                               | (near <= self.config.params["connect_radius"]))
        finite = np.isfinite(tight)
        return np.where(finite, tight, geodesic + (tight[finite].max() if finite.any() else 0))

    def _geodesic(self, goal, allowed=None) -> np.ndarray:
        """[m] the shortest 8-connected path over free lattice points of the goal's corridor
        component from every lattice point to the goal's, the guide H of the search (Hybrid
        A*'s obstacle heuristic); a point just outside takes its best neighbour's value plus a
        diagonal step, and inf marks points with no way to the goal."""
        labels = self._corridors()
        step = self.omap.resolution / SUBDIV
        target = self._lattice(goal)
        mask = (labels == labels[target]) & (self.omap.distance > 0)
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

    def _lattice(self, pose) -> tuple[int, int]:
        step = self.omap.resolution / SUBDIV
        col, row = np.rint((pose[:2] - self.omap.origin) / step).astype(int)
        rows, cols = self._components.shape
        return min(max(row, 0), rows - 1), min(max(col, 0), cols - 1)

    def _connect(self, node, goal, goal_speed, bounds=None, direction=1,
                 paths=None) -> tuple[Connection, str]:
        """Connection from a node state (5,), reached driving `direction` (+1 forwards, -1
        backwards), to the goal pose, its guesses driving `paths` (connect's); (connection,
        '' or why not). With reverse gear the OCP lets the speed go down to -vx."""
        prm = self.config.params
        conn = connect([node[0], node[1], node[2], direction * self.vx], goal, L=self.wheelbase,
                       m=self.vehicle["m"], bounds=bounds or self.omap.bounds(),
                       N=prm["connect_N"], goal_speed=goal_speed, delta_max=prm["delta_max"],
                       v_min=-self.vx if prm["reverse"] else 0.0, paths=paths)
        if not conn.success:
            return conn, f"IPOPT: {conn.status}"
        if first_collision(self.omap, self.footprint, conn.states[None, :, :3])[0] >= 0:
            return conn, "connection collides"
        return conn, ""


class _Search:
    """One run of Algorithm 1, made anytime; the tree is held in flat lists indexed by node id.

    Before the first solution the search is best-first on f = g + H with H the geodesic
    lattice distance to the goal; a shooting that collides keeps its collision-free first part
    (at least a quarter of the horizon) as a node, so a car facing a wall still moves; when the
    heap empties the pruning cells are halved (REFINE times) and every node is expanded again;
    if it empties once more, every node is expanded again with tight moves too (the kinematic
    bicycle, which turns at L / tan(delta_max) where the dynamic model at vx understeers),
    which chain until the tree's own moves take over.
    After it, nodes that cannot beat the best path (g + a lower bound of the rest) are dropped
    and connections that would shorten it are tried, until no node is left, improve_expansions
    expansions pass without a shorter path, or the budget ends."""

    def __init__(self, finder: PathFinder, start, goal, goal_speed, rng, result: PlanResult):
        self.f, self.goal, self.goal_speed, self.rng, self.result = (
            finder, goal, goal_speed, rng, result)
        self.prm = finder.config.params
        self.cell_xy, self.cell_heading, self.level = (self.prm["cell_xy"],
                                                       self.prm["cell_heading"], 0)
        self.geodesic = finder._geodesic(goal)
        self.guide_field = finder._guide_field(goal, self.geodesic)
        root = np.array([*start, 0.0, 0.0])
        self.states, self.parent, self.g = [root], [-1], [0.0]
        self.H = [float(np.hypot(*(start[:2] - goal[:2])))]
        self.radius = finder.turn_radius()
        self.rest = [float(self._rest(start[None])[0])]
        self.guide = [float(self._rest(start[None], self.guide_field)[0])]
        self.car = [float(self._car_bound(start[None])[0])]
        self.edges, self.steers = [None], [0.0]
        self.direction = [0]  # +1 forwards, -1 backwards, 0 the start (either way)
        self.tight = [False]  # whether a node's edge is a tight move
        self.widened_at = 0   # nodes below this id were there when the search widened
        self.seen = {self._cell(root, 0)}
        self.tried: set[int] = set()
        self.cheap: set[int] = set()  # tried nodes whose every Dubins path collides: no OCP
        self.failures: list[str] = []
        self.connect_s = 0.0
        self.best = math.inf
        self.t0 = perf_counter()
        result.lower_bound_m = self._bound(0)

    def _cell(self, state, direction) -> tuple[int, int, int, int]:
        """Pruning cell of a state: position cells of cell_xy, heading cells of cell_heading,
        and with reverse gear the direction it was reached in (as Hybrid A*)."""
        heading = state[2] % (2 * math.pi)
        return (math.floor(state[0] / self.cell_xy), math.floor(state[1] / self.cell_xy),
                math.floor(heading / self.cell_heading),
                direction if self.prm["reverse"] else 0)

    def _rest(self, xy, field=None) -> np.ndarray:
        """(K,) [m] the lattice field (default: the geodesic distance to the goal, inf: none)
        at the lattice points nearest points (K, 2+)."""
        omap = self.f.omap
        step = omap.resolution / SUBDIV
        col, row = omap.nearest_lattice((xy[:, 0] - omap.origin[0]) / step,
                                        (xy[:, 1] - omap.origin[1]) / step)
        return (self.geodesic if field is None else field)[row, col]

    def _car_bound(self, poses) -> np.ndarray:
        """(K,) [m] the shortest path of the car from poses (K, 3+) to the goal ignoring
        obstacles, a lower bound of the rest: Dubins forwards, Reeds-Shepp with reverse gear;
        0 (a weaker bound) beyond 2 connect_radius of the goal, where the geodesic leads and
        the turning radius hardly adds to it."""
        bound = reeds_shepp_length if self.prm["reverse"] else dubins_length
        out = np.zeros(len(poses))
        near = np.hypot(*(poses[:, :2] - self.goal[:2]).T) <= 2 * self.prm["connect_radius"]
        if near.any():
            out[near] = bound(poses[near], self.goal, self.radius)
        return out

    def _f(self, node) -> float:
        """The search's order: g + w H, w = h_weight (above 1: greedier first solutions), H the
        larger of the guide geodesic (obstacles, no turning radius; _guide_field) and the car's
        bound (turning radius, no obstacles: Dubins or Reeds-Shepp), as Hybrid A*: a node
        beside the goal but facing away ranks by the loop it needs."""
        return self.g[node] + self.prm["h_weight"] * max(self.guide[node], self.car[node])

    def _bound(self, node) -> float:
        """[m] a lower bound of the length of any path through `node`: g plus the larger of the
        car's bound (Dubins or Reeds-Shepp) and the geodesic less the octile metric's excess
        (at most 8.3% over Euclidean) and two lattice steps."""
        step = self.f.omap.resolution / SUBDIV
        return self.g[node] + max(self.rest[node] / OCTILE_EXCESS - 2 * step, 0.0,
                                  self.car[node])

    def _budget_left(self, res) -> bool:
        """Whether both budgets allow more work; if not, records which one bound."""
        if res.expansions >= self.prm["max_expansions"]:
            res.budget_bound = "max_expansions"
        elif perf_counter() - self.t0 >= self.prm["max_seconds"]:
            res.budget_bound = "max_seconds"
        return res.budget_bound is None

    def run(self) -> PlanResult:
        prm, res = self.prm, self.result
        heap = [(self._f(0), 0, 0)]  # (f, order, node): ties go to the older
        self.pushed = 1
        if self.H[0] <= prm["mindist"]:
            self._try_connect()
        ended, stall = "", 0
        while True:
            if math.isfinite(self.best) and stall >= prm["improve_expansions"]:
                ended = (f"no shorter path in {stall} expansions" if stall else
                         "improvement off (improve_expansions = 0)")
                break
            if not self._budget_left(res):
                res.cause = res.cause or "budget"
                ended = (f"budget ended after {res.expansions} expansions and "
                         f"{perf_counter() - self.t0:.2f} s")
                break
            if not math.isfinite(self.best) and self._attempts() >= prm["connect_tries"]:
                res.cause = "connections_failed"
                ended = f"all {prm['connect_tries']} connection attempts failed"
                break
            if not heap:
                if not math.isfinite(self.best) and self.level < REFINE:
                    heap = self._refine()
                    continue
                if not (math.isfinite(self.best) or res.widened) and prm["tight_moves"]:
                    res.widened, self.widened_at = True, len(self.states)
                    heap = self._requeue()
                    continue
                res.cause = res.cause or "exhausted"
                ended = ("no node left that could shorten the path" if res.cause == "connected"
                         else f"search exhausted: every reachable pruning cell of "
                         f"{self.cell_xy:g} m and {self.cell_heading:.3g} rad was expanded, "
                         + ("tight moves (the kinematic bicycle out to full lock) included"
                            if res.widened else "tight moves off"))
                if res.cause == "exhausted":
                    cause, why = self.f._check_enclosed(self.states[0][:3], self.goal)
                    if cause:
                        res.cause, ended = cause, f"{ended}; {why}"
                break
            nodes = self._pop(heap, min(prm["batch_nodes"],
                                        prm["max_expansions"] - res.expansions))
            if not nodes:
                continue
            res.expansions += len(nodes)
            stall += len(nodes)
            new = self._expand(nodes)
            for i in new:
                heapq.heappush(heap, (self._f(i), self.pushed, i))
                self.pushed += 1
            if any(self.H[i] <= prm["mindist"] for i in new) and self._try_connect():
                stall = 0
        res.nodes = len(self.states)
        res.tree = self.edges[1:]
        res.connect_s = self.connect_s
        res.search_s = perf_counter() - self.t0 - self.connect_s
        res.connect_attempts = self._attempts()
        if math.isfinite(self.best):
            res.status, res.cause = EXACT, "connected"
            res.reason = (f"{res.reason}; {len(res.progress) - 1} shorter paths after the first, "
                          f"then {ended}")
            return res
        failed = (f"; connections failed ({', '.join(sorted(set(self.failures)))})"
                  if self.failures else "")
        if res.cause in ("exhausted", *BOXED_IN):
            res.status, res.reason = NO_PATH, ended + failed
            return res
        closest = int(np.argmin(self.H))
        self._set_path(closest)
        res.status = APPROXIMATE
        res.reason = f"{ended}; closest node {self.H[closest]:.2f} m from the goal{failed}"
        return res

    def _refine(self) -> list:
        """Halve the pruning cells and the least kept prefix and queue every node again;
        returns the new heap."""
        self.level += 1
        self.cell_xy /= 2
        self.cell_heading /= 2
        self.seen = {self._cell(s, d) for s, d in zip(self.states, self.direction)}
        return self._requeue()

    def _requeue(self) -> list:
        """Every node queued again; returns the new heap."""
        heap = []
        for i in range(len(self.states)):
            heap.append((self._f(i), self.pushed, i))
            self.pushed += 1
        heapq.heapify(heap)
        return heap

    def _pop(self, heap, most) -> list[int]:
        """Up to `most` nodes off the heap, best f first, skipping those that cannot beat the
        best path."""
        nodes = []
        while heap and len(nodes) < most:
            _, _, node = heapq.heappop(heap)
            if self._bound(node) < self.best * (1 - IMPROVE_TOL):
                nodes.append(node)
        return nodes

    def _expand(self, nodes) -> list[int]:
        """Shoot from each of `nodes` towards the arc and the random points (and, with reverse
        gear, backwards towards an arc behind it and the same points), all in one integration
        call; add every valid, new-cell end (or the collision-free first part of a shooting,
        if long enough) as a child, node by node; return the new node ids."""
        prm = self.prm
        per = prm["n_arc"] + prm["n_random"]
        randoms = []
        for node in nodes:
            points = random_points(self.rng, self.goal, prm["n_random"], prm["random_spread"])
            if len(points):
                # One point leads along the geodesic instead: through the doors and round the
                # corners the lattice path takes, where the arc and the goal's disc rarely aim.
                points[0] = self._guide(self.states[node])
            randoms.append(points)
        rows = self._filled(nodes)
        states = np.repeat(np.array([self.states[i] for i in rows]), per, axis=0)
        new = []
        gears = [(1, self.f.shooter)]
        if self.f.back_shooter is not None:
            gears.append((-1, self.f.back_shooter))
        for direction, shooter in gears:
            points = []
            for node, random in zip(rows, self._filled(randoms)):
                state = self.states[node]
                ahead = np.r_[state[:2], state[2] + (0.0 if direction > 0 else math.pi)]
                points += [point_selector(ahead, prm["arc_radius"], prm["n_arc"],
                                          prm["delta_max"]), random]
            new += self._add_all(nodes, direction, shooter.shoot(states, np.vstack(points),
                                                                 self.goal))
        # Tight moves leave the region the tree exhausted: from its nodes and along chains of
        # tight moves; once a node is reached by the tree's own move, the tree goes on alone.
        tight = [i for i in nodes if i < self.widened_at or self.tight[i]]
        if tight:
            rows = self._filled(tight)
            fan = np.linspace(-prm["delta_max"], prm["delta_max"], per)
            shots = self.f.tight_shooter.shoot_steers(
                np.repeat(np.array([self.states[i] for i in rows]), per, axis=0),
                np.tile(fan, len(rows)), self.goal)
            new += self._add_all(tight, 1, shots, tight=True)
        return new

    def _filled(self, items: list) -> list:
        """`items` (at most batch_nodes) filled up to batch_nodes with copies of its last: a
        short batch's extra shootings are dropped by _add_all."""
        return items + items[-1:] * (self.prm["batch_nodes"] - len(items))

    def _add_all(self, nodes, direction, shots, tight=False) -> list[int]:
        """Add the kept shootings of a batch, n_arc + n_random per node of `nodes`."""
        per = self.prm["n_arc"] + self.prm["n_random"]
        new = []
        for k, node in enumerate(nodes):
            part = slice(k * per, (k + 1) * per)
            new += self._add(node, direction, Shots(*(a[part] for a in shots)), tight)
        return new

    def _guide(self, state) -> np.ndarray:
        """[m] the lattice point arc_radius down the geodesic from the state's (steepest
        descent), or where the descent stops."""
        omap = self.f.omap
        step = omap.resolution / SUBDIV
        col, row = omap.nearest_lattice((state[0] - omap.origin[0]) / step,
                                        (state[1] - omap.origin[1]) / step)
        row, col = int(row), int(col)
        field = self.guide_field
        for _ in range(max(1, round(self.prm["arc_radius"] / step))):
            r0, c0 = max(row - 1, 0), max(col - 1, 0)
            window = field[r0:row + 2, c0:col + 2]
            k = int(np.argmin(window))
            if not window.flat[k] < field[row, col]:
                break
            row, col = r0 + k // window.shape[1], c0 + k % window.shape[1]
        return np.array([col, row]) * step + omap.origin

    def _add(self, node, direction, shots, tight=False) -> list[int]:
        """Add the kept shootings of `shots`, driven in `direction` (tight moves or not), as
        children of `node`."""
        last = shots.free - 1  # the last row kept of each shooting
        # Each refinement halves the least prefix too: shorter moves in tight spots.
        least = shots.states.shape[1] // (PREFIX_FRACTION * 2 ** self.level)
        keep = np.flatnonzero(last >= max(1, least))
        ends = shots.states[keep, last[keep]]
        rest, car = self._rest(ends), self._car_bound(ends)
        guide = self._rest(ends, self.guide_field)
        H = np.hypot(*(ends[:, :2] - self.goal[:2]).T)
        # A change of direction costs cusp_cost [m] on top of the distance driven.
        cusp = self.prm["cusp_cost"] if self.direction[node] == -direction else 0.0
        new = []
        for j, k in enumerate(keep.tolist()):
            end = ends[j]
            cell = self._cell(end.tolist(), direction)
            if cell in self.seen:
                continue
            self.seen.add(cell)
            new.append(len(self.states))
            self.states.append(end)
            self.parent.append(node)
            self.g.append(self.g[node] + float(shots.travelled[k, last[k]]) + cusp)
            self.H.append(float(H[j]))
            self.rest.append(float(rest[j]))
            self.car.append(float(car[j]))
            self.guide.append(float(guide[j]))
            self.edges.append(shots.states[k, :last[k] + 1])
            self.steers.append(float(shots.steer[k]))
            self.direction.append(direction)
            self.tight.append(tight)
        return new

    def _attempts(self) -> int:
        """Connection attempts that called the OCP."""
        return len(self.tried) - len(self.cheap)

    def _car_path_free(self, node, guesses) -> bool:
        """Whether any Dubins path (with reverse gear, also any Reeds-Shepp path) from the node
        to the goal is collision-free: `guesses`, the paths the connection's guesses drive
        (connect.guess_paths), and with reverse gear the Dubins paths driven backwards."""
        radius, start = self.radius, self.states[node][:3]
        paths = [path_poses(start, segs, radius, DUBINS_SPACING) for segs in guesses]
        if self.prm["reverse"]:
            # Backwards, the footprint (symmetric about its centre) sweeps what it sweeps
            # driving forwards between the poses turned round.
            back = start + (0.0, 0.0, math.pi)
            paths += [path_poses(back, segs, radius, DUBINS_SPACING) for segs in
                      dubins_paths(back, self.goal[:3] + (0.0, 0.0, math.pi), radius)]
        if not paths:
            return False
        # One check of all words: each padded with its last pose to the longest.
        rows = max(len(p) for p in paths)
        padded = np.stack([np.vstack([p, np.repeat(p[-1:], rows - len(p), axis=0)])
                           for p in paths])
        return bool((first_collision(self.f.omap, self.f.footprint, padded) < 0).any())

    def _try_connect(self) -> bool:
        """Connect from the untried nodes within connect_radius of the goal that could shorten
        the best path, shortest g + car bound first, within the attempts left; True if the best
        path became shorter."""
        limit = self.best * (1 - IMPROVE_TOL)
        near = [i for i, d in enumerate(self.H) if d <= self.prm["connect_radius"]
                and i not in self.tried and self.g[i] + d < limit]
        improved = False
        # "Nearest" for a car: a node beside the goal but facing away needs a loop (or, with
        # reverse gear, a turn in three), which the map may not allow; the car's bound says so.
        for i in sorted(near, key=lambda j: (self.g[j] + max(self.H[j], self.car[j]), j)):
            if self._attempts() >= self.prm["connect_tries"] or \
                    not self._budget_left(self.result):
                break
            if self.g[i] + max(self.H[i], self.car[i]) >= self.best * (1 - IMPROVE_TOL):
                continue
            self.tried.add(i)
            guesses = guess_paths(self.states[i][:3], self.goal[:3], self.radius,
                                  self.prm["reverse"])
            if not self._car_path_free(i, guesses):
                # The OCP starts from these paths and ignores obstacles: it would collide too.
                self.cheap.add(i)
                self.failures.append("every Dubins path collides" if not self.prm["reverse"]
                                     else "every Dubins and Reeds-Shepp path collides")
                continue
            t0 = perf_counter()
            conn, why = self.f._connect(self.states[i], self.goal, self.goal_speed,
                                        direction=self.direction[i] or 1, paths=guesses)
            self.connect_s += perf_counter() - t0
            if why:
                self.failures.append(why)
                continue
            length = self.g[i] + float(np.hypot(*np.diff(conn.states[:, :2], axis=0).T).sum())
            if length >= self.best * (1 - IMPROVE_TOL):
                continue
            res = self.result
            if not math.isfinite(self.best):
                res.first_solution_s = perf_counter() - self.t0
                res.reason = (f"connected to the goal from a node {self.H[i]:.2f} m away "
                              f"(attempt {self._attempts()})")
            self.best, improved = length, True
            self._set_path(i)
            res.connection, res.cause = conn, "connected"
            res.solution_s = perf_counter() - self.t0
            res.progress.append((res.solution_s, length))
        return improved

    def _set_path(self, node):
        edges, steers, tight, directions = [], [], [], []
        while self.parent[node] >= 0:
            edges.append(self.edges[node])
            steers.append(self.steers[node])
            tight.append(self.tight[node])
            directions.append(self.direction[node])
            node = self.parent[node]
        res = self.result
        res.path_edges, res.path_steers, res.path_tight = edges[::-1], steers[::-1], tight[::-1]
        res.path_directions = directions[::-1]
