"""PathFinder (paper Algorithm 1): best-first growth of a tree of shootings ordered by
f = g + H, duplicates pruned by (x, y, heading) cells as in Hybrid A*, until a termination
condition; the connection (Section 2.4) from the nodes nearest the goal; then, anytime,
shorter connections until no node can shorten the path or the condition ends the search."""
from __future__ import annotations

import heapq
import math
from time import perf_counter
from typing import NamedTuple

import numpy as np

from stepzoo import dynamics
from stepzoo.dynamics.vehicles import limits as vehicle_limits
from stepzoo.search.planner.connection_ocp import Connection, Corridor, connect
from stepzoo.search.planner.endpoints import bad_endpoint, departure_boxed_in, enclosed, walled_off
from stepzoo.search.planner.expansion import SPEED_CHANGE_STEER, STRAIGHT_STEER, Expander
from stepzoo.search.world.footprint import Footprint
from stepzoo.search.planner.guide import Guide, corridors
from stepzoo.search.planner.heading_lattice import HeadingLattice
from stepzoo.search.world.maps import SUBDIV, OccupancyMap
from stepzoo.search.planner.status import (BAD_ENDPOINT, BOXED_IN, Cause, PlannerStatus,
                                        PlanResult)
from stepzoo.search.planner.config import PlannerConfig
from stepzoo.search.planner.shooting import Shooter, integrate_together
from stepzoo.search.planner.termination import Progress, Termination, default_termination
from stepzoo.search.planner.tree import Tree
from stepzoo.search.planner.connection import IMPROVE_TOL, Connector
from stepzoo.search.world.validity import FootprintChecker, ValidityChecker

__all__ = ["BAD_ENDPOINT", "BOXED_IN", "Cause", "OCTILE_EXCESS", "PathFinder", "PlanResult",
           "PlannerStatus"]

REFINE = 2              # times the pruning cells are halved when the heap empties unsolved
# [rad] steer cell of duplicate pruning when the steer is a state (rate-limited): about what
# one 0.8 s edge can change it by, so a node whose steer can still turn is not pruned by one
# in its cell whose steer cannot.
STEER_CELL = 0.3
# [m] with tie_break = "cell", f is compared in steps of this: far below any length a plan
# tells apart, far above the rounding of a sum of edges (about 1e-13 m).
F_QUANTUM = 2.0 ** -20
OCTILE_EXCESS = 1.0824  # the 8-connected lattice metric's largest ratio to Euclidean length


