"""A sweep config: a TOML file checked against its declaration (SweepFile: every key with its
type, default, range and doc) and resolved into a frozen `SweepConfig`. Every mistake is one
line naming the key, what is wrong and what to write instead; all mistakes are reported at
once (UsageError, exit 2)."""
from __future__ import annotations

import dataclasses
import math
import re
import typing
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, ConfigDict, Field, PlainSerializer, Tag, model_validator
from pydantic.dataclasses import dataclass

from stepzoo import config_schema
from stepzoo.bench.model import casadi_source as casadi_model
from stepzoo.bench.model.spec import (BICYCLE_ERROR_STATES, Expression, Hook, ModelSpec,
                                      Nested, builtin, check_rhs, flatten, load_function)
from stepzoo.config_schema import BY_SHAPE, Schema, quantity, ranged
from stepzoo.errors import UsageError
from stepzoo.validate import problem, read_toml

# The shared ranges of validate.RANGES, as field types.
Atol = Annotated[float, ranged("atol")]
Growth = Annotated[float, ranged("growth")]
Horizon = Annotated[float, ranged("horizon")]
Perturbation = Annotated[float, ranged("perturbation")]
RelTol = Annotated[float, ranged("rel_tol")]
Rounds = Annotated[int, ranged("rounds")]
Rtol = Annotated[float, ranged("rtol")]
Step = Annotated[float, ranged("step")]
NewtonAtol = Annotated[float, ranged("newton_atol")]
NewtonMaxIter = Annotated[int, ranged("newton_max_iter")]
NewtonMaxIterFull = Annotated[int, ranged("newton_max_iter_full")]
NewtonResTol = Annotated[float, ranged("newton_res_tol")]
NewtonRtol = Annotated[float, ranged("newton_rtol")]

MAX_GRID = 10_000       # values of one grid, or points of an envelope: more is a typo, and
                        # would be allocated before any estimate of the work
# `methods = "..."`: the zoo's methods of one kind. bounded: a finite real stability
# interval (explicit methods, Adams-Moulton), the methods a stiff problem's fast modes bind;
# unbounded: the rest (A- and A(alpha)-stable).
Selector = Literal["all", "explicit", "implicit", "bounded", "unbounded"]
SELECTORS: tuple[str, ...] = typing.get_args(Selector)
# [reference] solver: what computes a reference (the default: dopri5, JAX's adaptive
# Dormand-Prince, for every model but the stiff test problems, which take LSODA); the others
# are SciPy's solve_ivp methods, per distinct lane. Radau IIA (order 5) reaches further
# below LSODA's floor on the stiff problems.
RefSolver = Literal["", "dopri5", "LSODA", "Radau", "BDF", "DOP853"]
REF_SOLVERS: tuple[str, ...] = typing.get_args(RefSolver)
# [error] estimate: which times of a run its error `err` is taken over
Estimate = Literal["max", "final"]
ESTIMATES: dict[Estimate, str] = {
    "max": "the largest scaled error over every step of the run",
    "final": "the scaled error at the end of the horizon (as the Test Set for IVP Solvers "
             "and DiffEqDevTools' error_estimate = :final)"}
# Scaled size of the stability runs' initial deviation. h_pred is a linearised (small-
# deviation) limit, so the deviation stays small through its `growth`: far below the slip
# where a tyre saturates (a large one let saturation cap the growth, and the nonlinear tyres'
# limits came out several times the linear ones in straight running), and well above the
# Newton solves' default tolerances, so their noise is no growth.
DEFAULT_PERTURBATION = 1e-6
# [stability] rule: bench.sweep.runs.stability_runs.MODES_RULE, or metrics.BLOWUP_RULE.
StabilityRule = Literal["modes", "blowup"]
STABILITY_RULES = typing.get_args(StabilityRule)

GridSize = Annotated[int, quantity(
    "a number of grid values", "", "more is a typo, and would be allocated before any estimate "
    "of the work", ge=1, le=MAX_GRID)]
StabSteps = Annotated[int, quantity(
    "", "", "enough steps for a deviation to grow past `growth`; more is minutes per rung of "
    "the limit search", ge=50, le=100_000)]
Fraction = Annotated[float, quantity("a fraction of the predicted largest stable step", "",
                                     "a sample below the limit", gt=0.0, le=1.0)]
PastLimit = Annotated[float, quantity("a multiple of the predicted largest stable step", "",
                                      "the sample that blows up lies past the limit", gt=1.0)]
Scale = Annotated[float, quantity("an error scale", "", "the error norm divides by it", gt=0.0)]
Gib = Annotated[float, quantity("", "GiB", "a limit of memory", gt=0.0)]
Work = Annotated[float, quantity("", "", "a limit of work", gt=0.0)]
Lanes = Annotated[int, quantity("", "", "at least one operating point per batch", ge=1)]


