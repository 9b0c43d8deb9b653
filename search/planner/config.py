"""The planner's configuration: the integrator (method, step h) that `stepzoo tune` writes, and
the planner parameters declared once (`PlannerParams`: name, default, range, unit, reason and
doc line), so runs can log them and the docs list them.

A config TOML has top-level `method` and `h`; an optional `[planner]` table overrides params."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, field_validator

from stepzoo.config_schema import Schema, check, quantity
from stepzoo.errors import UsageError
from stepzoo.validate import check as check_value
from stepzoo.validate import check_budget, read_toml

DEFAULT_CONFIG = Path(__file__).with_name("tuned_default.toml")

Steer = Annotated[float, quantity(
    "a steer limit", "rad", "above 0.05 the arc holds distinct points; below 1.5 (86 degrees) "
    "tan(delta) and the turning radius stay finite", ge=0.05, le=1.5)]
Count = Annotated[int, quantity("a count", "", "at least one; the upper bound keeps one "
                                "expansion's batch within memory", ge=1, le=64)]
Switch = Annotated[int, quantity("a switch", "", "0 off, 1 on (true and false read as 1 and 0)",
                                 ge=0, le=1)]


class PlannerParams(Schema):
    """The tree planner's parameters (a planner config's `[planner]` table), frozen: a plan
    reads them as attributes and logs them whole."""
    delta_max: Steer = Field(math.pi / 4, description=(
        "steer limit; the point-selector arc spans psi +- delta_max [rad]"))
    arc_radius: Annotated[float, quantity(
        "a radius", "m", "from about a car's width to a block's length: shorter arcs stall, "
        "longer ones jump walls", ge=0.5, le=50.0)] = Field(
        4.0, description="radius of the point-selector arc ahead of a node [m]")
    n_arc: Count = Field(7, description="equally spaced points on the arc [1]")
    n_random: Annotated[int, quantity(
        "a count", "", "0 turns the random points off; the upper bound keeps one expansion's "
        "batch within memory", ge=0, le=64)] = Field(
        3, description="seeded random points around the destination, per expansion [1]")
    random_spread: Annotated[float, quantity(
        "a radius", "m", "0 puts every random point on the goal; beyond 100 m they no longer "
        "lead towards it", ge=0.0, le=100.0)] = Field(
        3.0, description="radius of the disc the random points fill [m]")
    horizon: Annotated[float, quantity(
        "a duration", "s", "at least one short step; beyond 10 s a shooting crosses a map "
        "without branching", ge=0.01, le=10.0)] = Field(
        0.8, description="duration of one shooting (rounded to whole steps) [s]")
    mindist: Annotated[float, quantity(
        "a distance", "m", "within the reach of the connection OCP, which ignores obstacles",
        ge=0.5, le=100.0)] = Field(
        6.0, description="a node this close to the goal triggers a connection [m]")
    connect_radius: Annotated[float, quantity(
        "a distance", "m", "from the car's size to a long street: the OCP ignores obstacles, "
        "so far candidates rarely connect", ge=0.5, le=200.0)] = Field(12.0, description=(
            "tree nodes this close to the goal are connection candidates, shortest Dubins "
            "first [m]"))
    h_weight: Annotated[float, quantity(
        "a weight", "", "1 is the paper's sum; above 10 the search ignores the distance "
        "travelled", ge=1.0, le=10.0)] = Field(2.0, description=(
            "w in the search order f = g + w H (1: the paper's sum; above 1 finds a first path "
            "sooner, which the improvement then shortens) [1]"))
    cell_xy: Annotated[float, quantity(
        "a cell size", "m", "finer than integration noise prunes nothing; coarser than a "
        "street merges its lanes", ge=0.05, le=20.0)] = Field(
        1.0, description="position cell of duplicate pruning [m]")
    cell_heading: Annotated[float, quantity(
        "a cell size", "rad", "up to a half turn; below 0.01 rad headings that differ by noise "
        "count as new", ge=0.01, le=math.pi)] = Field(math.pi / 8, description=(
            "heading cell of duplicate pruning [rad]"))
    margin: Annotated[float, quantity(
        "a margin", "m", "0 trusts the integration exactly; beyond 5 m no street is wide "
        "enough", ge=0.0, le=5.0)] = Field(0.1, description=(
            "footprint inflation on every side: covers integration error and cell rounding "
            "[m]"))
    max_expansions: Annotated[int, quantity(
        "a budget", "", "at least one expansion; the upper bound keeps the tree within memory",
        ge=1, le=10_000_000)] = Field(
        1_000_000, description=("budget of expansions (the default is far beyond what "
                                "max_seconds allows: the time bounds the plan) [1]"))
    max_seconds: Annotated[float, quantity(
        "a budget", "s", "from a millisecond to an hour", ge=0.001, le=3600.0)] = Field(
        20.0, description="budget of wall time, search and connections [s]")
    connect_tries: Annotated[int, quantity(
        "a count", "", "at least one OCP; each costs a solve", ge=1, le=10_000)] = Field(
        64, description="connection attempts before giving up [1]")
    improve_expansions: Annotated[int, quantity(
        "a count", "", "0 stops at the first path", ge=0, le=10_000_000)] = Field(
        300, description=("after the first exact path, expansions without a shorter one before "
                          "the plan ends (0: stop at the first, as the paper) [1]"))
    improve_attempts: Annotated[int, quantity(
        "a count", "", "0 sets no such bound; each attempt costs an OCP solve", ge=0,
        le=10_000)] = Field(0, description=(
            "after the first exact path, connection attempts (OCP solves) in a row without a "
            "shorter path before the plan ends (0: no such bound, improve_expansions and the "
            "budget end it) [1]"))
    reverse: Switch = Field(0, description=(
        "1: reverse gear (expansions backwards too, the connection may reverse); 0: forward "
        "only, as the paper [1]"))
    tight_moves: Switch = Field(1, description=(
        "1: tight moves (the kinematic bicycle at tight_speed, out to full lock) from every "
        "node where a move of the tree's collides, and from every node once the tree exhausts "
        "unsolved; they chain until the tree's own moves take over; 0: the tree's own moves "
        "only, as the paper [1]"))
    steering: Literal["rate_limited", "course_limited", "instant"] = Field(
        "course_limited", description=(
            "rate_limited: the steer angle is a state whose rate is bounded by the vehicle's "
            "max_steer_rate (tree edges are steer ramps, the connection's control is the steer "
            "rate) and the curvature by its max_lateral_acceleration at the planned speed; "
            "course_limited: rate_limited, and the course of the car's rear axle within those "
            "limits too, where the tyres' slip changes (the tree's own moves ramp at "
            "dynamic_rate_fraction, change their rate by at most it, and change speed or "
            "connect only with the wheel straight: docs/studies/course-reading-2026-11-29e.md "
            "and one-car-2026-11-29f.md); instant: each edge at one constant steer set at "
            "once, as the paper [1]"))
    guide: Literal["geodesic", "heading"] = Field("geodesic", description=(
        "the search's guide H: geodesic, the 2-D lattice geodesic to the goal (positions only; "
        "near the goal the larger of it and the Dubins or Reeds-Shepp length), as the paper's "
        "planner here has it; heading, the larger of that and the cost to go over an (x, y, "
        "heading) lattice of the car's turns solved from the goal (search/planner/"
        "heading_lattice.py), which leads the tree to the goal and through doors facing the "
        "way it must [1]"))
    tie_break: Literal["inserted", "cell"] = Field("cell", description=(
        "which of two nodes of equal f the search expands first: inserted, the older (f as "
        "computed, so f that differ in their last bits only are ordered by that rounding), as "
        "the paper's planner here has it; cell, f compared in steps of 2^-20 m and ties to the "
        "lesser pruning cell, so a rounding of the integration does not reorder siblings [1]"))
    narrow_cell_m: Annotated[float, quantity(
        "a clearance", "m", "0 turns it off; beyond 10 m nearly every cell of a street is "
        "halved", ge=0.0, le=10.0)] = Field(3.0, description=(
            "pruning cells are halved (position and heading) where the car's centre is less "
            "than this from an obstacle: in a door one node per cell cannot hold the "
            "alignment the door needs (0: off, as the paper's planner) [m]"))
    connect_steer_max: Annotated[float, quantity(
        "a steer angle", "rad", "0.3 is where the dynamic bicycle's circle parts from the "
        "kinematic one's (expansion.SPEED_CHANGE_STEER); course_limited steering connects "
        "within expansion.STRAIGHT_STEER (0.01) whatever this is; at or above the steer limit "
        "it is off", ge=0.0, le=1.6)] = Field(0.3, description=(
            "no connection sets off from a node of the tree's own moves, where they drive "
            "faster than its tight moves, steered past this: the kinematic connection's (X, Y) "
            "moves along its heading, the dynamic edge's centre of gravity along its body's "
            "heading plus a slip of about half the steer, so the course would kink where the "
            "connection sets off (1.6: off, as the paper's planner) [rad]"))
    tight_speed: Annotated[float, quantity(
        "a speed", "m/s", "a walking pace to a slow roll: below 0.5 m/s a move covers less than "
        "a pruning cell; above 5 m/s it is no longer tighter than the tree's", ge=0.5,
        le=5.0)] = Field(2.0, description=(
            "speed of the tight moves and of reversing with rate-limited steering (instant: "
            "the tree's speed), at most the tree's: at a steer rate r the steer turns r / v per "
            "metre, so at 2 m/s the wheel reaches full lock 2.5 times sooner than at 5 m/s "
            "[m/s]"))
    limit_fraction: Annotated[float, quantity(
        "a fraction", "", "1 plans at the car's limits; below 0.5 a plan gives away half its "
        "turning", ge=0.5, le=1.0)] = Field(0.8, description=(
            "the planner plans to this fraction of the vehicle's max_steer_rate and "
            "max_lateral_acceleration (rate-limited steering): the tracked car (Fiala tyres) "
            "grips to about 10.3 m/s^2, below the 11.5 m/s^2 of the published limit, and a "
            "tracking controller needs steer rate beyond the plan's to correct its errors [1]"))
    dynamic_rate_fraction: Annotated[float, quantity(
        "a fraction", "", "at least a tenth of the steer rate, so a move still turns; at most "
        "the car's limit", ge=0.1, le=1.0)] = Field(0.6, description=(
            "course_limited steering: the tree's own moves (the dynamic bicycle at the tree's "
            "speed) ramp the steer at most this fraction of the vehicle's max_steer_rate "
            "(and at most limit_fraction): the centre of gravity moves sideways with the steer "
            "before the body turns, so the course of (X, Y) reads each change of the ramp's "
            "rate as a step of the steer; with the rate changing by at most its limit between "
            "edges (expansion.RATE_CHANGE) the course reads 1.8 times the rate (a linear-tyre "
            "oracle at 5 m/s), 0.435 rad/s at 0.6 (0.24 rad/s), within 1.25 times the 0.4 "
            "rad/s limit (docs/studies/course-reading-2026-11-29e.md) [1]"))
    reverse_penalty: Annotated[float, quantity(
        "a factor", "", "1 makes a metre backwards cost what one forwards does; beyond 10 "
        "reversing is all but forbidden", ge=1.0, le=10.0)] = Field(3.0, description=(
            "a metre driven backwards costs this many metres in g (with reverse = 1); above "
            "h_weight (2), since a move backwards towards a goal behind the car changes f = g + "
            "h_weight H by (reverse_penalty - h_weight) per metre, and at 2 (Nav2 Smac "
            "Hybrid-A*'s and Kurzer's Hybrid A*'s default) the greedy first path backed whole "
            "queries [1]"))
    cusp_cost: Annotated[float, quantity(
        "a length", "m", "0 makes cusps free; beyond 1 km one forbids them", ge=0.0,
        le=1000.0)] = Field(5.0, description=(
            "added to the cost g at each change of direction (with reverse = 1) [m]"))
    connect_N: Annotated[int, quantity(
        "a count", "", "at least five intervals resolve a turn; the upper bound keeps one OCP "
        "solve short", ge=5, le=1000)] = Field(
        50, description="input intervals of the connection OCP [1]")
    batch_nodes: Count = Field(4, description=(
        "nodes expanded together, best f first, their shootings integrated in one call (1: one "
        "node at a time, as the paper) [1]"))

    @field_validator("reverse", "tight_moves", mode="before")
    @classmethod
    def _switch(cls, value):
        """A switch written `true` or `false` reads as 1 or 0."""
        return int(value) if isinstance(value, bool) else value


@dataclass(frozen=True)
class PlannerConfig:
    """Integrator (method, h [s]) plus planner params; `provenance` says where they came from."""
    method: str = "rk4"
    h: float = 0.02
    params: PlannerParams = field(default_factory=PlannerParams)
    provenance: str = "built-in defaults"
    source: str = ""

    @property
    def n_steps(self) -> int:
        """Integration steps per shooting: the horizon rounded to whole steps, at least one."""
        return max(1, round(self.params.horizon / self.h))


def planner_params(overrides: dict, base: PlannerParams | None = None,
                   where: str = "planner parameters") -> PlannerParams:
    """`base` (default: the defaults) with `overrides` by name, validated: UsageError naming
    every unknown key and out-of-range value at once."""
    values = (base or PlannerParams()).model_dump()
    return check(PlannerParams, {**values, **overrides}, where)


def make_config(method="rk4", h=0.02, provenance="built-in defaults", source="",
                **overrides) -> PlannerConfig:
    """A validated config: method a zoo name, h > 0 [s], overrides by param name."""
    from stepzoo.integrators import METHODS
    if not isinstance(method, str) or method not in METHODS:
        raise UsageError(f"unknown integration method {method!r} in the planner config; "
                         f"use one of {', '.join(METHODS)}")
    check_value("step", "planner step h", h)
    where = f"{source} [planner]" if source else "planner parameters"
    config = PlannerConfig(method, float(h), planner_params(overrides, where=where),
                           str(provenance), str(source))
    _check_budget(config)
    return config


def with_params(config: PlannerConfig, **overrides) -> PlannerConfig:
    """`config` with params overridden by name (validated), e.g. from command-line flags."""
    params = planner_params(overrides, config.params)
    return PlannerConfig(config.method, config.h, params, config.provenance, config.source)


def _check_budget(config: PlannerConfig) -> None:
    """UsageError if one integration call of the planner would not fit in memory: it shoots
    n_arc + n_random trajectories of n_steps from each of batch_nodes nodes, 5 states kept."""
    prm = config.params
    check_budget(f"the planner at h = {config.h:g} s", config.n_steps + 1,
                 prm.batch_nodes * (prm.n_arc + prm.n_random), 5, calls=prm.max_expansions)


def load_config(path=None) -> PlannerConfig:
    """Read a planner config TOML (default: the shipped tuned_default.toml), a tuned file
    (stepzoo.tuned_file: what `stepzoo tune` writes; unknown keys refused)."""
    from stepzoo.config_schema import check
    from stepzoo.tuned_file import TunedFile
    path = Path(path) if path is not None else DEFAULT_CONFIG
    data = read_toml(path, "planner config", "give a TOML file written by `stepzoo tune`")
    choice = check(TunedFile, data, str(path)).choice     # the evidence is tune's, not ours
    provenance = choice.provenance if choice.provenance is not None else (choice.why or
                                                                          "not stated")
    return make_config(choice.method, choice.h, provenance, str(path), **choice.planner)