class PathFinder:
    """The planner on one map for one vehicle at constant speed `vx` [m/s]; `checker` says
    which poses and motions are allowed (default: the car's footprint plus the config's
    margin on the map). The corridor and boxed-in proofs reason about that footprint: a
    checker of its own should be at least as strict."""

    def __init__(self, omap: OccupancyMap, config: PlannerConfig, vehicle: str | None = None,
                 vx: float = 5.0, checker: ValidityChecker | None = None):
        if not (math.isfinite(vx) and vx > 0):
            raise ValueError(f"speed must be a finite number > 0 [m/s], got {vx!r}")
        self.omap, self.config, self.vx = omap, config, float(vx)
        prm = config.params
        self.vehicle = dynamics.vehicle(vehicle)
        grow = 2 * prm.margin
        length, width = self.vehicle["length"] + grow, self.vehicle["width"] + grow
        # Slices half as long as the car is wide: the discs stick out 12% past the sides
        # instead of 32%, which is what lets a car through a door 0.6 m wider than itself.
        self.footprint = Footprint.from_vehicle(length, width, 2 * math.ceil(length / width))
        self.vehicle_footprint = Footprint.from_vehicle(  # the car itself, for measures
            self.vehicle["length"], self.vehicle["width"], len(self.footprint.offsets))
        self.checker = checker or FootprintChecker(omap, self.footprint)
        self.wheelbase = self.vehicle["Lf"] + self.vehicle["Lr"]
        self._components: np.ndarray | None = None
        self.limits = vehicle_limits(self.vehicle["name"])
        # Rate-limited, the car's limits bound every move: the steer rate, and the steer
        # (so the curvature tan(delta) / L) where v^2 kappa would exceed the lateral limit.
        # The planner keeps limit_fraction of each limit: the rest is the tracking
        # controller's, to correct its errors on a car whose tyres grip less than the limit.
        self.rate_limited = prm.steering != "instant"
        self.course_limited = prm.steering == "course_limited"
        # [rad] the car changes speed only with its steer within this (Expander)
        self.speed_change_steer = STRAIGHT_STEER if self.course_limited else SPEED_CHANGE_STEER
        # [rad] and sets off on the connection from the tree's own move only within this
        self.connect_steer_max = (min(prm.connect_steer_max, STRAIGHT_STEER)
                                  if self.course_limited else prm.connect_steer_max)
        self.lateral_limit = prm.limit_fraction * self.limits["max_lateral_acceleration"]
        self.steer_rate = (prm.limit_fraction * self.limits["max_steer_rate"]
                           if self.rate_limited else None)
        self.delta_max = self.steer_limit(self.vx)
        # Tight moves are driven slower: the steer turns faster per metre and the lateral
        # limit allows the full lock.
        self.tight_vx = min(prm.tight_speed, self.vx) if self.rate_limited else self.vx
        # [m] from the point of the kinematic moves that turns on circles of turn_radius to
        # their (X, Y): rate-limited, the rigid car's rear axle to its centre of gravity;
        # instant, the paper's kinematic bicycle's (X, Y) turns so itself.
        self.lever = self.vehicle["Lr"] if self.rate_limited else 0.0

        def shooter(vx=self.vx, rate=self.steer_rate, **kind):
            return Shooter(self.checker, self.vehicle["name"], vx, config.method, config.h,
                           config.n_steps, prm.batch_nodes * (prm.n_arc + prm.n_random),
                           self.steer_limit(vx), max_steer_rate=rate, **kind)
        # course_limited, the tree's own moves ramp slower: the course of the dynamic
        # bicycle's centre of gravity reads a change of the ramp's rate as a step of the steer
        # (its slip follows the steer at once), the kinematic moves' course reads their ramp
        # as it is.
        self.shooter = shooter(rate=(min(prm.dynamic_rate_fraction, prm.limit_fraction)
                                     * self.limits["max_steer_rate"]
                                     if self.course_limited else self.steer_rate))
        # Reverse gear: a second shooter drives backwards from every node, towards an arc
        # behind it and the random points, at tight_vx: drivers back up slowly, and a car
        # backing fast is hard to hold on a path (its steered axle trails).
        self.back_shooter = shooter(self.tight_vx, reverse=True) if prm.reverse else None
        # Tight moves, where the tree's moves collide or the tree exhausts unsolved: forwards
        # on the kinematic bicycle at tight_vx, a fan of steers out to full lock.
        self.tight_shooter = shooter(self.tight_vx, tight=True)

    def steer_limit(self, vx: float) -> float:
        """[rad] the steer limit at speed vx [m/s]: delta_max, and rate-limited below it
        atan(L a_lat / vx^2) where vx^2 tan(delta) / L would pass the planned lateral limit."""
        prm = self.config.params
        if not self.rate_limited:
            return prm.delta_max
        return min(prm.delta_max, math.atan(self.wheelbase * self.lateral_limit / vx ** 2))

    def warm_up(self, goal_speed_fixed=False) -> float:
        """Compile the driver and build the OCP once, so timed plans measure planning [s]."""
        t0 = perf_counter()
        batch = self.shooter.batch
        # The shooters an expansion integrates together (Expander.expand).
        shooters = [self.shooter]
        if self.back_shooter is not None:
            shooters.append(self.back_shooter)
        if self.rate_limited and self.config.params.tight_moves:
            shooters.append(self.tight_shooter)   # it shoots wherever a tree move collides
        integrate_together([(shooter, np.zeros((batch, 5)), np.zeros(batch), np.zeros(batch))
                            for shooter in shooters])
        self.connect(np.array([0.0, 0.0, 0.0, 0.0, 0.0]), np.array([8.0, 2.0, 0.0]),
                     1.0 if goal_speed_fixed else None, bounds=(-50.0, 50.0, -50.0, 50.0))
        return perf_counter() - t0

    def refuse(self, start, goal) -> PlanResult | None:
        """The no_path result for a start or goal off the map or not valid (the caller's
        input, one of BAD_ENDPOINT), None if both are fine. Compiles nothing: call it before
        warm_up, so that a bad pose is refused at once."""
        start, goal = np.asarray(start, float)[:3], np.asarray(goal, float)[:3]
        cause, reason = self.bad_endpoint(start, goal)
        if cause is None:
            return None
        return PlanResult(PlannerStatus.NO_PATH, reason, start, goal, self.config.h, self.vx,
                          cause=cause)

    def plan(self, start, goal, goal_speed=None, seed=0,
             until: Termination | None = None) -> PlanResult:
        """Plan from `start` [X, Y, psi] to `goal` [X, Y, psi] ([m, m, rad]); goal_speed [m/s]
        or None (free) is the speed the connection must end at; `until` ends the search
        (default: the config's max_expansions, then max_seconds). Deterministic for a seed
        when `until` holds no clock."""
        refused = self.refuse(start, goal)
        if refused is not None:
            return refused
        start, goal = np.asarray(start, float)[:3], np.asarray(goal, float)[:3]
        result = PlanResult(PlannerStatus.NO_PATH, "", start, goal, self.config.h, self.vx)
        result.cause, result.reason = self._search_blocked(start, goal)
        if result.cause:
            return result
        until = until if until is not None else default_termination(self.config.params)
        return Search(self, start, goal, goal_speed, np.random.default_rng(seed), result,
                      until).run()

    def bad_endpoint(self, start, goal) -> tuple[Cause | None, str]:
        """(cause, reason) if `start` or `goal` is off the map or not valid (its footprint +
        margin collides): one of BAD_ENDPOINT, the caller's input; (None, '') if both are
        fine."""
        car = (f"{self.vehicle['length']:g} x {self.vehicle['width']:g} m footprint "
               f"(+{self.config.params.margin:g} m margin)")
        return bad_endpoint(self.omap, self.checker, start, goal, car)

    def _search_blocked(self, start, goal) -> tuple[Cause | None, str]:
        """(cause, reason) why no search can reach the goal, proved before one starts."""
        cause, reason = walled_off(self.omap, self.corridors(), start, goal)
        if cause is None and not self.config.params.reverse:
            cause, reason = departure_boxed_in(self.omap, self.footprint, start, goal,
                                               self.turn_radius(), self.lever)
        return cause, reason

    def turn_radius(self) -> float:
        """[m] the kinematic bicycle's tightest turn, wheelbase / tan(delta), delta the steer
        limit at the slowest speed the tree drives (tight_vx with tight moves, else vx): the
        radius of the connection's guesses, the car bounds and the boxed-in proofs."""
        return self.wheelbase / math.tan(self.tight_shooter.delta_max
                                         if self.config.params.tight_moves else self.delta_max)

    def corridors(self) -> np.ndarray:
        """The lattice's corridor components for this car (guide.corridors), computed once."""
        if self._components is None:
            self._components = corridors(self.omap, self.vehicle["width"])
        return self._components

    def connect(self, node, goal, goal_speed, bounds=None, direction=1,
                paths=None, steer=0.0, speed=None) -> tuple[Connection, str]:
        """Connection from a node state (5,) at steer `steer` [rad] and speed `speed` [m/s]
        (default vx), reached driving `direction` (+1 forwards, -1 backwards), to the goal
        pose, its guesses driving `paths` (connect's); (connection, '' or why not). With
        reverse gear the OCP lets the speed go down to -tight_vx; rate-limited, it starts at the
        node's steer and bounds the steer rate and the lateral acceleration by the planned
        limits (the OCP may slow down to turn tighter: its steer limit is delta_max), on the
        rigid car whose states are the node's (centre of gravity and body)."""
        prm = self.config.params
        limits = ({"steer0": steer, "max_steer_rate": self.steer_rate,
                   "max_lateral_acceleration": self.lateral_limit, "Lr": self.vehicle["Lr"]}
                  if self.rate_limited else {})
        speed = self.vx if speed is None else speed
        if self.rate_limited:
            limits["corridor"] = Corridor(self.footprint.offsets, self.footprint.radius,
                                          self.omap.clearance)
        conn = connect([node[0], node[1], node[2], direction * speed], goal, L=self.wheelbase,
                       m=self.vehicle["m"], bounds=bounds or self.omap.bounds(),
                       N=prm.connect_N, goal_speed=goal_speed, delta_max=prm.delta_max,
                       v_min=-self.tight_vx if prm.reverse else 0.0, paths=paths, **limits)
        if not conn.success:
            return conn, f"IPOPT: {conn.status}"
        # Its nodes checked at their poses (rate-limited, the rigid car's: its centre of
        # gravity and body).
        if self.checker.first_invalid(conn.states[None, :, :3])[0] >= 0:
            return conn, "connection collides"
        return conn, ""


