"""A sweep config: a TOML file read into a frozen, validated `SweepConfig`. Every mistake is
one line naming the key, what is wrong and what to write instead; all mistakes are reported
at once (UsageError, exit 2)."""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from stepzoo.bench import casadi_model
from stepzoo.bench.model_spec import (BICYCLE_ERROR_STATES, ModelSpec, builtin, check_rhs, is_num,
                                      load_function, name_list)
from stepzoo.errors import UsageError
from stepzoo.validate import problem, read_toml

TOP = {"name", "model", "tyre", "vehicle", "horizon", "methods", "params", "initial",
       "envelope", "error", "steps", "reference", "limits", "stability", "chunks",
       "trajectories", "timing", "newton"}
MAX_GRID = 10_000       # values of one grid, or points of an envelope: more is a typo, and
                        # would be allocated before any estimate of the work
SECTIONS = {
    "steps": {"h"},
    "reference": {"rtol", "atol", "exact", "solver"},
    "stability": {"steps", "growth", "perturbation", "h_probe_max", "rel_tol"},
    "chunks": {"points"},
    "error": {"states", "scales", "estimate"},
    "limits": {"memory_gib", "steps"},
    "timing": {"rounds"},
}
# `methods = "..."`: the zoo's methods of one kind. bounded: a finite real stability
# interval (explicit methods, Adams-Moulton), the methods a stiff problem's fast modes bind;
# unbounded: the rest (A- and A(alpha)-stable).
SELECTORS = ("all", "explicit", "implicit", "bounded", "unbounded")
# [reference] solver: what computes a reference (the default: dopri5, JAX's adaptive
# Dormand-Prince, for every model but the stiff test problems, which take LSODA); the others
# are SciPy's solve_ivp methods, per distinct lane. Radau IIA (order 5) reaches 1e-13 where
# LSODA stops near 1e-12 (Robertson at rtol 1e-13: 6e-14 against 1.3e-12, rk6 at 2^19 steps
# the truth).
REF_SOLVERS = ("", "dopri5", "LSODA", "Radau", "BDF", "DOP853")
DEFAULT_ROUNDS = 5     # timed repeats of each accuracy run, after its compilation
ESTIMATES = {          # [error] estimate: which times of a run its error `err` is taken over
    "max": "the largest scaled error over every step of the run",
    "final": "the scaled error at the end of the horizon (as the Test Set for IVP Solvers "
             "and DiffEqDevTools' error_estimate = :final)"}
