"""The model of a sweep config, resolved: `model` (a built-in by name, or a [model] table of
your own), [params], [initial], [envelope] and [error] become one ModelSpec (bench.model.spec)
with its operating points; every mistake is a line appended to the caller's list."""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
from pydantic import AfterValidator, ConfigDict, Field, model_validator

from stepzoo.bench.model import casadi_source as casadi_model
from stepzoo.bench.model.spec import (BICYCLE_ERROR_STATES, Expression, Hook, ModelSpec,
                                      Nested, builtin, flatten, load_function)
from stepzoo.bench.sweep.grids import MAX_GRID, Grid, grid_values
from stepzoo.config_schema import Schema
from stepzoo.errors import UsageError
from stepzoo.validate import problem

if TYPE_CHECKING:
    from stepzoo.bench.sweep.config import SweepConfig


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


def model_spec(f: SweepConfig, source: str, bad: list) -> tuple[ModelSpec | None, str]:
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
