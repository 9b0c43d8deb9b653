"""A sweep config: a TOML file checked against its declaration (SweepConfig and its tables:
every key with its type, default, range and doc), then resolved, each table by code beside it
(the steps snapped, the trajectories' operating point, the reference's solver; the model by
bench.sweep.model_table). Every mistake is one line naming the key, what is wrong and what to
write instead; all mistakes are reported at once (UsageError, exit 2)."""
from __future__ import annotations

import hashlib
import json
import math
import typing
from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, ConfigDict, Field, PrivateAttr, Tag, model_validator
from pydantic_core import to_jsonable_python

from stepzoo import config_schema
from stepzoo.bench.model.spec import ModelSpec, check_rhs
from stepzoo.bench.sweep.grids import Step, StepGrid, grid_values
from stepzoo.bench.sweep.model_table import (Envelope, ModelTable, Names, ParamTable,
                                             closed_form_problem, default_solver, model_spec)
from stepzoo.config_schema import BY_SHAPE, Schema, quantity, ranged
from stepzoo.errors import UsageError
from stepzoo.validate import read_toml

# The shared ranges of validate.RANGES, as field types.
Atol = Annotated[float, ranged("atol")]
Growth = Annotated[float, ranged("growth")]
Horizon = Annotated[float, ranged("horizon")]
Perturbation = Annotated[float, ranged("perturbation")]
RelTol = Annotated[float, ranged("rel_tol")]
Rounds = Annotated[int, ranged("rounds")]
Rtol = Annotated[float, ranged("rtol")]
NewtonAtol = Annotated[float, ranged("newton_atol")]
NewtonMaxIter = Annotated[int, ranged("newton_max_iter")]
NewtonMaxIterFull = Annotated[int, ranged("newton_max_iter_full")]
NewtonResTol = Annotated[float, ranged("newton_res_tol")]
NewtonRtol = Annotated[float, ranged("newton_rtol")]

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


class Steps(Schema):
    """[steps]: the grid of step sizes of the accuracy runs."""
    h: StepGrid = Field(description="step sizes [s]: a list, or {min, max, num} (log-spaced); "
                        "each snapped to horizon/n so that a run ends at the horizon")

    def snapped(self, horizon: float) -> Steps:
        """The grid resolved: each step snapped to horizon/n (whole steps, each run ends at
        the horizon [s]), each once, ascending."""
        hs = sorted({horizon / max(1, round(horizon / h)) for h in grid_values(self.h)})
        return self.model_copy(update={"h": tuple(hs)})

class Reference(Schema):
    """[reference]: what the runs' errors are measured against."""
    rtol: Rtol = Field(1e-10, description="relative tolerance of the adaptive reference")
    atol: Atol = Field(1e-12, description="absolute tolerance of the adaptive reference")
    exact: bool = Field(False, description="the model's closed form as the reference (a "
                        "built-in test problem that has one, at its own published problem)")
    solver: RefSolver = Field(
        "", description='the reference\'s solver: "" the model\'s default (dopri5, LSODA for '
        "a stiff test problem), or one of SciPy's solve_ivp methods")


    def resolved(self, spec: ModelSpec | None, bad: list) -> Reference:
        """The reference resolved for `spec`: `exact` only where the model's closed form
        solves its problem (else a line in `bad`), and `solver` "" where it is the model's
        default or unused (the same results, the same sha256)."""
        exact, solver = self.exact, self.solver
        if exact and spec is not None:
            exact = closed_form_problem(spec, bad)
        if spec is not None and (exact or solver == default_solver(spec)):
            solver = ""
        return self.model_copy(update={"exact": exact, "solver": solver})

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
    the envelope's first value). Resolved, it holds every envelope variable, in order."""
    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[str, float] = Field(init=False)
    fractions: tuple[Fraction, ...] = Field((0.2, 0.5, 0.9), min_length=1, description="sample "
                                            "steps, as fractions of the predicted limit")
    past_limit: PastLimit = Field(1.5, description="the sample past the limit, as a multiple "
                                  "of it")

    @property
    def point(self) -> tuple[float, ...]:
        """The operating point of the resolved table: one value per envelope variable."""
        return tuple(float(v) for v in (self.model_extra or {}).values())

    def at(self, point: dict[str, float]) -> Trajectories:
        """This table at another operating point (envelope variable -> value, in order)."""
        values: dict[str, typing.Any] = {var: float(v) for var, v in point.items()}
        return type(self).model_construct(fractions=self.fractions, past_limit=self.past_limit,
                                          **values)

    def resolved(self, spec: ModelSpec | None, bad: list) -> Trajectories:
        """The table at its operating point: [trajectories]' value of each envelope variable
        of `spec`, else the envelope's first; an unknown key is a line in `bad`."""
        if spec is None:
            return self.at({})
        given = self.model_extra or {}
        for key in sorted(set(given) - set(spec.variables)):
            bad.append(f"unknown key trajectories.{key}; known: fractions, past_limit and the "
                       f"envelope's variables ({', '.join(spec.variables)})")
        return self.at({var: given.get(var, values[0]) for var, values in spec.envelope})


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