def _distinct(values: tuple) -> tuple:
    """A grid written as a list: at least one value, none twice, at most MAX_GRID."""
    if not values:
        raise ValueError("must list at least one value")
    if len(values) > MAX_GRID:
        raise ValueError(f"lists {len(values)} values; at most {MAX_GRID}")
    if len(set(values)) != len(values):
        raise ValueError("lists a value twice; list each once")
    return values


class Span(Schema):
    """A grid as a table: {values = [...]}, or `num` values from `min` to `max`, evenly
    spaced (log-spaced with log = true)."""
    values: tuple[float, ...] | None = Field(None, description="the values themselves")
    min: float | None = Field(None, description="the first value")
    max: float | None = Field(None, description="the last value, >= min")
    num: GridSize | None = Field(None, description="how many values")
    log: bool = Field(False, description="log-spaced (min > 0) rather than evenly")

    @model_validator(mode="after")
    def _one_form(self):
        given = self.model_fields_set - {"log"}
        if given == {"values"}:
            _distinct(self.values)
        elif given != {"min", "max", "num"}:
            raise ValueError("must be {values = [...]} or {min = ..., max = ..., num = ...}, "
                             f"got the keys {', '.join(sorted(self.model_fields_set))}")
        elif self.min > self.max:
            raise ValueError(f"must be {{min, max, num}} with min <= max, got min {self.min:g} "
                             f"> max {self.max:g}")
        elif self.log and self.min <= 0:
            raise ValueError(f"must be {{min, max, num}} with min > 0 for log spacing, got "
                             f"min {self.min:g}")
        return self

    def grid(self) -> list[float]:
        if self.values is not None:
            return [float(v) for v in self.values]
        assert self.min is not None and self.max is not None and self.num is not None
        spaced = np.geomspace if self.log else np.linspace
        return [float(v) for v in spaced(self.min, self.max, self.num)]


class StepSpan(Span):
    """A grid of steps [s] as a table, log-spaced unless log = false."""
    values: tuple[Step, ...] | None = Field(None, description="the steps themselves [s]")
    min: Step | None = Field(None, description="the smallest step [s]")
    max: Step | None = Field(None, description="the largest step [s], >= min")
    log: bool = Field(True, description="log-spaced rather than evenly")


Grid = Annotated[Annotated[tuple[float, ...], AfterValidator(_distinct), Tag("list")]
                 | Annotated[Span, Tag("table")], BY_SHAPE]
StepGrid = Annotated[Annotated[tuple[Step, ...], AfterValidator(_distinct), Tag("list")]
                     | Annotated[StepSpan, Tag("table")], BY_SHAPE]


def grid_values(grid) -> list[float]:
    """The values of a Grid or StepGrid as written (a list) or spanned (a table)."""
    return grid.grid() if isinstance(grid, Span) else [float(v) for v in grid]


def _known_methods(names: tuple) -> tuple:
    from stepzoo.integrators import METHODS
    if not names:
        raise ValueError("must name at least one method")
    unknown = [m for m in names if m not in METHODS]
    if unknown:
        raise ValueError(f"names unknown method {unknown[0]!r}; known: {', '.join(METHODS)}")
    if len(set(names)) != len(names):
        raise ValueError("lists a name twice; list each once")
    return names


def _names(names: tuple) -> tuple:
    if not all(names):
        raise ValueError("must be names (non-empty strings)")
    if len(set(names)) != len(names):
        raise ValueError("lists a name twice; list each once")
    return names


Names = Annotated[tuple[str, ...], AfterValidator(_names)]


class ModelTable(Schema):
    """Your own model, by one of two keys: `rhs` (a JAX f(t, x, u, p) -> dx/dt) or `casadi`
    (a casadi.Function of x, u, p, or its saved file)."""
    rhs: str | None = Field(None, description='"module:function" of your JAX f(t, x, u, p) '
                            "-> dx/dt; it reads [params] by name")
    casadi: str | None = Field(None, description='"module:function" returning a '
                               "casadi.Function of (x, u, p), or the saved function's file")
    path: str = Field(".", description="the module's folder, relative to the config file")
    states: Names = Field(description="the state names, in the order of x")
    inputs: Names = Field((), description="the input names, in the order of u (constant "
                          "in time)")
    p: Names | None = Field(None, description="with casadi: the entries of the function's p, "
                            "in order, each with a value in [params]")

    @model_validator(mode="after")
    def _one_way(self):
        if self.rhs is not None and self.casadi is not None:
            raise ValueError("model.rhs (a JAX f(t, x, u, p)) and model.casadi are two ways "
                             "to give a model; keep one")
        if self.p is not None and self.rhs is not None:
            raise ValueError("model.p names the entries of a CasADi function's p "
                             "(model.casadi); a JAX model.rhs reads [params] by name: drop "
                             "model.p")
        if self.rhs is None and self.casadi is None:
            raise ValueError('model.rhs must be "module:function" (your f(t, x, u, p)), or '
                             "give model.casadi")
        if not self.states:
            raise ValueError("model.states must name at least one state")
        return self