# Scaled size of the stability runs' initial deviation. h_pred is a linearised (small-
# deviation) limit, so the deviation stays small through its `growth`: 1e-6 grown 100 times
# is still far below the slip where a tyre saturates (at 0.1, saturation capped the growth
# and Pacejka/Fiala limits came out 5-67 times the linear ones in straight running), and
# well above the Newton solves' default tolerances (1e-10), so their noise is no growth.
DEFAULT_PERTURBATION = 1e-6
MODEL_KEYS = {"rhs", "path", "states", "inputs", "casadi", "p"}   # casadi, p: bench.casadi_model


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep. Step sizes are snapped to horizon/n (whole steps, each run ends at
    the horizon) and sorted; the operating points are every combination of the envelope's
    values (`spec.points`, the first variable slowest)."""
    name: str
    model: str                     # built-in name, or "module:function" of a user's model
    vehicle: str
    horizon: float                 # [s] of the accuracy runs
    methods: tuple
    spec: ModelSpec
    hs: tuple                      # [s], ascending
    rtol: float
    atol: float
    stab_steps: int                # steps of one stability run
    growth: float                  # blow-up threshold on the scaled deviation
    perturbation: float            # scaled size of the stability runs' initial deviation
    h_probe_max: float             # [s] largest step probed for a blow-up
    rel_tol: float                 # bisection stops when h_hi / h_lo - 1 <= rel_tol
    points_per_chunk: int
    traj_point: tuple              # one value per envelope variable: the sample trajectories'
    traj_fractions: tuple          # sample steps, as fractions of the predicted limit
    traj_past_limit: float         # the sample past the limit, as a multiple of it
    source: str = field(default="", compare=False)
    # [limits]: what the sweep may allocate [GiB] and integrate (they decide no result)
    max_memory_gib: float | None = field(default=None, compare=False)
    max_steps: float | None = field(default=None, compare=False)
    timing_rounds: int = DEFAULT_ROUNDS    # timed repeats of each accuracy run
    exact_reference: bool = False  # references from the model's closed form (reference.exact)
    error_estimate: str = "max"    # a key of ESTIMATES
    ref_solver: str = ""           # reference.solver; "": the model's default (REF_SOLVERS)
    # [newton]: the implicit methods' solve options (fields of NewtonOptions) that differ
    # from its defaults, as sorted (name, value) pairs
    newton: tuple = ()

    @property
    def points(self) -> list[tuple]:
        return self.spec.points

    def values(self, var: str) -> tuple:
        """The envelope's values of one variable."""
        return dict(self.spec.envelope)[var]

    def canonical(self) -> dict:
        """Everything that decides the results (not the file's path or layout)."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in
             ("source", "spec", "max_memory_gib", "max_steps")}
        # A sweep from before these keys keeps its sha256.
        if not self.exact_reference:
            del d["exact_reference"]
        if self.error_estimate == "max":
            del d["error_estimate"]
        if not self.ref_solver:
            del d["ref_solver"]
        if self.newton:
            d["newton"] = dict(self.newton)
        else:
            del d["newton"]
        d["spec"] = self.spec.canonical()
        return d

    @property
    def sha256(self) -> str:
        text = json.dumps(self.canonical(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    @property
    def newton_options(self) -> dict:
        """Every option of the implicit methods' Newton solves: [newton] over the defaults."""
        from dataclasses import asdict

        from stepzoo.integrators.newton import NewtonOptions
        return asdict(NewtonOptions(**dict(self.newton)))

    def method(self, name: str):
        """The zoo's method `name` with this sweep's [newton] options (the same Method for
        every call in a process: one compilation)."""
        from stepzoo.integrators import method
        from stepzoo.integrators.newton import NewtonOptions
        return method(name, NewtonOptions(**dict(self.newton)) if self.newton else None)


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
    from stepzoo.integrators import METHODS
    bad: list[str] = []
    check = _Checker(bad, source)

    for key in sorted(set(raw) - TOP):
        bad.append(f"{source}: unknown key {key!r}; known: {', '.join(sorted(TOP))}")
    sections = {}
    for sec in (*SECTIONS, "params", "initial", "envelope", "trajectories", "newton"):
        table = raw.get(sec, {})
        if not isinstance(table, dict):
            bad.append(f"{source}: [{sec}] must be a table")
            table = {}
        for key in sorted(set(table) - SECTIONS.get(sec, set(table))):
            bad.append(f"{source}: unknown key {sec}.{key}; known: "
                       f"{', '.join(sorted(SECTIONS[sec]))}")
        sections[sec] = table

    spec, vehicle = model_spec(raw, sections, source, bad, check)

    horizon = check.ranged("horizon", "horizon", raw.get("horizon"))
    methods = raw.get("methods", "all")
    if isinstance(methods, str) and methods in SELECTORS:
        methods = selected(methods)
    elif not (isinstance(methods, list) and methods and all(isinstance(m, str) for m in methods)):
        bad.append(f"{source}: methods must be one of {', '.join(map(repr, SELECTORS))} or a "
                   "non-empty list of names")
        methods = []
    for m in methods:
        if m not in METHODS:
            bad.append(f"{source}: unknown method {m!r} in methods; known: {', '.join(METHODS)}")
    if len(set(methods)) != len(methods):
        bad.append(f"{source}: methods lists a name twice; list each once")

    hs = check.grid("steps.h", sections["steps"].get("h"), "s", "step", log=True)
    if horizon and hs:
        if max(hs) > horizon:
            bad.append(f"{source}: steps.h reaches {max(hs):g} s, past the horizon "
                       f"{horizon:g} s; keep every step <= horizon")
        hs = sorted({horizon / max(1, round(horizon / h)) for h in hs})

    ref = sections["reference"]
    rtol = check.ranged("rtol", "reference.rtol", ref.get("rtol", 1e-10))
    atol = check.ranged("atol", "reference.atol", ref.get("atol", 1e-12))
    exact = ref.get("exact", False)
    if not isinstance(exact, bool):
        bad.append(f"{source}: reference.exact must be true or false, got {exact!r}")
    elif exact and spec is not None:
        exact = closed_form_problem(spec, source, bad)
    solver = ref.get("solver", "")
    if solver not in REF_SOLVERS:
        bad.append(f"{source}: reference.solver must be one of "
                   f"{', '.join(map(repr, REF_SOLVERS[1:]))}, got {solver!r}")
    elif spec is not None and (exact is True or solver == default_solver(spec)):
        solver = ""       # the default, or unused: the same results, the same sha256
    stab = sections["stability"]
    steps = stab.get("steps", 1000)
    if not (isinstance(steps, int) and not isinstance(steps, bool) and 50 <= steps <= 100_000):
        bad.append(f"{source}: stability.steps must be a whole number in [50, 100000], "
                   f"got {steps!r}")
    growth = check.ranged("growth", "stability.growth", stab.get("growth", 100.0))
    perturbation = check.ranged("perturbation", "stability.perturbation",
                                stab.get("perturbation", DEFAULT_PERTURBATION))
    h_probe_max = check.ranged("step", "stability.h_probe_max", stab.get("h_probe_max", 2.0))
    if h_probe_max and hs and h_probe_max < max(hs):
        bad.append(f"{source}: stability.h_probe_max ({h_probe_max:g} s) is below the "
                   f"largest step ({max(hs):g} s); raise it")
    rel_tol = check.ranged("rel_tol", "stability.rel_tol", stab.get("rel_tol", 1e-3))
    per_chunk = sections["chunks"].get("points", 25)
    if not (isinstance(per_chunk, int) and not isinstance(per_chunk, bool) and per_chunk >= 1):
        bad.append(f"{source}: chunks.points must be a whole number >= 1, got {per_chunk!r}")

    traj = sections["trajectories"]
    variables = spec.variables if spec else ()
    for key in sorted(set(traj) - {"fractions", "past_limit", *variables} if spec else ()):
        bad.append(f"{source}: unknown key trajectories.{key}; known: fractions, past_limit "
                   "and the envelope's variables")
    traj_point = []
    for var in variables:
        value = traj.get(var, dict(spec.envelope)[var][0])
        if not is_num(value):
            bad.append(f"{source}: trajectories.{var} must be a number")
            value = 0.0
        traj_point.append(float(value))
    fractions = traj.get("fractions", [0.2, 0.5, 0.9])
    if not (isinstance(fractions, list) and fractions
            and all(is_num(f) and 0 < f <= 1 for f in fractions)):
        bad.append(f"{source}: trajectories.fractions must be numbers in (0, 1] (of the "
                   "predicted largest stable step)")
        fractions = [0.5]
    past = check.positive("trajectories.past_limit", traj.get("past_limit", 1.5), "")
    if past and past <= 1:
        bad.append(f"{source}: trajectories.past_limit must be > 1 (a multiple of the limit)")

    limits = [sections["limits"].get(key) for key in ("memory_gib", "steps")]
    for key, value in zip(("limits.memory_gib", "limits.steps"), limits):
        if value is not None and not (is_num(value) and value > 0):
            bad.append(f"{source}: {key} must be a number > 0, got {value!r}")
    estimate = sections["error"].get("estimate", "max")
    if estimate not in ESTIMATES:
        bad.append(f"{source}: error.estimate must be one of {', '.join(map(repr, ESTIMATES))}"
                   f", got {estimate!r}")
    rounds = check.ranged("rounds", "timing.rounds",
                          sections["timing"].get("rounds", DEFAULT_ROUNDS))
    newton = newton_options(sections["newton"], source, bad)
    name = raw.get("name", Path(source).stem)
    if not isinstance(name, str):
        bad.append(f"{source}: name must be a string")
    if exact is True and spec is not None and tuple(traj_point) not in spec.points:
        bad.append(f"{source}: reference.exact solves the model's own problem alone; leave "
                   "[trajectories] at the envelope's values")
    if not bad and spec is not None:
        check_rhs(spec, source)
    if bad:
        raise UsageError("\n".join(bad))
    return SweepConfig(str(name), spec.name, vehicle, float(horizon), tuple(methods), spec,
                       tuple(hs), float(rtol), float(atol), int(steps), float(growth),
                       float(perturbation), float(h_probe_max), float(rel_tol), int(per_chunk),
                       tuple(traj_point), tuple(float(f) for f in fractions), float(past),
                       source, *limits, timing_rounds=int(rounds or DEFAULT_ROUNDS),
                       exact_reference=exact is True, error_estimate=estimate,
                       ref_solver=solver, newton=newton)


