"""A model as the sweep sees it: a right-hand side f(t, x, u, p) with state, input and
parameter names, fixed values, an initial state, an operating envelope over any parameter,
input or initial state by name, and the states (with scales) that the error norm reads.

A built-in model (`model = "dynamic5"`) and a user's own (`[model] rhs = "module:function"`)
are read into the same `ModelSpec`; nothing downstream knows which it was. An initial state may
be an expression of the others, the inputs and the parameters (`omega = "vx / r_w"`, read by
`Expression`, which evaluates arithmetic alone) or a "module:function" hook; nested [params]
tables are flattened with dotted names ("tyre.r_w") and handed to a user's f nested again."""
from __future__ import annotations

import ast
import functools
import hashlib
import importlib
import inspect
import itertools
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from stepzoo.errors import UsageError
from stepzoo.output import prints_to_stderr

# The built-in bicycle's error states: its lateral velocity and yaw rate. X, Y and psi
# integrate them and drift even in exact runs, so they never count toward blow-up.
BICYCLE_ERROR_STATES = ("vy", "r")


@dataclass(frozen=True)
class ModelSpec:
    """Everything the sweep needs of a model; values in the model's own units."""
    name: str                    # built-in name, or "module:function"
    rhs: Callable = field(compare=False, repr=False)
    states: tuple
    inputs: tuple
    params: tuple                # ((name, value), ...) fixed parameter values
    initial: tuple               # initial state, one value per state
    u0: tuple                    # inputs, constant in time, one value per input
    envelope: tuple              # ((variable, (values...)), ...) in the file's order
    error_states: tuple
    error_scales: tuple          # one positive scale per error state
    stiff: bool = False          # its reference needs an implicit solver
    tyre: str | None = None      # the tyre law of a built-in dynamic bicycle
    source_sha256: str = ""      # of the user's module file, so a changed model is a new sweep
    folder: str = field(default="", compare=False)    # absolute folder of a user's module
    # ((state, text), ...) initial states given as an expression or a "module:function" hook,
    # in the file's order, and their evaluators (Expression or Hook) alike
    derived: tuple = ()
    derive: tuple = field(default=(), compare=False, repr=False)

    @property
    def variables(self) -> tuple:
        return tuple(v for v, _ in self.envelope)

    def kind(self, var: str) -> str:
        """'param', 'input' or 'initial': where an envelope variable lives."""
        if var in dict(self.params):
            return "param"
        if var in self.inputs:
            return "input"
        return "initial"

    @property
    def points(self) -> list[tuple]:
        """Every combination of the envelope's values, the first variable slowest."""
        return list(itertools.product(*(vals for _, vals in self.envelope)))

    @property
    def vehicle(self) -> bool:
        """A planar vehicle: its position (X, Y) gives the position error columns."""
        return {"X", "Y"} <= set(self.states)

    @property
    def error_index(self) -> np.ndarray:
        return np.array([self.states.index(s) for s in self.error_states])

    def arrays(self, points) -> tuple[np.ndarray, np.ndarray, dict]:
        """(x0 (B, n), u (B, m), p {name: (B,)}) of a list of operating points."""
        n = len(points)
        x0 = np.tile(np.asarray(self.initial, float), (n, 1))
        u = np.tile(np.asarray(self.u0, float), (n, 1))
        p = {k: np.full(n, float(v)) for k, v in self.params}
        for j, var in enumerate(self.variables):
            col = np.array([pt[j] for pt in points], float)
            kind = self.kind(var)
            if kind == "param":
                p[var] = col
            elif kind == "input":
                u[:, self.inputs.index(var)] = col
            else:
                x0[:, self.states.index(var)] = col
        for (state, _), value in zip(self.derived, self.derive):
            x0[:, self.states.index(state)] = value(self.named(x0, u, p))
        return x0, u, p

    def named(self, x0, u, p) -> dict:
        """Every state, input and parameter by name, as columns over the points."""
        return {**p, **{s: u[:, i] for i, s in enumerate(self.inputs)},
                **{s: x0[:, i] for i, s in enumerate(self.states)}}

    def scaled(self, dx) -> np.ndarray:
        """max over error states of |dx_i| / scale_i along the last axis of dx (..., n)."""
        with np.errstate(invalid="ignore", over="ignore"):
            d = np.abs(np.asarray(dx)[..., self.error_index]) / np.asarray(self.error_scales)
            return np.where(np.isfinite(d).all(axis=-1), d.max(axis=-1), np.inf)

    def canonical(self) -> dict:
        return {"name": self.name, "states": list(self.states), "inputs": list(self.inputs),
                "params": dict(self.params), "initial": list(self.initial),
                "inputs_values": list(self.u0), "stiff": self.stiff, "tyre": self.tyre,
                "envelope": {v: list(vals) for v, vals in self.envelope},
                "error_states": list(self.error_states),
                "error_scales": list(self.error_scales), "source_sha256": self.source_sha256,
                **({"derived": dict(self.derived)} if self.derived else {})}