class Steps(Schema):
    """[steps]: the grid of step sizes of the accuracy runs."""
    h: StepGrid = Field(description="step sizes [s]: a list, or {min, max, num} (log-spaced); "
                        "each snapped to horizon/n so that a run ends at the horizon")


class Reference(Schema):
    """[reference]: what the runs' errors are measured against."""
    rtol: Rtol = Field(1e-10, description="relative tolerance of the adaptive reference")
    atol: Atol = Field(1e-12, description="absolute tolerance of the adaptive reference")
    exact: bool = Field(False, description="the model's closed form as the reference (a "
                        "built-in test problem that has one, at its own published problem)")
    solver: RefSolver = Field(
        "", description='the reference\'s solver: "" the model\'s default (dopri5, LSODA for '
        "a stiff test problem), or one of SciPy's solve_ivp methods")


class Stability(Schema):
    """[stability]: the search for each method's largest stable step per operating point."""
    steps: StabSteps = Field(1000, description="blowup: steps of one stability run (the "
                             "modes rule's runs last the stability horizon)")
    growth: Growth = Field(100.0, description="blow-up: the scaled deviation grown past this "
                           "many times its start")
    perturbation: Perturbation = Field(DEFAULT_PERTURBATION, description="scaled size of the "
                                       "initial deviation (small: h_pred is a linearised limit)")
    h_probe_max: Step = Field(2.0, description="largest step probed for a blow-up [s]; at "
                              "least the largest of steps.h")
    rel_tol: RelTol = Field(1e-3, description="the bisection of the largest stable step stops "
                            "when h_hi / h_lo - 1 <= rel_tol")
    rule: StabilityRule = Field(
        "modes", description="modes: every state, each eigenmode alone, against the "
        "reference's own growth, within the stability horizon (what a stiff, saturating "
        "model needs); blowup: the error states, the modes summed, `steps` steps (a smooth "
        "model whose error states read its fast modes)")
    horizon: Horizon | None = Field(None, description="modes: how long a stability run lasts "
                                    "[s] (default: the accuracy horizon); events after it "
                                    "decide nothing")


class Chunks(Schema):
    """[chunks]: how the operating points are batched."""
    points: Lanes = Field(25, description="operating points per chunk (one batch, one "
                          "resumable unit of work)")


class ErrorNorm(Schema):
    """[error]: the norm a run's error is measured in."""
    states: Names | None = Field(None, description="the states the norm reads (default: a "
                                 "built-in bicycle's vy and r, else every state)")
    scales: tuple[Scale, ...] | None = Field(None, description="one scale per error state, "
                                             "the norm's divisor (default 1)")
    estimate: Estimate = Field(
        "max", description="max: the largest scaled error over every step; final: at the "
        "horizon")


class Limits(Schema):
    """[limits]: what the sweep may allocate and integrate before it refuses; they decide no
    result."""
    memory_gib: Gib | None = Field(None, description="trajectory memory [GiB] (default: "
                                        "half the machine's)")
    steps: Work | None = Field(None, description="integration steps summed over "
                                   "trajectories (default 1e11)")


class Trajectories(Schema):
    """[trajectories]: the sample trajectories the report draws, at one operating point;
    besides `fractions` and `past_limit`, any envelope variable = its value there (default:
    the envelope's first value)."""
    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, float] = Field(init=False)
    fractions: tuple[Fraction, ...] = Field((0.2, 0.5, 0.9), min_length=1, description="sample "
                                            "steps, as fractions of the predicted limit")
    past_limit: PastLimit = Field(1.5, description="the sample past the limit, as a multiple "
                                  "of it")


class ParamTable(Schema):
    """[params.<name>]: a nested table of parameters (as simulators ship them); each key is
    named "<name>.<key>" in [envelope], [initial] expressions and the tables, and a model
    module's f reads it as p["<name>"]["<key>"]."""
    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, float | ParamTable] = Field(init=False)


ParamTable.model_rebuild()


def _plain_params(params: dict) -> dict:
    """[params] as plain nested dicts of numbers."""
    return {k: _plain_params(v.model_extra or {}) if isinstance(v, ParamTable) else v
            for k, v in params.items()}


# A "module:function" hook (an initial state computed by the user's code), not an expression.
HOOK = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


class Envelope(Schema):
    """[envelope]: the operating grid: any parameter, input or initial state by name = its
    values (a list, or {min, max, num}); every combination of the values is an operating
    point."""
    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, Grid] = Field(init=False)
    x0: tuple[float, ...] | None = Field(None, description="the whole initial state, one value "
                                         "per state (the bicycle configs' form of [initial])")