def default_solver(spec: ModelSpec) -> str:
    """The reference's solver where reference.solver is not given: LSODA for a stiff test
    problem, else dopri5."""
    return "LSODA" if spec.stiff else "dopri5"


def newton_options(table: dict, source: str, bad: list) -> tuple:
    """[newton]: options of the implicit methods' Newton solves, keyed by the fields of
    NewtonOptions; the sorted (name, value) pairs that differ from its defaults (a table
    that repeats a default keeps the sweep's sha256). Appends to `bad` if wrong."""
    from dataclasses import fields as fields_of

    from stepzoo.integrators.newton import NewtonOptions
    defaults = {f.name: f.default for f in fields_of(NewtonOptions)}
    before = len(bad)
    for key in sorted(set(table) - set(defaults)):
        bad.append(f"{source}: unknown key newton.{key}; known: {', '.join(sorted(defaults))}")
    given = {}
    for key in sorted(set(table) & set(defaults)):
        message = problem(f"newton_{key}", f"newton.{key}", table[key])
        if message:
            bad.append(f"{source}: {message}")
        else:
            given[key] = type(defaults[key])(table[key])
    opts = {**defaults, **given}
    if len(bad) == before and opts["rtol"] == 0 and opts["atol"] == 0:
        bad.append(f"{source}: newton.rtol and newton.atol are both 0; give one > 0")
    return tuple(sorted((k, v) for k, v in given.items() if v != defaults[k]))


