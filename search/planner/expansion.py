"""An expansion of the tree (paper Algorithms 2 and 3): from each of a batch of nodes, shoot
towards the point-selector arc and seeded random points (and, with reverse gear, backwards;
where a move collides or once the search has widened, tight moves at a fan of steers), all
in one integration call, and add every end in a new pruning cell as a child."""
from __future__ import annotations

import math

import numpy as np

from stepzoo.search.planner.point_selector import point_selector, random_points
from stepzoo.search.planner.shooting import Shots, integrate_together

PREFIX_FRACTION = 4     # a colliding shooting's free first part is kept from 1/4 of its rows
# [rad] the car changes between the tree's speed and tight_speed only with its steer within
# this: at one steer the dynamic bicycle at 5 m/s turns on a circle 1.3 times the kinematic
# one's, so a change of speed at a large steer is a step in curvature the path rows read as a
# jump of the steer (a fifth of it); within 0.3 rad that step stays under 0.07 rad.
SPEED_CHANGE_STEER = 0.3
# [rad] course_limited steering: within this, the wheel all but straight. The dynamic
# bicycle's tyres slip (its centre of gravity about half the steer aside of its body at
# 5 m/s, its rear axle a few hundredths of a radian), the rigid car's kinematic moves do not,
# so a change of speed (or the connection setting off) with the wheel turned is a kink in the
# course of the rear axle (and of (X, Y)); within 0.01 rad it stays under 5 mrad. Such nodes
# also get pruning cells of their own.
STRAIGHT_STEER = 0.01
# course_limited steering: the tree's own move (the dynamic bicycle) sets its steer rate
# within this fraction of its rate limit of its edge's rate: the slip of its centre of gravity
# follows the steer, so each change of the steer rate steps the course's curvature (a
# linear-tyre oracle at 5 m/s: 1.03 rad/s of implied steer rate per rad/s of change), and a
# ramp reversed at once (twice the rate) reads 2.4 times the rate by the course, one changed
# by at most its rate 1.8 times. A tight move from such a node keeps the same bound, and the
# tree's move from a tight node's sets a rate whose sum with the tight ramp's stays within
# the tight moves' rate (the slip it sets off adds to the course's turning).
RATE_CHANGE = 1.0