class Timing(Schema):
    """[timing]: how each accuracy run is timed."""
    rounds: Rounds = Field(5, description="timed repeats of each accuracy run after its "
                           "compilation")


class Newton(Schema):
    """[newton]: the implicit methods' Newton solves (integrators.newton.NewtonOptions)."""
    rtol: NewtonRtol = Field(1e-10, description="relative tolerance on the stage values")
    atol: NewtonAtol = Field(1e-10, description="absolute tolerance on the stage values")
    res_tol: NewtonResTol = Field(1.0, description="residual tolerance, times the residual "
                                  "an error within tolerance makes")
    max_iter: NewtonMaxIter = Field(10, description="simplified Newton iterations per solve")
    max_iter_full: NewtonMaxIterFull = Field(40, description="full Newton iterations of the "
                                             "retry (0: none)")

    @model_validator(mode="after")
    def _some_tolerance(self):
        if self.rtol == 0 and self.atol == 0:
            raise ValueError("newton.rtol and newton.atol are both 0; give one > 0")
        return self


class SweepFile(Schema):
    """A sweep config file: one model, its operating envelope, the methods and steps."""
    name: str | None = Field(None, description="the sweep's name (default: the file's stem)")
    model: Annotated[Annotated[str, Tag("value")] | Annotated[ModelTable, Tag("table")],
                     BY_SHAPE] = Field(
        "dynamic5", description="a built-in model by name, or a [model] table of your own")
    tyre: str | None = Field(None, description="the tyre law of a built-in dynamic bicycle")
    vehicle: str | None = Field(None, description="a vehicle set of dynamics/vehicles.toml "
                                "(default: the default vehicle)")
    horizon: Horizon = Field(description="length of the accuracy runs [s]")
    methods: Annotated[Annotated[Selector, Tag("value")]
                       | Annotated[tuple[str, ...], AfterValidator(_known_methods), Tag("list")],
                       BY_SHAPE] = Field(
        "all", description="the zoo's method names, or a kind: " + ", ".join(SELECTORS))
    params: dict[str, float | ParamTable] = Field({}, description="parameter values by "
                                                  "name, over the model's own; a nested "
                                                  "table is named with dots (tyre.r_w)")
    initial: dict[str, float | str] = Field({}, description="initial state values by name: a "
                                            "number, an expression of the other states, "
                                            'inputs and parameters ("vx / tyre.r_w"; + - * / '
                                            "**, sqrt, exp, log, sin, cos, tan, atan, atan2, "
                                            'hypot, abs, min, max, pi), or "module:function", '
                                            "the user's function of them all (NumPy arrays "
                                            "over the operating points, by name)")
    envelope: Envelope = Field(Envelope(), description="the operating grid")
    error: ErrorNorm = Field(ErrorNorm(), description="the error norm")
    steps: Steps = Field(description="the step sizes")
    reference: Reference = Field(Reference(), description="the reference solution")
    limits: Limits = Field(Limits(), description="what the sweep may allocate and integrate")
    stability: Stability = Field(Stability(), description="the search for the largest stable "
                                 "step")
    chunks: Chunks = Field(Chunks(), description="the batches of operating points")
    trajectories: Trajectories = Field(Trajectories(), description="the sample trajectories")
    timing: Timing = Field(Timing(), description="the timing of the accuracy runs")
    newton: Newton = Field(Newton(), description="the implicit methods' Newton solves")


def _default(table: type[Schema], key: str):
    """The declared default of one key of a config table: the resolved config's default is
    the file's."""
    return table.model_fields[key].default


@dataclass(frozen=True, kw_only=True, config=ConfigDict(arbitrary_types_allowed=True,
                                                         extra="forbid"))
