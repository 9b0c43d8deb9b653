"""The connection step of the search (paper Section 2.4, made anytime): from the tree nodes
near the goal that could shorten the best path, cheapest bound first, screen the car's
obstacle-blind paths for a free one, then solve the OCP (search/planner/connection_ocp.py)
and keep it if it is valid and shorter."""
from __future__ import annotations

import math
from time import perf_counter
from typing import TYPE_CHECKING

import numpy as np

from stepzoo.dynamics.kinematic import shifted
from stepzoo.search.planner.connection_ocp import dubins_paths, guess_paths, path_poses
from stepzoo.search.planner.status import Cause

if TYPE_CHECKING:
    from stepzoo.search.planner.pathfinder import Search

IMPROVE_TOL = 1e-3      # a path counts as shorter when it is shorter by this fraction
DUBINS_SPACING = 0.5    # [m] between the poses of a Dubins path checked before an OCP


class Connector:
    """Connection attempts of one search (`search`: pathfinder.Search, whose tree, best path
    and result they read and improve)."""

    def __init__(self, search: Search) -> None:
        self.s = search
        self.tried: set[int] = set()
        # Tried nodes no OCP was called for: every Dubins path collides, or the steer is too
        # large to connect at the tree's speed.
        self.cheap: set[int] = set()
        self.failures: list[str] = []
        self.seconds = 0.0            # [s] wall time of the OCP solves
        self.improved_at = 0          # attempts() when the best path last became shorter

    def attempts(self) -> int:
        """Connection attempts that called the OCP."""
        return len(self.tried) - len(self.cheap)

    def improvement_spent(self) -> bool:
        """Whether a path exists and improve_attempts (if set) attempts in a row have not
        shortened it: the improvement ends."""
        n = self.s.prm.improve_attempts
        return bool(n) and math.isfinite(self.s.best) and self.attempts() - self.improved_at >= n

    def free_guesses(self, node, guesses) -> list | None:
        """The valid ones of `guesses`, the Dubins paths (with reverse gear, also Reeds-Shepp
        paths) from the node to the goal that the connection's guesses drive
        (connect.guess_paths, of the rear axle's poses: `rear`); all of them if only a Dubins
        path driven backwards is valid (reverse gear); None if none is."""
        s = self.s
        radius, start, lever = s.radius, self.rear(s.tree.states[node]), s.f.lever
        paths = [shifted(path_poses(start, segs, radius, DUBINS_SPACING), lever)
                 for segs in guesses]
        if s.prm.reverse:
            # Backwards, the footprint (symmetric about its centre) sweeps what it sweeps
            # driving forwards between the poses turned round, the centre of gravity behind
            # the turned round rear axle.
            back = start + (0.0, 0.0, math.pi)
            paths += [shifted(path_poses(back, segs, radius, DUBINS_SPACING), -lever)
                      for segs in dubins_paths(back, self.rear(s.goal) + (0.0, 0.0, math.pi),
                                               radius)]
        if not paths:
            return None
        # One check of all words: each padded with its last pose to the longest.
        rows = max(len(p) for p in paths)
        padded = np.stack([np.vstack([p, np.repeat(p[-1:], rows - len(p), axis=0)])
                           for p in paths])
        free = s.f.checker.first_invalid(padded) < 0
        if not free.any():
            return None
        return [segs for segs, ok in zip(guesses, free) if ok] or list(guesses)

    def rear(self, pose) -> np.ndarray:
        """The pose [X, Y, psi] of the point of the car at `pose` (3+,) that turns on circles
        of the turning radius: rate-limited, the rigid car's rear axle (PathFinder.lever)."""
        return shifted(np.asarray(pose, float)[:3], -self.s.f.lever)

    def cost(self, conn, direction) -> float:
        """[m] the connection's cost as the tree's g counts it: its length, a metre backwards
        reverse_penalty metres, and cusp_cost per change of direction (from `direction`, the
        way its node was reached, on)."""
        prm = self.s.prm
        step = np.hypot(*np.diff(conn.states[:, :2], axis=0).T)
        way = np.sign(conn.states[:-1, 3] + conn.states[1:, 3])
        if not prm.reverse:
            return float(step.sum())
        moving = way[way != 0]
        cusps = np.count_nonzero(np.diff(np.r_[direction, moving]) != 0)
        return float(step[way >= 0].sum() + prm.reverse_penalty * step[way < 0].sum()
                     + prm.cusp_cost * cusps)

    def try_connect(self) -> bool:
        """Connect from the untried nodes within connect_radius of the goal that could shorten
        the best path, shortest g + car bound first, within the attempts left; True if the best
        path became shorter."""
        s, prm, tree, res = self.s, self.s.prm, self.s.tree, self.s.result
        H, g = tree.H, tree.g
        limit = s.best * (1 - IMPROVE_TOL)
        near = [i for i in np.flatnonzero((H <= prm.connect_radius) & (g + H < limit)).tolist()
                if i not in self.tried]
        # "Nearest" for a car: a node beside the goal but facing away needs a loop (or, with
        # reverse gear, a turn in three), which the map may not allow; the car's bound says so.
        key = (g + np.maximum(H, tree.car)).tolist()
        improved = False
        for i in sorted(near, key=lambda j: (key[j], j)):
            if (self.attempts() >= prm.connect_tries or not s.budget_left()
                    or self.improvement_spent()):
                break
            if key[i] >= s.best * (1 - IMPROVE_TOL):
                continue
            self.tried.add(i)
            if (s.f.rate_limited and s.f.vx > s.f.tight_vx and not tree.tight[i]
                    and tree.direction[i] >= 0 and abs(tree.steer[i]) > s.f.connect_steer_max):
                # The connection drives the kinematic bicycle: at the tree's speed (above the
                # tight moves') and a steer this large the dynamic bicycle turns on a wider
                # circle, and the path's curvature would step where the connection sets off
                # (as between speeds, expansion.SPEED_CHANGE_STEER), a steer jump the car
                # cannot drive.
                self.cheap.add(i)
                self.failures.append(f"steer past {s.f.connect_steer_max:g} rad at the tree's "
                                     "speed")
                continue
            # The OCP ignores obstacles: started from a free path it more often stays free
            # (rate-limited; the paper's planner tries every word's guess).
            words = guess_paths(self.rear(tree.states[i]), self.rear(s.goal), s.radius,
                                prm.reverse)
            guesses = self.free_guesses(i, words)
            if guesses is not None and not s.f.rate_limited:
                guesses = words
            if guesses is None:
                # The OCP starts from these paths and ignores obstacles: it would collide too.
                self.cheap.add(i)
                self.failures.append("every Dubins path collides" if not prm.reverse
                                     else "every Dubins and Reeds-Shepp path collides")
                continue
            t0 = perf_counter()
            direction = int(tree.direction[i]) or 1
            conn, why = s.f.connect(tree.states[i], s.goal, s.goal_speed, direction=direction,
                                    paths=guesses, steer=float(tree.steer[i]),
                                    speed=s.f.tight_vx if tree.tight[i] or direction < 0
                                    else s.f.vx)
            self.seconds += perf_counter() - t0
            if why:
                self.failures.append(why)
                continue
            length = float(g[i] + self.cost(conn, direction))
            if length >= s.best * (1 - IMPROVE_TOL):
                continue
            if not math.isfinite(s.best):
                res.first_solution_s = perf_counter() - s.t0
                res.reason = (f"connected to the goal from a node {H[i]:.2f} m away "
                              f"(attempt {self.attempts()})")
            s.best, improved, self.improved_at = length, True, self.attempts()
            s.set_path(i)
            res.connection, res.cause = conn, Cause.CONNECTED
            res.solution_s = perf_counter() - s.t0
            res.progress.append((res.solution_s, length))
        return improved