# The fingerprint's names: the settings that decide results (those of [model], [params],
# [initial], [envelope] and [error]'s states and scales are in the model spec), each by the
# name a config's sha256 has been taken over since results folders recorded it (a stored
# folder's config_sha256 must stay its config's); over its value where that is not the
# default.
FINGERPRINT = {"rtol": ("reference", "rtol"), "atol": ("reference", "atol"),
               "stab_steps": ("stability", "steps"), "growth": ("stability", "growth"),
               "perturbation": ("stability", "perturbation"),
               "h_probe_max": ("stability", "h_probe_max"), "rel_tol": ("stability", "rel_tol"),
               "stab_rule": ("stability", "rule"), "stab_horizon": ("stability", "horizon"),
               "points_per_chunk": ("chunks", "points"),
               "traj_fractions": ("trajectories", "fractions"),
               "traj_past_limit": ("trajectories", "past_limit"),
               "timing_rounds": ("timing", "rounds"), "exact_reference": ("reference", "exact"),
               "error_estimate": ("error", "estimate"), "ref_solver": ("reference", "solver")}


class SweepConfig(Schema):
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
    # Resolved by validate(): the model with its operating points, and the file it came from.
    _spec: ModelSpec = PrivateAttr()
    _source: str = PrivateAttr("")

    @property
    def spec(self) -> ModelSpec:
        """The model, its envelope and error norm, resolved (bench.sweep.model_table)."""
        return self._spec

    @property
    def source(self) -> str:
        """The config file's path ("" where none); it decides no result."""
        return self._source

    @property
    def hs(self) -> tuple[float, ...]:
        """The resolved step sizes [s], ascending (Steps.snapped)."""
        return tuple(grid_values(self.steps.h))

    @property
    def points(self) -> list[tuple]:
        return self.spec.points

    def values(self, var: str) -> tuple:
        """The envelope's values of one variable."""
        return dict(self.spec.envelope)[var]

    def changed(self, spec: ModelSpec | None = None, source: str | None = None,
                **changes) -> SweepConfig:
        """A copy with `changes`: a table given as a dict changes only the keys it names
        (stability={"rule": "modes"}); `spec` replaces the model, `source` the file."""
        update = {key: getattr(self, key).model_copy(update=value)
                  if isinstance(value, dict) and isinstance(getattr(self, key), Schema)
                  else value for key, value in changes.items()}
        out = self.model_copy(update=update)
        if spec is not None:
            out._spec = spec
        if source is not None:
            out._source = source
        return out

    def __eq__(self, other) -> bool:
        """Equal where they decide the same results (the file's path and [limits] decide
        none)."""
        return isinstance(other, SweepConfig) and self.canonical() == other.canonical()

    def __hash__(self) -> int:
        return hash(self.sha256)

    def canonical(self) -> dict:
        """What decides the results, as JSON-ready data (what sha256 is over): the sweep's
        identity, and each setting of FINGERPRINT and [newton] that differs from its
        default."""
        flat: dict = {"name": self.name, "model": self.spec.name, "vehicle": self.vehicle,
                      "horizon": self.horizon, "methods": self.methods,
                      "spec": self.spec.canonical(), "hs": self.hs,
                      "traj_point": self.trajectories.point}
        for key, (table, field) in FINGERPRINT.items():
            part = getattr(self, table)
            value = getattr(part, field)
            if value != type(part).model_fields[field].default:
                flat[key] = value
        newton = config_schema.differing(self.newton)
        if newton:
            flat["newton"] = newton
        return to_jsonable_python(flat)

    @property
    def sha256(self) -> str:
        """The hex sha256 of canonical() as canonical JSON (sorted keys, no spaces)."""
        text = json.dumps(self.canonical(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    @property
    def stability_horizon(self) -> float:
        """How long a stability run of the "modes" rule lasts [s]."""
        return self.horizon if self.stability.horizon is None else self.stability.horizon

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
    """The sweep of a config's table: its keys checked against SweepConfig, then against each
    other and the model (UsageError, one line per mistake), and resolved: its name, vehicle,
    methods, steps, reference and trajectories as the sweep runs them, and its model."""
    f = config_schema.check(SweepConfig, raw, source)
    bad: list[str] = []
    spec, vehicle = model_spec(f, source, bad)
    methods = selected(f.methods) if isinstance(f.methods, str) else list(f.methods)
    grid = grid_values(f.steps.h)
    if max(grid) > f.horizon:
        bad.append(f"steps.h reaches {max(grid):g} s, past the horizon {f.horizon:g} s; keep "
                   "every step <= horizon")
    steps = f.steps.snapped(f.horizon)
    hs = grid_values(steps.h)
    reference = f.reference.resolved(spec, bad)
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
    trajectories = f.trajectories.resolved(spec, bad)
    if reference.exact and spec is not None and trajectories.point not in spec.points:
        bad.append("reference.exact solves the model's own problem alone; leave "
                   "[trajectories] at the envelope's values")
    if not bad and spec is not None:
        check_rhs(spec, source)
    if bad or spec is None:               # no spec: model_spec said why in bad
        raise UsageError("\n".join(f"{source}: {line}" for line in bad))
    cfg = f.model_copy(update={
        "name": f.name if f.name is not None else Path(source).stem, "vehicle": vehicle,
        "methods": tuple(methods), "steps": steps, "reference": reference,
        "trajectories": trajectories})
    cfg._spec, cfg._source = spec, source
    return cfg


def check_workload(cfg: SweepConfig, what: str | None = None):
    """UsageError (the estimate and the limit) if the sweep (or `what`, a run of the sweep's
    kind on `cfg`) would hold more trajectory memory or integrate more steps than allowed
    ([limits], --max-memory, --max-steps)."""
    from stepzoo.validate import GIB, check_budget
    lanes = min(cfg.chunks.points, len(cfg.points))
    steps = run_steps(cfg) + 1                                           # every call's length
    blocks = -(-len(cfg.points) // cfg.chunks.points)
    # Per method and block, calls of one block's lanes: the accuracy runs at every step; for
    # stability a pair of runs (perturbed, unperturbed) a call apart, per grid step, per rung
    # of the ladders past the grid (at most ten) and per narrowing round (a bisection's at
    # most, from a bracket of 1.3). The pair's two trajectory arrays are held at once. The
    # "modes" rule runs one unperturbed and MODES + d perturbed runs per candidate, and also
    # probes its ladder of multiples of h_pred.
    from stepzoo.bench.sweep.limit_search import PRED_LADDER
    from stepzoo.bench.sweep.runs.stability_runs import MODES
    rounds = math.ceil(math.log2(math.log(1.3) / math.log1p(cfg.stability.rel_tol))) + 1
    per, probes = (2, 0) if cfg.stability.rule == "blowup" else \
        (MODES + len(cfg.spec.states) + 1, len(PRED_LADDER))
    calls = len(cfg.hs) + per * (len(cfg.hs) + 10 + rounds + probes)
    memory = cfg.limits.memory_gib and cfg.limits.memory_gib * GIB
    check_budget(what or f"the sweep {cfg.name!r}", steps, 2 * lanes, len(cfg.spec.states),
                 calls=len(cfg.methods) * blocks * calls / 2,
                 memory=memory, max_steps=cfg.limits.steps)


def run_steps(cfg: SweepConfig) -> int:
    """The steps of a sweep's longest call: the accuracy run at the smallest step, or a
    stability run (`stability.steps`, or the stability horizon at the smallest step)."""
    stab = cfg.stability.steps if cfg.stability.rule == "blowup" else \
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