class SweepConfig:
    """A validated sweep, built by keyword. Step sizes are snapped to horizon/n (whole steps,
    each run ends at the horizon) and sorted; the operating points are every combination of
    the envelope's values (`spec.points`, the first variable slowest). Its sha256 is over the
    values that differ from the defaults (config_schema.sha256)."""
    name: str
    model: str                     # built-in name, or "module:function" of a user's model
    vehicle: str
    horizon: float                 # [s] of the accuracy runs
    methods: tuple[str, ...]
    spec: Annotated[ModelSpec, PlainSerializer(lambda s: s.canonical())]
    hs: tuple[float, ...]          # [s], ascending
    traj_point: tuple[float, ...]  # one value per envelope variable: the sample trajectories'
    rtol: float = _default(Reference, "rtol")
    atol: float = _default(Reference, "atol")
    stab_steps: int = _default(Stability, "steps")      # steps of one stability run
    growth: float = _default(Stability, "growth")       # blow-up threshold, scaled deviation
    perturbation: float = _default(Stability, "perturbation")
    h_probe_max: float = _default(Stability, "h_probe_max")    # [s] largest step probed
    rel_tol: float = _default(Stability, "rel_tol")     # bisection: h_hi / h_lo - 1 <= rel_tol
    stab_rule: str = _default(Stability, "rule")        # a key of STABILITY_RULES
    stab_horizon: float | None = _default(Stability, "horizon")   # [s] None: `horizon`
    points_per_chunk: int = _default(Chunks, "points")
    traj_fractions: tuple[float, ...] = _default(Trajectories, "fractions")
    traj_past_limit: float = _default(Trajectories, "past_limit")
    timing_rounds: int = _default(Timing, "rounds")     # timed repeats of each accuracy run
    exact_reference: bool = _default(Reference, "exact")
    error_estimate: Estimate = _default(ErrorNorm, "estimate")    # a key of ESTIMATES
    ref_solver: RefSolver = _default(Reference, "solver")     # "": the model's default
    newton: Newton = Newton()      # the implicit methods' solve options ([newton])
    # What decides no result: the file's path and [limits] (what the sweep may allocate
    # [GiB] and integrate) are not part of the config's identity.
    source: Annotated[str, Field(exclude=True)] = dataclasses.field(default="", compare=False)
    max_memory_gib: Annotated[float | None, Field(exclude=True)] = dataclasses.field(
        default=None, compare=False)
    max_steps: Annotated[float | None, Field(exclude=True)] = dataclasses.field(
        default=None, compare=False)

    @property
    def points(self) -> list[tuple]:
        return self.spec.points

    def values(self, var: str) -> tuple:
        """The envelope's values of one variable."""
        return dict(self.spec.envelope)[var]

    def canonical(self) -> dict:
        """What decides the results and differs from the defaults (what sha256 is over)."""
        return config_schema.differing(self)

    @property
    def sha256(self) -> str:
        return config_schema.sha256(self)

    @property
    def stability_horizon(self) -> float:
        """How long a stability run of the "modes" rule lasts [s]."""
        return self.horizon if self.stab_horizon is None else self.stab_horizon

    @property
    def newton_options(self) -> dict:
        """Every option of the implicit methods' Newton solves: [newton] over the defaults."""
        return self.newton.model_dump()

    def method(self, name: str):
        """The zoo's method `name` with this sweep's [newton] options (the same Method for
        every call in a process: one compilation)."""
        from stepzoo.integrators import method
        from stepzoo.integrators.newton import NewtonOptions
        given = config_schema.differing(self.newton)
        return method(name, NewtonOptions(**self.newton.model_dump()) if given else None)


def load(path) -> SweepConfig:
    """Read and validate a sweep TOML; UsageError (one line per mistake) if it is wrong."""
    raw = read_toml(path, "sweep config", "give a TOML file such as bench/configs/small.toml")
    check_one_problem(raw, path)
    return validate(raw, str(path))


def check_one_problem(raw: dict, path):
    """UsageError when the config is a suite ([[problem]] tables), which only `stepzoo sweep`
    runs; the commands that take one model's config call this."""
    if "problem" in raw:
        raise UsageError(f"{path} is a suite of {len(raw['problem'])} problems ([[problem]] "
                         "tables): `stepzoo sweep` runs it whole; this command takes one "
                         "problem: the config.toml in that problem's folder of the suite's "
                         "sweep, or a config of one model")