def closed_form_problem(spec: ModelSpec, source: str, bad: list) -> bool:
    """Whether the references may be `spec`'s closed form: a built-in test problem that has
    one, at its own default problem (initial state, inputs, parameters) in every operating
    point, since the closed form solves that problem alone; appends to `bad` if not."""
    from stepzoo import dynamics
    m = dynamics.MODELS.get(spec.name)
    if m is None or m.exact is None or m.vehicle_params is not None:
        bad.append(f"{source}: reference.exact needs a built-in test problem with a closed "
                   f"form; {spec.name} has none (set reference.exact = false)")
        return False
    x0, u, p = spec.arrays(spec.points)
    own = bool((x0 == np.asarray(m.x0, float)).all() and (u == np.asarray(m.u0, float)).all()
               and all((p[k] == v).all() for k, v in m.params().items()))
    if not own:
        bad.append(f"{source}: reference.exact solves {spec.name}'s own problem alone; keep "
                   "[envelope], [initial] and [params] at its published values")
    return own


def model_spec(raw, sections, source, bad, check) -> tuple[ModelSpec | None, str]:
    """(the config's model, the vehicle set name) from `model`, [params], [initial],
    [envelope] and [error]; appends to `bad` and returns None for the model when wrong."""
    from stepzoo import dynamics
    before = len(bad)
    model = raw.get("model", "dynamic5")
    vehicle = raw.get("vehicle", dynamics.default_vehicle())
    if vehicle not in dynamics.vehicle_names():
        bad.append(f"{source}: unknown vehicle {vehicle!r}; known: "
                   f"{', '.join(dynamics.vehicle_names())}")
        vehicle = dynamics.default_vehicle()
    sha, tyre, stiff, folder = "", raw.get("tyre"), False, ""
    if tyre is not None and not isinstance(model, str):
        bad.append(f"{source}: tyre is an option of the built-in dynamic bicycles; your own "
                   "model sets its tyres itself")
        return None, vehicle
    if isinstance(model, str):
        if model not in dynamics.MODELS:
            bad.append(f"{source}: unknown model {model!r}; known: {', '.join(dynamics.MODELS)}"
                       " (or a [model] table naming your own rhs = \"module:function\")")
            return None, vehicle
        name = model
        try:
            rhs, states, inputs, params, initial, kinds, stiff = builtin(model, vehicle, tyre)
        except KeyError as err:
            bad.append(f"{source}: {err.args[0]}")
            return None, vehicle
    elif isinstance(model, dict):
        for key in sorted(set(model) - MODEL_KEYS):
            bad.append(f"{source}: unknown key model.{key}; known: "
                       f"{', '.join(sorted(MODEL_KEYS))}")
        key = "casadi" if "casadi" in model else "rhs"
        name = model.get(key)
        if "casadi" in model and "rhs" in model:
            bad.append(f"{source}: model.rhs (a JAX f(t, x, u, p)) and model.casadi are two "
                       "ways to give a model; keep one")
            return None, vehicle
        if "p" in model and key == "rhs":
            bad.append(f"{source}: model.p names the entries of a CasADi function's p "
                       "(model.casadi); a JAX model.rhs reads [params] by name: drop model.p")
            return None, vehicle
        if not isinstance(name, str):
            what = "f(t, x, u, p)" if key == "rhs" else "casadi.Function, or its saved file"
            bad.append(f"{source}: model.{key} must be \"module:function\" (your {what})")
            return None, vehicle
        states = name_list(model.get("states"), "states", source, bad)
        inputs = name_list(model.get("inputs", []), "inputs", source, bad)
        if not states:
            bad.append(f"{source}: model.states must name at least one state")
            return None, vehicle
        folder = model.get("path", ".")
        if not isinstance(folder, str):
            bad.append(f"{source}: model.path must be a folder (relative to {source})")
            return None, vehicle
        folder = str((Path(source).resolve().parent / folder).resolve())
        try:
            if key == "casadi":
                p_names = casadi_model.check_p(model.get("p"), sections["params"], source, bad)
                if len(bad) > before:
                    return None, vehicle
                rhs, sha = casadi_model.load(name, Path(folder), states, inputs, p_names,
                                             source)
            else:
                rhs, sha = load_function(name, Path(folder), source)
        except UsageError as err:
            bad.append(str(err))
            return None, vehicle
        params, initial, kinds = {}, dict.fromkeys([*states, *inputs], 0.0), {}
    else:
        bad.append(f"{source}: model must be a built-in name or a [model] table")
        return None, vehicle

    for key, value in sections["params"].items():
        if not is_num(value):
            bad.append(f"{source}: params.{key} must be a finite number, got {value!r}")
        params[key] = value
    envelope_raw = dict(sections["envelope"])
    legacy_x0 = envelope_raw.pop("x0", None)     # the bicycle configs' whole initial state
    if legacy_x0 is not None:
        if not (isinstance(legacy_x0, list) and len(legacy_x0) == len(states)
                and all(is_num(v) for v in legacy_x0)):
            bad.append(f"{source}: envelope.x0 must be {len(states)} finite numbers "
                       f"[{', '.join(states)}]")
        else:
            initial.update(zip(states, legacy_x0))
    for key, value in sections["initial"].items():
        if key not in states:
            bad.append(f"{source}: initial.{key} is not a state; states: {', '.join(states)}")
        elif not is_num(value):
            bad.append(f"{source}: initial.{key} must be a finite number, got {value!r}")
        else:
            initial[key] = value
    known = set(states) | set(inputs) | set(params)
    envelope = []
    for var, value in envelope_raw.items():
        if var not in known:
            bad.append(f"{source}: envelope.{var} is not a parameter, input or state of "
                       f"{name}; known: {', '.join(sorted(known))}")
            continue
        values = check.grid(f"envelope.{var}", value, "", kinds.get(var), log=False)
        envelope.append((var, tuple(values)))
    n_points = math.prod(len(vals) for _, vals in envelope)
    if n_points > MAX_GRID:
        bad.append(f"{source}: the envelope has "
                   f"{' x '.join(str(len(v)) for _, v in envelope)} operating points; at most "
                   f"{MAX_GRID}")
    if not envelope and len(bad) == before:
        bad.append(f"{source}: [envelope] names no variable; give at least one parameter, "
                   "input or initial state with its values")
    err = sections["error"]
    error_states = err.get("states", list(BICYCLE_ERROR_STATES) if name == "dynamic5"
                           else list(states))
    if not (isinstance(error_states, list) and error_states
            and all(s in states for s in error_states)):
        bad.append(f"{source}: error.states must be a non-empty list of state names; "
                   f"states: {', '.join(states)}")
        error_states = list(states)
        scales = [1.0] * len(states)
    else:
        scales = err.get("scales", [1.0] * len(error_states))
    if not (isinstance(scales, list) and len(scales) == len(error_states)
            and all(is_num(s) and s > 0 for s in scales)):
        bad.append(f"{source}: error.scales must be one number > 0 per error state "
                   f"({len(error_states)})")
        scales = [1.0] * len(error_states)
    if len(bad) > before:
        return None, vehicle
    return ModelSpec(name, rhs, tuple(states), tuple(inputs),
                     tuple((k, float(v)) for k, v in params.items()),
                     tuple(float(initial[s]) for s in states),
                     tuple(float(initial[s]) for s in inputs), tuple(envelope),
                     tuple(error_states), tuple(float(s) for s in scales), stiff,
                     tyre if tyre is None else str(tyre), sha,
                     folder), vehicle