class Expander:
    """Expansions for one search (`search`: pathfinder.Search, whose tree, guide, pruning
    cells and refinement level they read and grow)."""

    def __init__(self, search):
        self.s = search
        self.per = search.prm.n_arc + search.prm.n_random  # shootings per node and gear

    def expand(self, nodes) -> list[int]:
        """Shoot from each of `nodes` and add the kept ends; returns the new node ids."""
        s, prm, tree = self.s, self.s.prm, self.s.tree
        randoms = []
        for node in nodes:
            points = random_points(s.rng, s.goal, prm.n_random, prm.random_spread)
            if len(points):
                # One point leads along the geodesic instead: through the doors and round the
                # corners the lattice path takes, where the arc and the goal's disc rarely aim.
                points[0] = s.guide.descend(tree.states[node], prm.arc_radius)
            randoms.append(points)
        rows = self.filled(nodes)
        states = np.repeat(tree.states[rows], self.per, axis=0)
        steers = np.repeat(tree.steer[rows], self.per)  # each shooting starts at its node's
        ways = np.repeat(tree.direction[rows], self.per)
        new = []
        cramped = np.zeros(len(nodes), bool)  # nodes where a move of the tree's collides
        gears = [(1, s.f.shooter)]
        if s.f.back_shooter is not None:
            gears.append((-1, s.f.back_shooter))
        requests = []
        for direction, shooter in gears:
            aims = []
            for node, random in zip(rows, self.filled(randoms)):
                state = tree.states[node]
                ahead = np.r_[state[:2], state[2] + (0.0 if direction > 0 else math.pi)]
                aims += [point_selector(ahead, prm.arc_radius, prm.n_arc, s.f.delta_max),
                         random]
            # From the start or at a cusp the car stands: it turns the wheel before moving off.
            standing = (ways == 0) | (ways == -direction)
            # Rate-limited, a dynamic edge after a standstill or a kinematic edge sets off at
            # the lateral steady state of its steer: the car rolls without slip on a turn of
            # that steer, so it carries the turn on instead of a transient of its own making.
            settle = None
            if s.f.rate_limited and direction > 0:
                settle = standing | (ways < 0) | np.repeat(tree.tight[rows], self.per)
            steer0 = np.where(standing, np.nan, steers)
            steer = shooter.aim(states, np.vstack(aims), steer0)
            if direction > 0 and s.f.course_limited:
                steer = self.rate_bounded(rows, steer, steer0, shooter)
            requests.append((shooter, shooter.launch(states, steer, steer0, settle), steer,
                             steer0))
        # Tight moves (below) are shot from every node of the batch in the same call as the
        # tree's moves, before it is known which nodes take them: one call of the driver per
        # expansion, the unused ones dropped.
        speculate = s.prm.tight_moves and (s.f.rate_limited or s.result.widened)
        if speculate:
            requests.append(self.tight_request(rows))
        trajectories = integrate_together(requests)
        for (direction, shooter), (_, _, steer, steer0), states in zip(gears, requests,
                                                                      trajectories):
            shots = shooter.shots(states, steer, steer0, s.goal)
            if direction > 0 and s.f.rate_limited:
                # From a tight move's node the car speeds up only with its wheel near straight.
                slow = np.repeat(tree.tight[rows], self.per)
                shots.free[slow & (np.abs(shots.steer0) > s.f.speed_change_steer)] = 0
            cramped |= (shots.free < shots.states.shape[1]).reshape(len(rows), -1).any(
                axis=1)[:len(nodes)]
            new += self.add_all(nodes, direction, shots)
        # Tight moves: where a move of the tree's collides (a door, a corner: the tree at its
        # speed may not turn in time), from every node once the tree exhausted, and along
        # chains of tight moves; once a node is reached by the tree's own move, the tree goes
        # on alone.
        # Rate-limited, the car slows down from the tree's move only with its wheel near
        # straight (course_limited: also once the tree exhausted).
        slows = [not s.f.rate_limited or tree.direction[i] != 1
                 or abs(tree.steer[i]) <= s.f.speed_change_steer for i in nodes]
        tight = [k for k, i in enumerate(nodes)
                 if tree.tight[i] or (i < s.widened_at and (slows[k] or not s.f.course_limited))
                 or (cramped[k] and s.prm.tight_moves and s.f.rate_limited and slows[k])]
        if tight:
            assert speculate, "tight moves are shot only where the search may take them"
            shooter, _, steer, steer0 = requests[-1]
            # The shootings of the nodes that take them, each node's block of `per`.
            pick = (np.array(tight)[:, None] * self.per + np.arange(self.per)).ravel()
            shots = shooter.shots(trajectories[-1][pick], steer[pick], steer0[pick], s.goal)
            new += self.add_all([nodes[k] for k in tight], 1, shots, tight=True)
        return new

    def rate_bounded(self, rows, steer, steer0, shooter) -> np.ndarray:
        """(B,) the end steers `steer` of `shooter`'s moves from the nodes `rows` (`per`
        each) at start steers `steer0` (NaN: from a standstill, unbounded), bounded so that
        each move's steer rate lies within `step` of the rate `edge_rates` gives."""
        rate, step = (np.repeat(a, self.per) for a in self.edge_rates(rows, shooter.kinematic))
        T, top = shooter.duration, shooter.rate
        free = np.isnan(rate)       # not after the tree's own move: no bound of its own
        lo = steer0 + T * np.where(free, -top, np.maximum(-top, rate - step))
        hi = steer0 + T * np.where(free, top, np.minimum(top, rate + step))
        with np.errstate(invalid="ignore"):
            return np.where(np.isnan(steer0), steer, np.clip(steer, lo, hi))

    def edge_rates(self, rows, kinematic) -> tuple[np.ndarray, np.ndarray]:
        """(len(rows),) [rad/s] the rate a move from each node (a kinematic one if
        `kinematic`) keeps its steer rate near, and (len(rows),) [rad/s] how near: after the
        tree's own move forwards, that move's rate, within RATE_CHANGE of the tree's rate
        limit; after a tight move, for the tree's own move, minus the tight move's rate,
        within the tight moves' rate limit; else NaN (no bound)."""
        tree, f = self.s.tree, self.s.f
        rate, step = np.full(len(rows), np.nan), np.zeros(len(rows))
        for k, i in enumerate(rows):
            edge = tree.edges[i]
            if edge is None or tree.direction[i] <= 0 or len(edge) < 2 or (
                    kinematic and tree.tight[i]):
                continue
            own = (tree.steer[i] - tree.steer0[i]) / ((len(edge) - 1) * f.config.h)
            rate[k] = -own if tree.tight[i] else own
            step[k] = f.tight_shooter.rate if tree.tight[i] else RATE_CHANGE * f.shooter.rate
        return rate, step

    def tight_request(self, rows) -> tuple:
        """(tight_shooter, start states, end steers, start steers) of the tight moves from each
        node of `rows` (batch_nodes of them): a fan of `per` steers out to full lock, or
        rate-limited, the steers one shooting can reach from the node's."""
        s, tree = self.s, self.s.tree
        shooter = s.f.tight_shooter
        standing = tree.direction[rows] != 1    # from the start or a cusp
        steers = np.repeat(tree.steer[rows], self.per)
        steers[np.repeat(standing, self.per)] = np.nan
        limit = shooter.delta_max
        fan = np.tile(np.linspace(-limit, limit, self.per), len(rows))
        if shooter.rate is not None:
            # Rate-limited, the fan spans the steers one shooting can reach.
            reach = shooter.rate * shooter.duration
            near = np.clip(steers + np.tile(np.linspace(-reach, reach, self.per), len(rows)),
                           -limit, limit)
            if s.f.course_limited:
                # The one nearest straight straightens the wheel as far as it can, so that a
                # chain of tight moves can reach the straight wheel the tree's move sets off
                # with.
                middle = np.arange(len(rows)) * self.per + self.per // 2
                near[middle] = np.clip(0.0, steers[middle] - reach, steers[middle] + reach)
                near = self.rate_bounded(rows, near, steers, shooter)
            fan = np.where(np.isnan(steers), fan, near)
        start = np.repeat(tree.states[rows], self.per, axis=0)
        return shooter, shooter.launch(start, fan, steers), fan, steers

    def filled(self, items: list) -> list:
        """`items` (at most batch_nodes) filled up to batch_nodes with copies of its last: a
        short batch's extra shootings are dropped by add_all."""
        return items + items[-1:] * (self.s.prm.batch_nodes - len(items))

    def add_all(self, nodes, direction, shots, tight=False) -> list[int]:
        """Add the kept shootings of a batch, n_arc + n_random per node of `nodes`."""
        new = []
        for k, node in enumerate(nodes):
            part = slice(k * self.per, (k + 1) * self.per)
            new += self.add(node, direction, Shots(*(a[part] for a in shots)), tight)
        return new

    def add(self, node, direction, shots, tight=False) -> list[int]:
        """Add the kept shootings of `shots`, driven in `direction` (tight moves or not), as
        children of `node`: those valid to the end, or whose valid first part is long enough,
        and whose end lies in a pruning cell not yet seen."""
        s, tree = self.s, self.s.tree
        last = shots.free - 1  # the last row kept of each shooting
        # Each refinement halves the least prefix too: shorter moves in tight spots.
        least = shots.states.shape[1] // (PREFIX_FRACTION * 2 ** s.level)
        keep = np.flatnonzero(last >= max(1, least))
        ends = shots.states[keep, last[keep]]
        ramp = last[keep] / (shots.states.shape[1] - 1)
        steer_end = shots.steer0[keep] + (shots.steer[keep] - shots.steer0[keep]) * ramp
        fresh = []
        for j, end in enumerate(ends.tolist()):
            cell = s.cell(end, direction, steer_end[j])
            if cell not in s.seen:
                s.seen.add(cell)
                fresh.append(j)
        if not fresh:
            return []
        ends, keep = ends[fresh], keep[fresh]
        # A change of direction costs cusp_cost [m] on top of the distance driven, and a metre
        # backwards reverse_penalty metres.
        cusp = s.prm.cusp_cost if tree.direction[node] == -direction else 0.0
        per_metre = s.prm.reverse_penalty if direction < 0 else 1.0
        steer, steer0 = shots.steer[keep], shots.steer0[keep]
        # A shooting cut short by a collision ends part of the way up its steer ramp.
        steer = steer0 + (steer - steer0) * (last[keep] / (shots.states.shape[1] - 1))
        return list(tree.add(
            [shots.states[k, :last[k] + 1] for k in keep.tolist()], states=ends, parent=node,
            g=tree.g[node] + per_metre * shots.travelled[keep, last[keep]] + cusp,
            H=np.hypot(*(ends[:, :2] - s.goal[:2]).T), rest=s.guide.rest(ends),
            guide=s.guide.guide(ends), car=s.guide.car_bound(ends), steer=steer, steer0=steer0,
            direction=direction, tight=tight))