# The functions an initial-state expression may call, on NumPy arrays over the points.
FUNCTIONS = {"sqrt": np.sqrt, "exp": np.exp, "log": np.log, "sin": np.sin, "cos": np.cos,
             "tan": np.tan, "atan": np.arctan, "atan2": np.arctan2, "hypot": np.hypot,
             "abs": np.abs, "min": np.minimum, "max": np.maximum}
CONSTANTS = {"pi": np.pi}
_OPS = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply, ast.Div: np.divide,
        ast.Pow: np.power, ast.USub: np.negative, ast.UAdd: np.positive}


class Expression:
    """An arithmetic expression of named values ("vx / tyre.r_w"): numbers, names (dotted
    names of nested parameters), + - * / **, and FUNCTIONS; anything else (attributes of
    objects, subscripts, lambdas, imports) is refused when it is read, and nothing is ever
    handed to eval."""

    def __init__(self, text: str):
        self.text = text
        try:
            self.tree = ast.parse(text, mode="eval").body
        except SyntaxError as err:
            raise ValueError(f"is not an expression ({err.msg})") from None
        self.names: set[str] = set()
        self._check(self.tree)

    def _check(self, node):
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) \
                and not isinstance(node.value, bool):
            return
        if _dotted(node) is not None:
            name = _dotted(node)
            if name not in CONSTANTS:
                self.names.add(name)
            return
        if isinstance(node, ast.BinOp) and type(node.op) in _OPS:
            self._check(node.left)
            self._check(node.right)
            return
        if isinstance(node, ast.UnaryOp) and type(node.op) in _OPS:
            self._check(node.operand)
            return
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id in FUNCTIONS and not node.keywords:
            for arg in node.args:
                self._check(arg)
            return
        raise ValueError(f"may hold numbers, names, + - * / ** and {', '.join(FUNCTIONS)}; "
                         f"not {ast.unparse(node)!r}")

    def __call__(self, values: dict):
        return np.asarray(self._eval(self.tree, values), float)

    def _eval(self, node, values):
        if isinstance(node, ast.Constant):
            return node.value
        name = _dotted(node)
        if name is not None:
            return CONSTANTS[name] if name in CONSTANTS else values[name]
        if isinstance(node, ast.BinOp):
            return _OPS[type(node.op)](self._eval(node.left, values),
                                       self._eval(node.right, values))
        if isinstance(node, ast.UnaryOp):
            return _OPS[type(node.op)](self._eval(node.operand, values))
        return FUNCTIONS[node.func.id](*(self._eval(a, values) for a in node.args))


def _dotted(node) -> str | None:
    """"a.b.c" of a name or a chain of attributes of a name, else None."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    return ".".join([node.id, *reversed(parts)])


class Hook:
    """An initial state computed by the user's "module:function": called with every state,
    input and parameter by name, as NumPy arrays over the operating points (the states
    already set), it returns the state's values (one per point, or one for all)."""

    def __init__(self, fn):
        self.fn = fn
        self.names = set()

    def __call__(self, values: dict):
        return np.asarray(self.fn(dict(values)), float)