class _Checker:
    """Appends one line per mistake to `bad`; returns a usable value either way."""

    def __init__(self, bad, source):
        self.bad, self.source = bad, source

    def positive(self, key, value, unit):
        if not (is_num(value) and value > 0):
            units = f" [{unit}]" if unit else ""
            self.bad.append(f"{self.source}: {key} must be a number > 0{units}, got {value!r}")
            return None
        return float(value)

    def ranged(self, kind, key, value):
        """`value` if it lies in RANGES[kind], else None (and a line in `bad`)."""
        message = problem(kind, key, value)
        if message:
            self.bad.append(f"{self.source}: {message}")
            return None
        return float(value)

    def grid(self, key, value, unit, kind, log):
        """A list of numbers, {values = [...]}, or {min, max, num <= MAX_GRID} spaced linearly
        (log-spaced if `log`, or if the table says log = true); each in RANGES[kind] when a
        kind is given."""
        spacing = "log-spaced" if log else "evenly spaced, or log = true"
        units = f" [{unit}]" if unit else ""
        what = (f"{key} must be a list of numbers{units}, {{values = [...]}} or "
                f"{{min = ..., max = ..., num = ...}} ({spacing})")
        if isinstance(value, dict) and set(value) == {"values"}:
            value = value["values"]
        if isinstance(value, dict):
            lo, hi, num = value.get("min"), value.get("max"), value.get("num")
            log = value.get("log", log)
            if not set(value) - {"log"} == {"min", "max", "num"} \
                    or not (is_num(lo) and is_num(hi)) or not isinstance(log, bool) \
                    or not (isinstance(num, int) and not isinstance(num, bool)
                            and 1 <= num <= MAX_GRID) or lo > hi:
                self.bad.append(f"{self.source}: {what} with min <= max and 1 <= num <= "
                                f"{MAX_GRID}, got {value!r}")
                return []
            if kind and (self.ranged(kind, f"{key}.min", lo) is None
                         or self.ranged(kind, f"{key}.max", hi) is None):
                return []
            if log and lo <= 0:
                self.bad.append(f"{self.source}: {key}.min must be > 0 for log spacing, "
                                f"got {lo!r}")
                return []
            values = np.geomspace(lo, hi, num) if log else np.linspace(lo, hi, num)
            return [float(v) for v in values]
        if not (isinstance(value, list) and value and all(is_num(v) for v in value)):
            self.bad.append(f"{self.source}: {what}, got {value!r}")
            return []
        if len(value) > MAX_GRID:
            self.bad.append(f"{self.source}: {key} lists {len(value)} values; at most "
                            f"{MAX_GRID}")
            return []
        if kind and any(self.ranged(kind, f"every {key}", v) is None for v in value):
            return []
        if len(set(value)) != len(value):
            self.bad.append(f"{self.source}: {key} lists a value twice; list each once")
            return []
        return [float(v) for v in value]


