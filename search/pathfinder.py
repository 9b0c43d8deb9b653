"""PathFinder (paper Algorithm 1): best-first growth of a tree of shootings ordered by
f = g + H, duplicates pruned by (x, y, heading) cells as in Hybrid A*, under budgets of
expansions and seconds; then the connection (Section 2.4) from the nodes nearest the goal."""
from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from time import perf_counter

import numpy as np
from scipy.ndimage import label

from stepzoo import dynamics
from stepzoo.search.connect import Connection, connect, dubins_paths
from stepzoo.search.footprint import Footprint, first_collision, poses_collide
from stepzoo.search.maps import SUBDIV, OccupancyMap
from stepzoo.search.planner_config import PlannerConfig
from stepzoo.search.point_selector import point_selector, random_points
from stepzoo.search.shooting import Shooter

EXACT, APPROXIMATE, NO_PATH = "exact", "approximate", "no_path"
# Why a plan ended. Bad endpoints are the caller's input: no search was run.
BAD_ENDPOINT = ("start_off_map", "start_in_collision", "goal_off_map", "goal_in_collision")
CAUSES = (*BAD_ENDPOINT, "walled_off", "exhausted", "budget", "connections_failed", "connected")


@dataclass
class PlanResult:
    """What a plan found. `path_edges` are the tree shootings from the start to the node the
    path ends at (each (n_steps+1, 5) [X, Y, psi, vy, r] at steps of h), `path_steers` their
    constant steers [rad], `connection` the OCP segment to the goal (exact plans only)."""
    status: str                   # exact | approximate | no_path
    reason: str
    start: np.ndarray             # [X, Y, psi]
    goal: np.ndarray              # [X, Y, psi]
    h: float                      # [s] step of the tree shootings
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
        self.footprint = Footprint.from_vehicle(self.vehicle["length"] + grow,
                                                self.vehicle["width"] + grow)
        self.wheelbase = self.vehicle["Lf"] + self.vehicle["Lr"]
        self.shooter = Shooter(omap, self.footprint, self.vehicle["name"], self.vx, config.method,
                               config.h, config.n_steps, prm["n_arc"] + prm["n_random"],
                               prm["delta_max"])
        self._components = None

    def warm_up(self, goal_speed_fixed=False) -> float:
        """Compile the driver and build the OCP once, so timed plans measure planning [s]."""
        t0 = perf_counter()
        batch = self.shooter.batch
        self.shooter.integrate(np.zeros((batch, 5)), np.zeros(batch))
        self._connect(np.array([0.0, 0.0, 0.0, 0.0, 0.0]), np.array([8.0, 2.0, 0.0]),
                      1.0 if goal_speed_fixed else None, bounds=(-50.0, 50.0, -50.0, 50.0))
        return perf_counter() - t0

    def plan(self, start, goal, goal_speed=None, seed=0) -> PlanResult:
        """Plan from `start` [X, Y, psi] to `goal` [X, Y, psi] ([m, m, rad]); goal_speed [m/s]
        or None (free) is the speed the connection must end at. Deterministic for a seed."""
        start, goal = np.asarray(start, float)[:3], np.asarray(goal, float)[:3]
        result = PlanResult(NO_PATH, "", start, goal, self.config.h)
        result.cause, result.reason = self._check_endpoints(start, goal)
        if result.cause:
            return result
        return _Search(self, start, goal, goal_speed, np.random.default_rng(seed), result).run()

    def _check_endpoints(self, start, goal) -> tuple[str, str]:
        """(cause, reason) why no search can start, ('', '') if it can."""
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
        labels = self._corridors()
        a, b = (labels[self._lattice(p)] for p in (start, goal))
        if a == 0 or a != b:
            return "walled_off", ("goal walled off from the start: no corridor as wide as the "
                                  "vehicle joins them")
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

    def _lattice(self, pose) -> tuple[int, int]:
        step = self.omap.resolution / SUBDIV
        col, row = np.rint((pose[:2] - self.omap.origin) / step).astype(int)
        rows, cols = self._components.shape
        return min(max(row, 0), rows - 1), min(max(col, 0), cols - 1)

    def _connect(self, node, goal, goal_speed, bounds=None) -> tuple[Connection, str]:
        """Connection from a node state (5,) to the goal pose; (connection, '' or why not)."""
        prm = self.config.params
        conn = connect([node[0], node[1], node[2], self.vx], goal, L=self.wheelbase,
                       m=self.vehicle["m"], bounds=bounds or self.omap.bounds(),
                       N=prm["connect_N"], goal_speed=goal_speed, delta_max=prm["delta_max"])
        if not conn.success:
            return conn, f"IPOPT: {conn.status}"
        if first_collision(self.omap, self.footprint, conn.states[None, :, :3])[0] >= 0:
            return conn, "connection collides"
        return conn, ""


