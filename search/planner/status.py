"""What a plan found: its status (OMPL's PlannerStatus, in the words plan.json writes), the
cause of that status, and the path as the tree edges and the connection that make it."""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from stepzoo.search.planner.connection_ocp import Connection


class PlannerStatus(StrEnum):
    """How a plan ended; the value is what plan.json's `status` holds."""
    EXACT = "exact"               # a path to the goal pose
    APPROXIMATE = "approximate"   # a path to the tree node nearest the goal
    NO_PATH = "no_path"           # none: a bad input, or a proof that none exists


class Cause(StrEnum):
    """Why a plan ended as it did; the value is what plan.json's `cause` holds."""
    START_OFF_MAP = "start_off_map"
    START_IN_COLLISION = "start_in_collision"
    GOAL_OFF_MAP = "goal_off_map"
    GOAL_IN_COLLISION = "goal_in_collision"
    WALLED_OFF = "walled_off"                # no corridor as wide as the car joins the ends
    START_BOXED_IN = "start_boxed_in"        # no forward path leaves the start
    GOAL_BOXED_IN = "goal_boxed_in"          # ... or arrives at the goal
    EXHAUSTED = "exhausted"                  # every reachable pruning cell was expanded
    BUDGET = "budget"                        # the termination condition ended the search
    CONNECTIONS_FAILED = "connections_failed"  # connect_tries OCPs, none collision-free
    CONNECTED = "connected"                  # an exact path


# Bad endpoints are the caller's input: no search was run.
BAD_ENDPOINT = (Cause.START_OFF_MAP, Cause.START_IN_COLLISION, Cause.GOAL_OFF_MAP,
                Cause.GOAL_IN_COLLISION)
# A boxed-in end is a true result for this car, not a bad input: no_path, no search run.
BOXED_IN = (Cause.START_BOXED_IN, Cause.GOAL_BOXED_IN)


@dataclass
class PlanResult:
    """What a plan found. `path_edges` are the tree shootings from the start to the node the
    path ends at (each (n_steps+1, 5) [X, Y, psi, vy, r] at steps of h), `path_steers` their
    constant steers [rad] (rate-limited: their end steers, `path_steer_rates` their rates),
    `path_tight` whether each is a tight move (kinematic bicycle),
    `path_directions` the way each was driven (+1 forwards, -1 backwards: reverse gear, on the
    kinematic bicycle), `connection` the OCP segment to the goal (exact plans only); with
    `vx` they are the controls that produce the path (search/plans/replay.py)."""
    status: PlannerStatus
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
    cause: Cause | None = None    # the reason as a word for programs
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
    tight_vx: float = 0.0         # [m/s] the speed tight moves are driven at
    path_directions: list = field(default_factory=list)
    # Rate-limited steering: each path edge's constant steer rate [rad/s], its steer ramping
    # to path_steers from the previous edge's end steer (from a standstill, the start or a
    # cusp, from its own: the driver turns the wheel before moving off); empty if instant.
    path_steer_rates: list = field(default_factory=list)

    def path_length(self) -> float:
        """[m] along the tree edges and the connection."""
        pieces = [e[:, :2] for e in self.path_edges]
        if self.connection is not None:
            pieces.append(self.connection.states[:, :2])
        return float(sum(np.hypot(*np.diff(p, axis=0).T).sum() for p in pieces))