def check_workload(cfg: SweepConfig):
    """UsageError (the estimate and the limit) if the sweep would hold more trajectory memory
    or integrate more steps than allowed ([limits], --max-memory, --max-steps)."""
    from stepzoo.validate import GIB, check_budget
    lanes = min(cfg.points_per_chunk, len(cfg.points))
    steps = max(round(cfg.horizon / cfg.hs[0]), cfg.stab_steps) + 1   # every call's length
    blocks = -(-len(cfg.points) // cfg.points_per_chunk)
    # Per method and block, calls of one block's lanes: the accuracy runs at every step; for
    # stability a pair of runs (perturbed, unperturbed) a call apart, per grid step, per rung
    # of the ladders past the grid (at most ten) and per narrowing round (a bisection's at
    # most, from a bracket of 1.3). The pair's two trajectory arrays are held at once.
    rounds = math.ceil(math.log2(math.log(1.3) / math.log1p(cfg.rel_tol))) + 1
    calls = len(cfg.hs) + 2 * (len(cfg.hs) + 10 + rounds)
    memory = cfg.max_memory_gib and cfg.max_memory_gib * GIB
    check_budget(f"the sweep {cfg.name!r}", steps, 2 * lanes, len(cfg.spec.states),
                 calls=len(cfg.methods) * blocks * calls / 2,
                 memory=memory, max_steps=cfg.max_steps)


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