def validate(raw: dict, source: str = "config") -> SweepConfig:
    """The sweep of a config's table: its keys checked against SweepFile, then against each
    other and the model (UsageError, one line per mistake)."""
    f = config_schema.check(SweepFile, raw, source)
    bad: list[str] = []
    spec, vehicle = model_spec(f, source, bad)
    methods = selected(f.methods) if isinstance(f.methods, str) else list(f.methods)
    hs = grid_values(f.steps.h)
    if max(hs) > f.horizon:
        bad.append(f"steps.h reaches {max(hs):g} s, past the horizon {f.horizon:g} s; keep "
                   "every step <= horizon")
    hs = sorted({f.horizon / max(1, round(f.horizon / h)) for h in hs})
    exact, solver = f.reference.exact, f.reference.solver
    if exact and spec is not None:
        exact = closed_form_problem(spec, bad)
    if spec is not None and (exact or solver == default_solver(spec)):
        solver = ""       # the default, or unused: the same results, the same sha256
    if f.stability.h_probe_max < max(hs):
        bad.append(f"stability.h_probe_max ({f.stability.h_probe_max:g} s) is below the "
                   f"largest step ({max(hs):g} s); raise it")
    if "steps" in f.stability.model_fields_set and f.stability.rule == "modes":
        bad.append("stability.steps counts the \"blowup\" rule's steps; the \"modes\" rule "
                   "(the default) runs to the stability horizon: set stability.rule = "
                   "\"blowup\", or drop stability.steps (and set stability.horizon)")
    if f.stability.horizon is not None and f.stability.rule == "blowup":
        bad.append("stability.horizon is the length of the \"modes\" rule's runs; the "
                   "\"blowup\" rule runs stability.steps steps: set stability.rule = "
                   "\"modes\" or drop stability.horizon")
    traj_point = trajectory_point(f.trajectories, spec, bad)
    if exact and spec is not None and traj_point not in spec.points:
        bad.append("reference.exact solves the model's own problem alone; leave "
                   "[trajectories] at the envelope's values")
    if not bad and spec is not None:
        check_rhs(spec, source)
    if bad or spec is None:               # no spec: model_spec said why in bad
        raise UsageError("\n".join(f"{source}: {line}" for line in bad))
    return SweepConfig(
        name=f.name if f.name is not None else Path(source).stem, model=spec.name,
        vehicle=vehicle, horizon=f.horizon, methods=tuple(methods), spec=spec, hs=tuple(hs),
        traj_point=traj_point, rtol=f.reference.rtol, atol=f.reference.atol,
        stab_steps=f.stability.steps, growth=f.stability.growth,
        perturbation=f.stability.perturbation, h_probe_max=f.stability.h_probe_max,
        rel_tol=f.stability.rel_tol, stab_rule=f.stability.rule,
        stab_horizon=f.stability.horizon, points_per_chunk=f.chunks.points,
        traj_fractions=f.trajectories.fractions, traj_past_limit=f.trajectories.past_limit,
        timing_rounds=f.timing.rounds, exact_reference=exact, error_estimate=f.error.estimate,
        ref_solver=solver, newton=f.newton, source=source, max_memory_gib=f.limits.memory_gib,
        max_steps=f.limits.steps)


def trajectory_point(traj: Trajectories, spec: ModelSpec | None, bad: list) -> tuple:
    """The sample trajectories' operating point: [trajectories]' value of each envelope
    variable, else the envelope's first."""
    if spec is None:
        return ()
    given = traj.model_extra or {}
    for key in sorted(set(given) - set(spec.variables)):
        bad.append(f"unknown key trajectories.{key}; known: fractions, past_limit and the "
                   f"envelope's variables ({', '.join(spec.variables)})")
    return tuple(float(given.get(var, values[0])) for var, values in spec.envelope)


def default_solver(spec: ModelSpec) -> str:
    """The reference's solver where reference.solver is not given: LSODA for a stiff test
    problem, else dopri5."""
    return "LSODA" if spec.stiff else "dopri5"


def closed_form_problem(spec: ModelSpec, bad: list) -> bool:
    """Whether the references may be `spec`'s closed form: a built-in test problem that has
    one, at its own default problem (initial state, inputs, parameters) in every operating
    point, since the closed form solves that problem alone; appends to `bad` if not."""
    from stepzoo import dynamics
    m = dynamics.MODELS.get(spec.name)
    if m is None or m.exact is None or m.vehicle_params is not None:
        bad.append(f"reference.exact needs a built-in test problem with a closed form; "
                   f"{spec.name} has none (set reference.exact = false)")
        return False
    x0, u, p = spec.arrays(spec.points)
    own = bool((x0 == np.asarray(m.x0, float)).all() and (u == np.asarray(m.u0, float)).all()
               and all((p[k] == v).all() for k, v in m.params().items()))
    if not own:
        bad.append(f"reference.exact solves {spec.name}'s own problem alone; keep "
                   "[envelope], [initial] and [params] at its published values")
    return own