class Cell(NamedTuple):
    """A pruning cell: position and heading cell indices, the direction of travel (with
    reverse gear; else 0), the steer cell (rate-limited; else 0), and 1 for a cell of half
    the size (narrow_cell_m)."""
    x: int
    y: int
    heading: int
    direction: int
    steer: int
    fine: int = 0
    straight: int = 0


class Search:
    """One run of Algorithm 1, made anytime, on the tree's columns (search/planner/tree.py).

    Before the first solution the search is best-first on f = g + H with H the geodesic
    lattice distance to the goal; a shooting that collides keeps its collision-free first part
    as a node (search/planner/expansion.py), so a car facing a wall still moves; when the heap
    empties the pruning cells are halved (REFINE times) and every node is expanded again; if it
    empties once more, every node is expanded again with tight moves too (the kinematic
    bicycle, which turns at L / tan(delta_max) where the dynamic model at vx understeers),
    which chain until the tree's own moves take over.
    After it, nodes that cannot beat the best path (g + a lower bound of the rest) are dropped
    and connections that would shorten it are tried (search/planner/connection.py), until no node
    is left, improve_expansions expansions (or improve_attempts connection attempts, if set)
    pass without a shorter path, or `until` ends it."""

    def __init__(self, finder: PathFinder, start, goal, goal_speed, rng, result: PlanResult,
                 until: Termination):
        self.f, self.goal, self.goal_speed, self.rng, self.result = (
            finder, goal, goal_speed, rng, result)
        self.until = until
        self.stopped: Termination | None = None
        self.prm = prm = finder.config.params
        self.cell_xy, self.cell_heading, self.level = prm.cell_xy, prm.cell_heading, 0
        self.radius = finder.turn_radius()
        heading = (HeadingLattice(finder.omap, goal, finder.footprint, self.radius,
                                  prm.reverse_penalty if prm.reverse else None)
                   if prm.guide == "heading" else None)
        self.guide = Guide(finder.omap, finder.corridors(), goal,
                           finder.vehicle["width"] / 2 + prm.margin, prm.connect_radius,
                           self.radius, bool(prm.reverse), heading)
        root = np.array([*start, 0.0, 0.0])
        self.tree = Tree()
        self.tree.add([None], states=root, parent=-1, g=0.0,
                      H=float(np.hypot(*(start[:2] - goal[:2]))),
                      rest=self.guide.rest(start[None]), guide=self.guide.guide(start[None]),
                      car=self.guide.car_bound(start[None]), steer=0.0, steer0=0.0, direction=0,
                      tight=False)
        self.widened_at = 0   # nodes below this id were there when the search widened
        self.pushed = 0       # heap entries made (tie_break = "inserted")
        self.seen = {self.cell(root, 0)}
        self.best = math.inf
        self.expander, self.connector = Expander(self), Connector(self)
        self.t0 = perf_counter()
        result.lower_bound_m = self.bound(0)

    def cell(self, state, direction, steer=0.0) -> Cell:
        """Pruning cell of a state: position cells of cell_xy, heading cells of cell_heading
        (both halved, `fine`, where the state's clearance is below narrow_cell_m), with
        reverse gear the direction it was reached in (as Hybrid A*), and rate-limited the
        steer [rad] at it in cells of STEER_CELL."""
        heading = state[2] % (2 * math.pi)
        size, turn, fine = self.cell_xy, self.cell_heading, 0
        narrow = self.prm.narrow_cell_m
        if narrow and self.f.omap.clearance_at(state[0], state[1]) < narrow:
            size, turn, fine = size / 2, turn / 2, 1
        return Cell(math.floor(state[0] / size), math.floor(state[1] / size),
                    math.floor(heading / turn),
                    direction if self.prm.reverse else 0,
                    math.floor(steer / STEER_CELL + 0.5) if self.f.rate_limited else 0, fine,
                    int(self.f.course_limited and abs(steer) <= STRAIGHT_STEER))

    def order(self, nodes) -> list[float]:
        """The search's order of `nodes`: g + w H, w = h_weight (above 1: greedier first
        solutions), H the larger of the guide geodesic (obstacles, no turning radius) and the
        car's bound (turning radius, no obstacles: Dubins or Reeds-Shepp), as Hybrid A*: a
        node beside the goal but facing away ranks by the loop it needs."""
        t = self.tree
        return (t.g[nodes] + self.prm.h_weight * np.maximum(t.guide[nodes], t.car[nodes])
                ).tolist()

    def bound(self, node) -> float:
        """[m] a lower bound of the length of any path through `node`: g plus the larger of the
        car's bound (Dubins or Reeds-Shepp) and the geodesic less the octile metric's excess
        and two lattice steps."""
        step = self.f.omap.resolution / SUBDIV
        t = self.tree
        return float(t.g[node] + max(t.rest[node] / OCTILE_EXCESS - 2 * step, 0.0, t.car[node]))

    def budget_left(self) -> bool:
        """Whether the termination condition allows more work; once it says stop, it stays
        stopped, and the budget it names (if any) is recorded."""
        if self.stopped is None:
            progress = Progress(self.result.expansions, math.isfinite(self.best), self.t0)
            self.stopped = self.until.stop(progress)
            if self.stopped is not None:
                self.result.budget_bound = self.stopped.budget
        return self.stopped is None

    def run(self) -> PlanResult:
        prm, res = self.prm, self.result
        heap = self.entries([0])
        if self.tree.H[0] <= prm.mindist:
            self.connector.try_connect()
        ended, stall = "", 0
        while True:
            if math.isfinite(self.best) and stall >= prm.improve_expansions:
                ended = (f"no shorter path in {stall} expansions" if stall else
                         "improvement off (improve_expansions = 0)")
                break
            if self.connector.improvement_spent():
                ended = f"no shorter path in {prm.improve_attempts} connection attempts"
                break
            if not self.budget_left():
                assert self.stopped is not None   # budget_left: the condition that said stop
                res.cause = res.cause or Cause.BUDGET
                ended = (f"budget ended after {res.expansions} expansions and "
                         f"{perf_counter() - self.t0:.2f} s" if self.stopped.budget else
                         "the termination condition ended the search at the first exact path")
                break
            if not math.isfinite(self.best) and self.connector.attempts() >= prm.connect_tries:
                res.cause = Cause.CONNECTIONS_FAILED
                ended = f"all {prm.connect_tries} connection attempts failed"
                break
            if not heap:
                if not math.isfinite(self.best) and self.level < REFINE:
                    heap = self.refine()
                    continue
                if not (math.isfinite(self.best) or res.widened) and prm.tight_moves:
                    res.widened, self.widened_at = True, len(self.tree)
                    heap = self.requeue()
                    continue
                ended = self.exhausted()
                break
            nodes = self.pop(heap, min(prm.batch_nodes, self.until.room(res.expansions)))
            if not nodes:
                continue
            res.expansions += len(nodes)
            stall += len(nodes)
            new = self.expander.expand(nodes)
            for entry in self.entries(new):
                heapq.heappush(heap, entry)
            if (self.tree.H[new] <= prm.mindist).any() and self.connector.try_connect():
                stall = 0
        return self.finish(ended)

    def exhausted(self) -> str:
        """Why the search ended with its heap empty; the cause is exhausted, unless a path
        was found."""
        res = self.result
        res.cause = res.cause or Cause.EXHAUSTED
        return ("no node left that could shorten the path" if res.cause == Cause.CONNECTED
                else f"search exhausted: every reachable pruning cell of "
                f"{self.cell_xy:g} m and {self.cell_heading:.3g} rad was expanded, "
                + ("tight moves (the kinematic bicycle out to full lock) included"
                   if res.widened else "tight moves off"))

    def boxed_in(self, ended: str) -> str:
        """`ended`, and the cause, for a search that ended without a path (exhausted, or
        cut short by its budget): with the reason of the enclosure proof (forward only,
        endpoints.enclosed) appended and its cause set if the proof shows the start or goal
        boxed in. Cut short, the tree may hold nodes beside the goal that face elsewhere:
        an approximate path to them would hide that no forward path arrives."""
        if self.prm.reverse:
            return ended
        cause, why = enclosed(self.f.omap, self.f.footprint, self.tree.states[0][:3],
                              self.goal, self.radius, self.f.lever)
        if cause:
            self.result.cause, ended = cause, f"{ended}; {why}"
        return ended

    def finish(self, ended: str) -> PlanResult:
        """The result once the loop has ended, for the reason `ended`."""
        res, conn = self.result, self.connector
        if not math.isfinite(self.best):
            ended = self.boxed_in(ended)   # its seconds count as the search's
        res.nodes = len(self.tree)
        res.tree = self.tree.edges[1:]
        res.connect_s = conn.seconds
        res.search_s = perf_counter() - self.t0 - conn.seconds
        res.connect_attempts = conn.attempts()
        if math.isfinite(self.best):
            res.status, res.cause = PlannerStatus.EXACT, Cause.CONNECTED
            res.reason = (f"{res.reason}; {len(res.progress) - 1} shorter paths after the first, "
                          f"then {ended}")
            return res
        failed = (f"; connections failed ({', '.join(sorted(set(conn.failures)))})"
                  if conn.failures else "")
        if res.cause in (Cause.EXHAUSTED, *BOXED_IN):
            res.status, res.reason = PlannerStatus.NO_PATH, ended + failed
            return res
        closest = int(np.argmin(self.tree.H))
        self.set_path(closest)
        res.status = PlannerStatus.APPROXIMATE
        res.reason = f"{ended}; closest node {self.tree.H[closest]:.2f} m from the goal{failed}"
        return res

    def refine(self) -> list:
        """Halve the pruning cells and the least kept prefix and queue every node again;
        returns the new heap."""
        self.level += 1
        self.cell_xy /= 2
        self.cell_heading /= 2
        t = self.tree
        self.seen = {self.cell(s, d, a) for s, d, a in zip(t.states, t.direction.tolist(),
                                                           t.steer.tolist())}
        return self.requeue()

    def requeue(self) -> list:
        """Every node queued again; returns the new heap."""
        heap = self.entries(range(len(self.tree)))
        heapq.heapify(heap)
        return heap

    def entries(self, nodes) -> list[tuple]:
        """The heap entries of `nodes`: (f, tie, node), f = order's. With tie_break =
        "inserted" (the paper's planner here), f as computed and ties to the older entry; with
        "cell", f rounded down to F_QUANTUM and ties to the lesser pruning cell: siblings often
        have the same f but for the last bits of their edges' lengths (the same duration at one
        speed), so a rounding of the integration (another XLA option, another machine) would
        reorder them and grow another tree."""
        nodes = list(nodes)
        f = self.order(nodes)
        if self.prm.tie_break == "inserted":
            first = self.pushed
            self.pushed += len(nodes)
            return list(zip(f, range(first, self.pushed), nodes))
        t = self.tree
        return [(math.floor(v / F_QUANTUM) * F_QUANTUM if math.isfinite(v) else v,
                 self.cell(t.states[i], int(t.direction[i]), float(t.steer[i])), i)
                for v, i in zip(f, nodes)]

    def pop(self, heap, most) -> list[int]:
        """Up to `most` nodes off the heap, best f first, skipping those that cannot beat the
        best path."""
        nodes: list[int] = []
        while heap and len(nodes) < most:
            _, _, node = heapq.heappop(heap)
            if self.bound(node) < self.best * (1 - IMPROVE_TOL):
                nodes.append(node)
        return nodes

    def set_path(self, node):
        """The result's path: the tree edges from the start to `node`."""
        t, res = self.tree, self.result
        rows = t.path_to(node)
        res.path_edges = [t.edges[i] for i in rows]
        res.path_steers = t.steer[rows].tolist()
        res.path_tight = t.tight[rows].tolist()
        res.tight_vx = self.f.tight_vx
        res.path_directions = t.direction[rows].tolist()
        if self.f.rate_limited:
            # Each edge ramps from its start steer (its parent's, unless the car stood) to its
            # end steer at a constant rate.
            steps = np.array([len(t.edges[i]) - 1 for i in rows])
            res.path_steer_rates = ((t.steer[rows] - t.steer0[rows])
                                    / (steps * self.f.config.h)).tolist()