class _Search:
    """One run of Algorithm 1; the tree is held in flat lists indexed by node id."""

    def __init__(self, finder: PathFinder, start, goal, goal_speed, rng, result: PlanResult):
        self.f, self.goal, self.goal_speed, self.rng, self.result = (
            finder, goal, goal_speed, rng, result)
        self.prm = finder.config.params
        root = np.array([*start, 0.0, 0.0])
        self.states, self.parent, self.g = [root], [-1], [0.0]
        self.H = [float(np.hypot(*(start[:2] - goal[:2])))]
        self.edges, self.steers = [None], [0.0]
        self.seen = {self._cell(root)}
        self.tried: set[int] = set()
        self.dubins: dict[int, float] = {}
        self.failures: list[str] = []
        self.connect_s = 0.0

    def _cell(self, state) -> tuple[int, int, int]:
        """Pruning cell of a state: position cells of cell_xy, heading cells of cell_heading."""
        heading = state[2] % (2 * math.pi)
        return (math.floor(state[0] / self.prm["cell_xy"]),
                math.floor(state[1] / self.prm["cell_xy"]),
                math.floor(heading / self.prm["cell_heading"]))

    def run(self) -> PlanResult:
        prm, res = self.prm, self.result
        t0 = perf_counter()
        heap = [(self.H[0], 0, 0)]  # (f, insertion order, node): ties go to the older node
        pushed = 1
        done = self.H[0] <= prm["mindist"] and self._try_connect()
        ended = ""
        while not done:
            if not heap:
                res.cause, ended = "exhausted", ("search exhausted: every reachable pruning "
                                                 "cell was expanded")
                break
            if len(self.tried) >= prm["connect_tries"]:
                res.cause = "connections_failed"
                ended = f"all {prm['connect_tries']} connection attempts failed"
                break
            if res.expansions >= prm["max_expansions"] or \
                    perf_counter() - t0 >= prm["max_seconds"]:
                res.cause, ended = "budget", (f"budget ended after {res.expansions} expansions "
                                              f"and {perf_counter() - t0:.2f} s")
                break
            _, _, node = heapq.heappop(heap)
            res.expansions += 1
            new = self._expand(node)
            for i in new:
                heapq.heappush(heap, (self.g[i] + self.H[i], pushed, i))
                pushed += 1
            done = any(self.H[i] <= prm["mindist"] for i in new) and self._try_connect()
        res.nodes = len(self.states)
        res.tree = self.edges[1:]
        res.connect_s = self.connect_s
        res.search_s = perf_counter() - t0 - self.connect_s
        res.connect_attempts = len(self.tried)
        if done:
            return res
        failed = (f"; connections failed ({', '.join(sorted(set(self.failures)))})"
                  if self.failures else "")
        if res.cause == "exhausted":
            res.status, res.reason = NO_PATH, ended + failed
            return res
        closest = int(np.argmin(self.H))
        self._set_path(closest)
        res.status = APPROXIMATE
        res.reason = f"{ended}; closest node {self.H[closest]:.2f} m from the goal{failed}"
        return res

    def _expand(self, node) -> list[int]:
        """Shoot from `node` towards the arc and the random points; add every valid, new-cell
        end as a child; return the new node ids."""
        prm, state = self.prm, self.states[node]
        points = np.vstack([
            point_selector(state, prm["arc_radius"], prm["n_arc"], prm["delta_max"]),
            random_points(self.rng, self.goal, prm["n_random"], prm["random_spread"])])
        shots = self.f.shooter.shoot(state, points, self.goal)
        # Python floats: the same values, at a fraction of the cost of NumPy scalars.
        ends, g, H, steer = (shots.states[:, -1, :3].tolist(), shots.g.tolist(),
                             shots.H.tolist(), shots.steer.tolist())
        new = []
        for k in np.flatnonzero(shots.valid).tolist():
            cell = self._cell(ends[k])
            if cell in self.seen:
                continue
            self.seen.add(cell)
            new.append(len(self.states))
            self.states.append(shots.states[k, -1])
            self.parent.append(node)
            self.g.append(self.g[node] + g[k])
            self.H.append(H[k])
            self.edges.append(shots.states[k])
            self.steers.append(steer[k])
        return new

    def _dubins_length(self, node) -> float:
        """[m] of the shortest forward path at the minimum turning radius from the node's
        pose to the goal pose: "nearest" for a car, which the straight distance ignores (a
        node beside the goal but facing away needs a loop, which the map may not allow)."""
        if node not in self.dubins:
            radius = self.f.wheelbase / math.tan(self.prm["delta_max"])
            paths = dubins_paths(self.states[node][:3], self.goal[:3], radius)
            self.dubins[node] = sum(q for _, q in paths[0]) if paths else math.inf
        return self.dubins[node]

    def _try_connect(self) -> bool:
        """Connect from the untried nodes within connect_radius of the goal, shortest Dubins
        path first, within the attempts left."""
        near = [i for i, d in enumerate(self.H)
                if d <= self.prm["connect_radius"] and i not in self.tried]
        for i in sorted(near, key=lambda j: (self._dubins_length(j), j)):
            if len(self.tried) >= self.prm["connect_tries"]:
                return False
            self.tried.add(i)
            t0 = perf_counter()
            conn, why = self.f._connect(self.states[i], self.goal, self.goal_speed)
            self.connect_s += perf_counter() - t0
            if not why:
                self._set_path(i)
                res = self.result
                res.status, res.connection, res.cause = EXACT, conn, "connected"
                res.reason = (f"connected to the goal from a node {self.H[i]:.2f} m away "
                              f"(attempt {len(self.tried)})")
                return True
            self.failures.append(why)
        return False

    def _set_path(self, node):
        edges, steers = [], []
        while self.parent[node] >= 0:
            edges.append(self.edges[node])
            steers.append(self.steers[node])
            node = self.parent[node]
        self.result.path_edges, self.result.path_steers = edges[::-1], steers[::-1]