def model_spec(f: SweepFile, source: str, bad: list) -> tuple[ModelSpec | None, str]:
    """(the config's model, the vehicle set name) from `model`, [params], [initial],
    [envelope] and [error]; appends to `bad` and returns None for the model when wrong."""
    from stepzoo import dynamics
    before = len(bad)
    vehicle = f.vehicle if f.vehicle is not None else dynamics.default_vehicle()
    if vehicle not in dynamics.vehicle_names():
        bad.append(f"unknown vehicle {vehicle!r}; known: {', '.join(dynamics.vehicle_names())}")
        vehicle = dynamics.default_vehicle()
    sha, stiff, folder, model = "", False, "", f.model
    given = flatten(_plain_params(f.params))
    if isinstance(model, str):
        if model not in dynamics.MODELS:
            bad.append(f"unknown model {model!r}; known: {', '.join(dynamics.MODELS)} (or a "
                       "[model] table naming your own rhs = \"module:function\")")
            return None, vehicle
        name = model
        try:
            rhs, states, inputs, params, initial, kinds, stiff = builtin(model, vehicle, f.tyre)
        except KeyError as err:
            bad.append(err.args[0])
            return None, vehicle
    else:
        if f.tyre is not None:
            bad.append("tyre is an option of the built-in dynamic bicycles; your own model "
                       "sets its tyres itself")
            return None, vehicle
        function = model.casadi if model.casadi is not None else model.rhs
        assert function is not None       # ModelTable._one_way: one of the two is given
        name = function
        states, inputs = model.states, model.inputs
        folder = str((Path(source).resolve().parent / model.path).resolve())
        try:
            if model.casadi is not None:
                said: list[str] = []
                p_names = casadi_model.check_p(list(model.p or ()), given, source, said)
                bad.extend(line.removeprefix(f"{source}: ") for line in said)
                if len(bad) > before:
                    return None, vehicle
                rhs, sha = casadi_model.load(name, Path(folder), states, inputs, p_names,
                                             source)
            else:
                rhs, sha = load_function(name, Path(folder), source)
                if any("." in k for k in given):
                    rhs = Nested(rhs)          # the module reads its tables nested
        except UsageError as err:
            bad.append(str(err).removeprefix(f"{source}: "))
            return None, vehicle
        params, initial, kinds = {}, dict.fromkeys([*states, *inputs], 0.0), {}
    params.update(given)
    if f.envelope.x0 is not None:
        if len(f.envelope.x0) != len(states):
            bad.append(f"envelope.x0 must be {len(states)} finite numbers "
                       f"[{', '.join(states)}]")
        else:
            initial.update(zip(states, f.envelope.x0))
    derived = {}
    for key, value in f.initial.items():
        if key not in states:
            bad.append(f"initial.{key} is not a state; states: {', '.join(states)}")
        elif isinstance(value, str):
            derived[key] = value
        else:
            initial[key] = value
    known = set(states) | set(inputs) | set(params)
    derive = _derive(derived, known, folder or str(Path(source).resolve().parent), source, bad)
    envelope = []
    for var, grid in (f.envelope.model_extra or {}).items():
        if var not in known:
            bad.append(f"envelope.{var} is not a parameter, input or state of {name}; "
                       f"known: {', '.join(sorted(known))}")
            continue
        if var in derived:
            bad.append(f"envelope.{var} varies a state that initial.{var} computes; keep one "
                       "of the two")
            continue
        values = grid_values(grid)
        kind = kinds.get(var)
        wrong = kind and next(filter(None, (problem(kind, f"every envelope.{var}", v)
                                            for v in values)), None)
        if wrong:
            bad.append(wrong)
            continue
        envelope.append((var, tuple(values)))
    n_points = math.prod(len(vals) for _, vals in envelope)
    if n_points > MAX_GRID:
        bad.append(f"the envelope has {' x '.join(str(len(v)) for _, v in envelope)} "
                   f"operating points; at most {MAX_GRID}")
    if not envelope and len(bad) == before:
        bad.append("[envelope] names no variable; give at least one parameter, input or "
                   "initial state with its values")
    error_states = f.error.states
    if error_states is None:
        error_states = BICYCLE_ERROR_STATES if name == "dynamic5" else states
    elif not set(error_states) <= set(states):
        bad.append(f"error.states must be a non-empty list of state names; states: "
                   f"{', '.join(states)}")
        error_states = states
    scales = f.error.scales if f.error.scales is not None else (1.0,) * len(error_states)
    if len(scales) != len(error_states) and len(bad) == before:
        bad.append(f"error.scales must be one number > 0 per error state "
                   f"({len(error_states)})")
    if len(bad) > before:
        return None, vehicle
    spec = ModelSpec(name, rhs, tuple(states), tuple(inputs),
                     tuple((k, float(v)) for k, v in params.items()),
                     tuple(float(initial[s]) for s in states),
                     tuple(float(initial[s]) for s in inputs), tuple(envelope),
                     tuple(error_states), tuple(float(s) for s in scales), stiff,
                     f.tyre, sha, folder, tuple(derived.items()), tuple(derive))
    return _check_derived(spec, bad), vehicle


