"""A JAX right-hand side f(t, x, u, p) of a few states as one straight-line Python function of
floats: its float64 jaxpr traced once, every element of every array a Python float, each
instruction a float operation (`math` for sin, cos and the like). SciPy's solvers call it
in microseconds where a jitted function's dispatch costs tens; the values agree with XLA's
to rounding (libm's and XLA's sin and cos differ by an ulp). A function with an instruction
outside this small set, or arrays of more than one axis, raises ValueError."""
from __future__ import annotations

import math

import numpy as np

_UNARY = {"neg": "(-{0})", "sin": "_m.sin({0})", "cos": "_m.cos({0})", "tan": "_m.tan({0})",
          "asin": "_m.asin({0})", "acos": "_m.acos({0})", "atan": "_m.atan({0})",
          "sinh": "_m.sinh({0})", "cosh": "_m.cosh({0})", "tanh": "_m.tanh({0})",
          "exp": "_m.exp({0})", "log": "_m.log({0})", "sqrt": "_m.sqrt({0})",
          "abs": "abs({0})", "sign": "_sign({0})", "floor": "_m.floor({0})",
          "ceil": "_m.ceil({0})"}
_BINARY = {"add": "({0} + {1})", "sub": "({0} - {1})", "mul": "({0} * {1})",
           "div": "({0} / {1})", "pow": "({0} ** {1})", "atan2": "_m.atan2({0}, {1})",
           "max": "max({0}, {1})", "min": "min({0}, {1})"}


def _sign(a: float) -> float:
    return float(np.sign(a))


def _rank(var) -> int:
    return len(var.aval.shape)


class _Writer:
    """The function's lines; each jaxpr variable a list of the names of its elements."""

    def __init__(self):
        self.lines, self.env, self.count = [], {}, 0

    def name(self, expr: str) -> str:
        self.count += 1
        self.lines.append(f"    v{self.count} = {expr}")
        return f"v{self.count}"

    def read(self, var) -> list[str]:
        if hasattr(var, "val"):     # a literal
            return [repr(float(v)) for v in np.ravel(var.val)]
        return self.env[var]

    def write(self, jaxpr, ins: list[list[str]]) -> list[list[str]]:
        self.env.update(zip(jaxpr.invars, ins))
        for eqn in jaxpr.eqns:
            if any(_rank(v) > 1 for v in [*eqn.invars, *eqn.outvars]):
                raise ValueError(f"{eqn.primitive}: arrays of more than one axis")
            outs = self._eqn(eqn, [self.read(v) for v in eqn.invars])
            self.env.update(zip(eqn.outvars, outs))
        return [self.read(v) for v in jaxpr.outvars]

    def _eqn(self, eqn, ins) -> list[list[str]]:
        name, par = eqn.primitive.name, eqn.params
        size = int(np.prod(eqn.outvars[0].aval.shape)) if eqn.outvars else 0
        if name in ("pjit", "jit", "closed_call"):
            inner = par.get("jaxpr") or par["call_jaxpr"]
            if getattr(inner, "consts", None):
                raise ValueError("a nested function with constants")
            return self.write(getattr(inner, "jaxpr", inner), ins)
        if name in _UNARY or name in _BINARY or name == "integer_pow":
            # Elementwise: a scalar operand broadcast against the other's elements.
            full = [a * size if len(a) == 1 else a for a in ins]
            if name == "integer_pow":
                y = par["y"]
                pattern = "({0} * {0})" if y == 2 else f"({{0}} ** {y})"
            else:
                pattern = _UNARY.get(name) or _BINARY[name]
            return [[self.name(pattern.format(*args)) for args in zip(*full)]]
        if name == "slice":
            (a,), (lo,), (hi,) = ins, par["start_indices"], par["limit_indices"]
            step = (par["strides"] or (1,))[0]
            return [a[lo:hi:step]]
        if name in ("squeeze", "reshape", "convert_element_type", "copy", "copy_p"):
            if name == "convert_element_type" and par["new_dtype"] != np.float64:
                raise ValueError(f"conversion to {par['new_dtype']}")
            return [ins[0]]
        if name == "broadcast_in_dim":
            return [ins[0] * size if len(ins[0]) == 1 else ins[0]]
        if name in ("concatenate", "stack"):
            return [[e for a in ins for e in a]]
        raise ValueError(f"no float code for {name}")


def scalar_function(f, n: int, k: int, keys: tuple[str, ...]):
    """f(t, x, u, p) for x of n and u of k floats and p a dict of floats with these keys, as
    a Python function g(t, x, u, pv) of floats and sequences of floats, pv p's values in the
    order of `keys`, returning f's value as a float64 array. Traced once, in float64."""
    import jax
    with jax.enable_x64(True):
        closed = jax.make_jaxpr(lambda t, x, u, *pv: f(t, x, u, dict(zip(keys, pv))))(
            0.0, np.zeros(n), np.zeros(k), *(0.0 for _ in keys))
    if closed.consts:
        raise ValueError("a function with captured arrays")
    writer = _Writer()
    ins = [["t"], [f"x[{i}]" for i in range(n)], [f"u[{i}]" for i in range(k)],
           *[[f"pv[{i}]"] for i in range(len(keys))]]
    outs = writer.write(closed.jaxpr, ins)
    if len(outs) != 1:
        raise ValueError("a function of more than one result")
    body = "\n".join(writer.lines)
    source = (f"def scalar_rhs(t, x, u, pv):\n{body}\n"
              f"    return _np.array([{', '.join(outs[0])}])\n")
    scope = {"_m": math, "_np": np, "_sign": _sign}
    exec(compile(source, "<scalar_rhs>", "exec"), scope)
    return scope["scalar_rhs"]