def flatten(params: dict, prefix: str = "") -> dict:
    """Nested parameter tables as one table of dotted names: {"tyre": {"r_w": 0.3}} ->
    {"tyre.r_w": 0.3}."""
    out = {}
    for key, value in params.items():
        if isinstance(value, dict):
            out.update(flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def nest(p: dict) -> dict:
    """The inverse of `flatten`: dotted names as nested dicts (any leaves: arrays, tracers)."""
    out: dict = {}
    for key, value in p.items():
        *path, last = key.split(".")
        table = out
        for part in path:
            table = table.setdefault(part, {})
        table[last] = value
    return out


class Nested:
    """A user's f(t, x, u, p) that reads nested parameter tables (p["tyre"]["r_w"]), called
    with the flat dotted table the sweep varies; equal, hashed and pickled by f."""

    def __init__(self, fn):
        self.fn = fn
        functools.update_wrapper(self, fn)

    def __call__(self, t, x, u, p):
        return self.fn(t, x, u, nest(p))

    def __eq__(self, other):
        return isinstance(other, Nested) and other.fn == self.fn

    def __hash__(self):
        return hash(("nested", self.fn))

    def __reduce__(self):
        return Nested, (self.fn,)


def builtin(name: str, vehicle: str, tyre: str | None = None):
    """(rhs, states, inputs, params, initial {name: value} of states and inputs, {variable:
    RANGES kind}, stiff) of a registered model: a vehicle model with the named vehicle set
    (and tyre law), any other with its own default problem. A speed and a steer angle are
    checked against their physical ranges."""
    from stepzoo import dynamics
    m = dynamics.model(name, tyre=tyre)
    params = dict(m.params(vehicle) if m.vehicle_params is not None else m.params())
    initial = dict(zip(m.states, m.x0)) | dict(zip(m.inputs, m.u0))
    kinds = {k: v for k, v in (("vx", "speed"), ("delta", "steer"))
             if k in params or k in m.inputs or k in m.states}
    return (m.rhs, tuple(m.states), tuple(m.inputs), params, initial, kinds, bool(m.stiff))


def load_function(ref: str, folder: Path, source: str):
    """(function, sha256 of its module file) for "module:function", importing the module with
    `folder` first on the import path; UsageError (one line) when it cannot be had."""
    module_name, _, func_name = ref.partition(":")
    if not module_name or not func_name:
        raise UsageError(f"{source}: model.rhs must be \"module:function\", got {ref!r}")
    module = import_user_module(module_name, folder, source, "rhs")
    fn = getattr(module, func_name, None)
    if fn is None:
        raise UsageError(f"{source}: {module_name!r} has no function {func_name!r} (model.rhs "
                         "names f(t, x, u, p) -> dx/dt)")
    if not callable(fn):
        raise UsageError(f"{source}: {module_name}.{func_name} is {type(fn).__name__!r}, not a "
                         "function f(t, x, u, p) -> dx/dt")
    try:
        text = Path(inspect.getfile(module)).read_bytes()
    except (TypeError, OSError):
        text = b""
    return _Quiet(fn), hashlib.sha256(text).hexdigest()


def import_user_module(module_name: str, folder: Path, source: str, key: str):
    """The user's module `module_name`, imported with `folder` first on the import path and
    its prints sent to stderr; UsageError (one line) when it is missing, exits or fails at
    import, or when a module of that name from elsewhere shadows it. `key`: the [model] key
    that names it (rhs, casadi), for the messages."""
    sys.path.insert(0, str(folder))
    try:
        with prints_to_stderr():
            module = importlib.import_module(module_name)
    except ModuleNotFoundError as err:
        raise UsageError(f"{source}: model.{key} names module {module_name!r}, which is not in "
                         f"{folder} nor installed ({err}); set model.path to its folder") \
            from None
    except SystemExit as err:  # sys.exit() at import would end stepzoo with its status
        raise UsageError(f"{source}: the model module {module_name!r} exited during import "
                         f"(SystemExit {err.code!r}); a model module defines functions, it "
                         "does not run a program at import") from None
    except Exception as err:   # the user's module failing at import: say so in one line
        raise UsageError(f"{source}: importing {module_name!r} failed: "
                         f"{type(err).__name__}: {err}") from None
    finally:
        sys.path.remove(str(folder))
    _shadowed(module, module_name, folder, source, key)
    return module


def _shadowed(module, module_name: str, folder: Path, source: str, key: str):
    """UsageError when `folder` holds the module's file but the import found another module
    of that name (Python's own, or one imported or installed earlier): the model would be
    looked up in the wrong module."""
    top = module_name.split(".")[0]
    mine = [folder / f"{top}.py", folder / top]
    if not any(p.exists() for p in mine):
        return
    found = getattr(module, "__file__", None)
    if found and Path(found).resolve().is_relative_to(folder.resolve()):
        return
    whose = "Python's standard module" if top in sys.stdlib_module_names else "the module"
    raise UsageError(f"{source}: model.{key} names module {top!r}, but "
                     f"{folder / (top + '.py')} is shadowed by {whose} {top!r} "
                     f"({found or 'built in'}); rename your file (and model.{key}) to a name "
                     "of its own")


class _Quiet:
    """A user's f(t, x, u, p) whose prints go to stderr. Equal to, and hashed as, another of
    the same f, and pickled (for a Dask worker) as f itself: JAX's compiled programs, cached
    by function, serve every load of the model."""

    def __init__(self, fn):
        self.fn = fn
        functools.update_wrapper(self, fn)

    def __call__(self, t, x, u, p):
        with prints_to_stderr():
            return self.fn(t, x, u, p)

    def __eq__(self, other):
        return isinstance(other, _Quiet) and other.fn == self.fn

    def __hash__(self):
        return hash(self.fn)

    def __reduce__(self):
        return _Quiet, (self.fn,)


def check_rhs(spec: ModelSpec, source: str):
    """Trace the right-hand side once: it must return one real derivative per state, its
    parameters may not be named like a state or input (an envelope over the name would vary
    the parameter alone), and an envelope over a parameter it never reads is a warning on
    stderr."""
    import jax
    import jax.numpy as jnp
    for name, _ in spec.params:
        if name in spec.states or name in spec.inputs:
            what = "state" if name in spec.states else "input"
            raise UsageError(f"{source}: params.{name} has the name of a {what} of "
                             f"{spec.name}; an envelope over {name!r} would vary the "
                             "parameter alone: rename the parameter")
    x0, u, p = spec.arrays(spec.points[:1])
    args = (0.0, jnp.asarray(x0[0]), jnp.asarray(u[0]), {k: v[0] for k, v in p.items()})
    try:
        out = jax.eval_shape(spec.rhs, *args)
    except Exception as err:   # any failure of the user's code while tracing
        first = str(err).splitlines()[0] if str(err) else ""
        raise UsageError(f"{source}: model {spec.name} fails on its initial state of "
                         f"{len(spec.states)} states (model.states): {type(err).__name__}: "
                         f"{first}") from None
    shape = getattr(out, "shape", None)
    if shape != (len(spec.states),):
        raise UsageError(f"{source}: model {spec.name} returns shape {shape}, but model.states "
                         f"names {len(spec.states)} states; return one derivative per state")
    if jnp.issubdtype(out.dtype, jnp.complexfloating):
        raise UsageError(f"{source}: model {spec.name} returns complex values ({out.dtype}); "
                         "the integrators take real states: return real derivatives (a "
                         "complex state as two real states, its real and imaginary parts)")
    for name in unread_params(spec, args):
        sys.stderr.write(f"{source}: warning: the envelope varies params.{name}, which model "
                         f"{spec.name} never reads: every value of it gives the same results\n")


def unread_params(spec: ModelSpec, args) -> list[str]:
    """The envelope's parameters that the right-hand side's output does not depend on, found
    by tracing it: a parameter counts as read when any operation that leads to the output
    takes it (an operation with a sub-program counts all its inputs, so nothing read is
    ever reported)."""
    import jax
    from jax.extend.core import Var
    unread = []
    t, x, u, p = args
    for name in (v for v in spec.variables if spec.kind(v) == "param"):
        def of_one(value, name=name):
            return spec.rhs(t, x, u, {**p, name: value})
        closed = jax.make_jaxpr(of_one)(p[name])
        jaxpr = closed.jaxpr
        needed = {v for v in jaxpr.outvars if isinstance(v, Var)}
        for eqn in reversed(jaxpr.eqns):
            if needed.intersection(eqn.outvars):
                needed.update(v for v in eqn.invars if isinstance(v, Var))
        if jaxpr.invars[0] not in needed:
            unread.append(name)
    return unread