def _derive(derived: dict, known: set, folder: str, source: str, bad: list) -> list:
    """The evaluators (model_spec.Expression or Hook) of the initial states given as text,
    in order; each may read the states, inputs and parameters, but no state computed after
    it (nor itself). Appends to `bad` when one cannot be had."""
    from stepzoo.bench.model.spec import import_user_module
    out: list[Hook | Expression] = []
    later = set(derived)
    for key, text in derived.items():
        later.discard(key)
        if HOOK.match(text):
            module, _, func = text.partition(":")
            try:
                fn = getattr(import_user_module(module, Path(folder), source,
                                                f"initial.{key}"), func, None)
            except UsageError as err:
                bad.append(str(err).removeprefix(f"{source}: "))
                continue
            if not callable(fn):
                bad.append(f"initial.{key} = {text!r}: {module} has no function {func!r}")
                continue
            out.append(Hook(fn))
            continue
        try:
            expr = Expression(text)
        except ValueError as err:
            bad.append(f"initial.{key} = {text!r} {err}; write an arithmetic expression of "
                       "states, inputs and parameters, or \"module:function\"")
            continue
        unknown = sorted(expr.names - known)
        ahead = sorted(expr.names & (later | {key}))
        if unknown:
            bad.append(f"initial.{key} = {text!r} names {', '.join(unknown)}, not a state, "
                       f"input or parameter; known: {', '.join(sorted(known))}")
        elif ahead:
            bad.append(f"initial.{key} = {text!r} reads {', '.join(ahead)}, computed at or "
                       f"after it; list initial.{ahead[0]} before initial.{key}")
        else:
            out.append(expr)
    return out


def _check_derived(spec: ModelSpec, bad: list) -> ModelSpec | None:
    """The spec, or None (with a line in `bad`) when an initial state it computes fails or is
    not finite at some operating point."""
    if not spec.derived:
        return spec
    try:
        with np.errstate(all="ignore"):
            x0, _, _ = spec.arrays(spec.points)
    except Exception as err:     # the user's hook or a bad shape: one line, not a traceback
        bad.append(f"the initial states computed by [initial] ({', '.join(dict(spec.derived))})"
                   f" fail: {type(err).__name__}: {err}")
        return None
    for state, text in spec.derived:
        col = x0[:, spec.states.index(state)]
        if not np.isfinite(col).all():
            at = spec.points[int(np.argmin(np.isfinite(col)))]
            where = ", ".join(f"{v} = {a:g}" for v, a in zip(spec.variables, at))
            bad.append(f"initial.{state} = {text!r} is not finite at {where}; keep it finite "
                       "over the envelope")
            return None
    return spec


def check_workload(cfg: SweepConfig, what: str | None = None):
    """UsageError (the estimate and the limit) if the sweep (or `what`, a run of the sweep's
    kind on `cfg`) would hold more trajectory memory or integrate more steps than allowed
    ([limits], --max-memory, --max-steps)."""
    from stepzoo.validate import GIB, check_budget
    lanes = min(cfg.points_per_chunk, len(cfg.points))
    steps = run_steps(cfg) + 1                                           # every call's length
    blocks = -(-len(cfg.points) // cfg.points_per_chunk)
    # Per method and block, calls of one block's lanes: the accuracy runs at every step; for
    # stability a pair of runs (perturbed, unperturbed) a call apart, per grid step, per rung
    # of the ladders past the grid (at most ten) and per narrowing round (a bisection's at
    # most, from a bracket of 1.3). The pair's two trajectory arrays are held at once. The
    # "modes" rule runs one unperturbed and MODES + d perturbed runs per candidate, and also
    # probes its ladder of multiples of h_pred.
    from stepzoo.bench.sweep.limit_search import PRED_LADDER
    from stepzoo.bench.sweep.runs.stability_runs import MODES
    rounds = math.ceil(math.log2(math.log(1.3) / math.log1p(cfg.rel_tol))) + 1
    per, probes = (2, 0) if cfg.stab_rule == "blowup" else \
        (MODES + len(cfg.spec.states) + 1, len(PRED_LADDER))
    calls = len(cfg.hs) + per * (len(cfg.hs) + 10 + rounds + probes)
    memory = cfg.max_memory_gib and cfg.max_memory_gib * GIB
    check_budget(what or f"the sweep {cfg.name!r}", steps, 2 * lanes, len(cfg.spec.states),
                 calls=len(cfg.methods) * blocks * calls / 2,
                 memory=memory, max_steps=cfg.max_steps)


def run_steps(cfg: SweepConfig) -> int:
    """The steps of a sweep's longest call: the accuracy run at the smallest step, or a
    stability run (`stability.steps`, or the stability horizon at the smallest step)."""
    stab = cfg.stab_steps if cfg.stab_rule == "blowup" else \
        math.ceil(cfg.stability_horizon / cfg.hs[0] - 1e-9)
    return max(round(cfg.horizon / cfg.hs[0]), stab)


def selected(kind: str) -> list[str]:
    """The names of the zoo's methods of one of the SELECTORS kinds, in the zoo's order."""
    from stepzoo.integrators import METHODS
    from stepzoo.integrators.stability import stability_intervals

    def keep(m) -> bool:
        if kind in ("explicit", "implicit"):
            return m.implicit == (kind == "implicit")
        if kind in ("bounded", "unbounded"):
            return math.isfinite(stability_intervals(m)[0]) == (kind == "bounded")
        return True
    return [name for name, m in METHODS.items() if keep(m)]
