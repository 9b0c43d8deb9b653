"""The planner's configuration: the integrator (method, step h) that `stepzoo tune` writes, and
every planner parameter declared once by name, default, range and unit, so runs can log them.

A config TOML has top-level `method` and `h`; an optional `[planner]` table overrides params."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from stepzoo.errors import UsageError
from stepzoo.validate import check, check_budget, read_toml

DEFAULT_CONFIG = Path(__file__).with_name("tuned_default.toml")


@dataclass(frozen=True)
class Param:
    """One planner parameter: default, closed range [lo, hi], unit and meaning."""
    name: str
    default: float | int
    lo: float
    hi: float
    unit: str
    doc: str

    @property
    def integer(self) -> bool:
        return isinstance(self.default, int)


PARAMS = {p.name: p for p in (
    Param("delta_max", math.pi / 4, 0.05, 1.5, "rad",
          "steer limit; the point-selector arc spans psi +- delta_max"),
    Param("arc_radius", 4.0, 0.5, 50.0, "m", "radius of the point-selector arc ahead of a node"),
    Param("n_arc", 7, 1, 64, "1", "equally spaced points on the arc"),
    Param("n_random", 3, 0, 64, "1", "seeded random points around the destination, per expansion"),
    Param("random_spread", 3.0, 0.0, 100.0, "m", "radius of the disc the random points fill"),
    Param("horizon", 0.8, 0.01, 10.0, "s", "duration of one shooting (rounded to whole steps)"),
    Param("mindist", 6.0, 0.5, 100.0, "m", "a node this close to the goal triggers a connection"),
    Param("connect_radius", 12.0, 0.5, 200.0, "m",
          "tree nodes this close to the goal are connection candidates, shortest Dubins first"),
    Param("h_weight", 2.0, 1.0, 10.0, "1",
          "w in the search order f = g + w H (1: the paper's sum; above 1 finds a first path "
          "sooner, which the improvement then shortens)"),
    Param("cell_xy", 1.0, 0.05, 20.0, "m", "position cell of duplicate pruning"),
    Param("cell_heading", math.pi / 8, 0.01, math.pi, "rad", "heading cell of duplicate pruning"),
    Param("margin", 0.1, 0.0, 5.0, "m",
          "footprint inflation on every side: covers integration error and cell rounding"),
    Param("max_expansions", 1_000_000, 1, 10_000_000, "1",
          "budget of expansions (the default is far beyond what max_seconds allows: the time "
          "bounds the plan)"),
    Param("max_seconds", 20.0, 0.001, 3600.0, "s", "budget of wall time, search and connections"),
    Param("connect_tries", 64, 1, 10_000, "1", "connection attempts before giving up"),
    Param("improve_expansions", 300, 0, 10_000_000, "1",
          "after the first exact path, expansions without a shorter one before the plan ends "
          "(0: stop at the first, as the paper)"),
    Param("reverse", 0, 0, 1, "1",
          "1: reverse gear (expansions backwards too, the connection may reverse); 0: forward "
          "only, as the paper"),
    Param("tight_moves", 1, 0, 1, "1",
          "1: when the tree exhausts unsolved, expand every node again with tight moves too "
          "(the kinematic bicycle, out to full lock), which chain until the tree's own moves "
          "take over; 0: the tree's own moves only, as the paper"),
    Param("cusp_cost", 5.0, 0.0, 1000.0, "m",
          "added to the cost g at each change of direction (with reverse = 1)"),
    Param("connect_N", 50, 5, 1000, "1", "input intervals of the connection OCP"),
    Param("batch_nodes", 4, 1, 64, "1",
          "nodes expanded together, best f first, their shootings integrated in one call "
          "(1: one node at a time, as the paper)"),
)}


@dataclass(frozen=True)
class PlannerConfig:
    """Integrator (method, h [s]) plus planner params; `provenance` says where they came from."""
    method: str = "rk4"
    h: float = 0.02
    params: dict = field(default_factory=lambda: {k: p.default for k, p in PARAMS.items()})
    provenance: str = "built-in defaults"
    source: str = ""

    @property
    def n_steps(self) -> int:
        """Integration steps per shooting: the horizon rounded to whole steps, at least one."""
        return max(1, round(self.params["horizon"] / self.h))


def check_param(name: str, value):
    """`value` of planner param `name`, validated against its declared range; else UsageError."""
    if name not in PARAMS:
        raise UsageError(f"unknown planner parameter {name!r}; known: {', '.join(PARAMS)}")
    spec = PARAMS[name]
    if spec.lo == 0 and spec.hi == 1 and spec.integer and isinstance(value, bool):
        value = int(value)  # a switch: `reverse = true` reads as 1
    ok_type = isinstance(value, int) if spec.integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok_type or not (spec.lo <= value <= spec.hi):
        kind = "a whole number" if spec.integer else "a number"
        raise UsageError(f"planner parameter {name} must be {kind} in [{spec.lo}, {spec.hi}] "
                         f"[{spec.unit}], got {value!r}")
    return int(value) if spec.integer else float(value)


def make_config(method="rk4", h=0.02, provenance="built-in defaults", source="",
                **overrides) -> PlannerConfig:
    """A validated config: method a zoo name, h > 0 [s], overrides by param name."""
    from stepzoo.integrators import METHODS
    if not isinstance(method, str) or method not in METHODS:
        raise UsageError(f"unknown integration method {method!r} in the planner config; "
                         f"use one of {', '.join(METHODS)}")
    check("step", "planner step h", h)
    params = {k: p.default for k, p in PARAMS.items()}
    params.update({k: check_param(k, v) for k, v in overrides.items()})
    config = PlannerConfig(method, float(h), params, str(provenance), str(source))
    # One call shoots n_arc + n_random trajectories of n_steps from each of batch_nodes nodes,
    # the 5 states kept.
    batch = params["batch_nodes"] * (params["n_arc"] + params["n_random"])
    check_budget(f"the planner at h = {h:g} s", config.n_steps + 1, batch, 5,
                 calls=params["max_expansions"])
    return config


def with_params(config: PlannerConfig, **overrides) -> PlannerConfig:
    """`config` with params overridden by name (validated), e.g. from command-line flags."""
    params = dict(config.params)
    params.update({k: check_param(k, v) for k, v in overrides.items()})
    return PlannerConfig(config.method, config.h, params, config.provenance, config.source)


def load_config(path=None) -> PlannerConfig:
    """Read a planner config TOML (default: the shipped tuned_default.toml), a tuned file
    (stepzoo.tuned_file: what `stepzoo tune` writes; unknown keys refused)."""
    from stepzoo.config_schema import check
    from stepzoo.tuned_file import TunedFile
    path = Path(path) if path is not None else DEFAULT_CONFIG
    data = read_toml(path, "planner config", "give a TOML file written by `stepzoo tune`")
    tuned = check(TunedFile, data, str(path))
    provenance = tuned.provenance if tuned.provenance is not None else (tuned.why or
                                                                        "not stated")
    return make_config(tuned.method, tuned.h, provenance, str(path), **tuned.planner)
