"""A CasADi function as JAX: the instructions of its scalar (SX) expression graph replayed
as jnp operations, so that jit, vmap and jacfwd see through it as through any JAX model.
Constants keep every bit; an operation without a JAX counterpart raises ValueError."""
from __future__ import annotations

from typing import Callable

import numpy as np


def _ops() -> dict:
    """CasADi's scalar operation codes -> (name, jnp function of the operands)."""
    import casadi as ca
    import jax.numpy as jnp
    from jax.scipy import special

    def flag(c):
        # CasADi's comparisons and logic give 1 or 0 in the float work vector.
        return jnp.where(c, 1.0, 0.0)

    table = {
        "ASSIGN": lambda a: a, "ADD": lambda a, b: a + b, "SUB": lambda a, b: a - b,
        "MUL": lambda a, b: a * b, "DIV": lambda a, b: a / b, "NEG": lambda a: -a,
        "EXP": jnp.exp, "LOG": jnp.log, "POW": jnp.power, "CONSTPOW": jnp.power,
        "SQRT": jnp.sqrt, "SQ": lambda a: a * a, "TWICE": lambda a: 2.0 * a,
        "SIN": jnp.sin, "COS": jnp.cos, "TAN": jnp.tan, "ASIN": jnp.arcsin,
        "ACOS": jnp.arccos, "ATAN": jnp.arctan, "ATAN2": jnp.arctan2,
        "SINH": jnp.sinh, "COSH": jnp.cosh, "TANH": jnp.tanh, "ASINH": jnp.arcsinh,
        "ACOSH": jnp.arccosh, "ATANH": jnp.arctanh, "INV": lambda a: 1.0 / a,
        "LT": lambda a, b: flag(a < b), "LE": lambda a, b: flag(a <= b),
        "EQ": lambda a, b: flag(a == b), "NE": lambda a, b: flag(a != b),
        "NOT": lambda a: flag(a == 0), "AND": lambda a, b: flag((a != 0) & (b != 0)),
        "OR": lambda a, b: flag((a != 0) | (b != 0)),
        "IF_ELSE_ZERO": lambda c, a: jnp.where(c != 0, a, 0.0),
        "FLOOR": jnp.floor, "CEIL": jnp.ceil, "FMOD": jnp.fmod,
        # C's remainder: the quotient rounded to the nearest integer, ties to even.
        "REMAINDER": lambda a, b: a - b * jnp.round(a / b),
        "FABS": jnp.abs, "SIGN": jnp.sign, "COPYSIGN": jnp.copysign,
        "FMIN": jnp.minimum, "FMAX": jnp.maximum, "HYPOT": jnp.hypot,
        "LOG1P": jnp.log1p, "EXPM1": jnp.expm1, "ERF": special.erf, "ERFINV": special.erfinv,
    }
    return {getattr(ca, f"OP_{name}"): (name, fn) for name, fn in table.items()
            if hasattr(ca, f"OP_{name}")}


def _names() -> dict:
    import casadi as ca
    return {getattr(ca, n): n[3:] for n in dir(ca) if n.startswith("OP_")}


def scalar_form(fn):
    """`fn` as an SX function (an MX one expanded); ValueError when it cannot be."""
    if fn.is_a("SXFunction"):
        return fn
    try:
        return fn.expand()
    except RuntimeError as err:
        first = str(err).strip().splitlines()[-1] if str(err).strip() else ""
        raise ValueError(f"CasADi function {fn.name()!r} cannot be expanded to scalar "
                         f"operations (SX): {first}") from None


# The most scalar instructions translated: each becomes one jnp operation, and XLA's time to
# compile the resulting graph grows faster than its size (a stiff model's Jacobian and every
# stage of a method multiply it), so that a long chain took tens of minutes or crashed its
# compiler (SIGSEGV) with no word; docs/studies/hostile-limits-2026-11-28.md.
MAX_INSTRUCTIONS = 2000


def program(fn) -> tuple[list, list]:
    """(instructions [(code, outputs, inputs, constant)], dense positions of every output's
    nonzeros) of an SX function; ValueError naming an operation JAX has no counterpart of, or
    a function of more than MAX_INSTRUCTIONS instructions."""
    import casadi as ca
    if fn.n_instructions() > MAX_INSTRUCTIONS:
        raise ValueError(f"CasADi function {fn.name()!r} has {fn.n_instructions()} scalar "
                         f"instructions, more than the {MAX_INSTRUCTIONS} whose JAX "
                         "translation compiles in reasonable time; shorten it (common "
                         "subexpressions: casadi.cse), or write the model in JAX")
    ops = _ops()
    steps = []
    for k in range(fn.n_instructions()):
        code = fn.instruction_id(k)
        if code not in ops and code not in (ca.OP_CONST, ca.OP_INPUT, ca.OP_OUTPUT):
            raise ValueError(f"CasADi function {fn.name()!r} uses operation "
                             f"{_names().get(code, code)}, which has no JAX translation here")
        const = fn.instruction_constant(k) if code == ca.OP_CONST else None
        steps.append((code, tuple(fn.instruction_output(k)), tuple(fn.instruction_input(k)),
                      const))
    positions = [np.asarray(fn.sparsity_out(i).find(), int) for i in range(fn.n_out())]
    return steps, positions


def to_jax(fn) -> Callable:
    """A pure JAX function of fn's inputs (each a dense array of that input's numel, in
    column-major order), returning the list of fn's outputs as dense column-major vectors in
    the inputs' dtype. `fn` is a casadi.Function (MX ones are expanded first)."""
    import casadi as ca
    fn = scalar_form(fn)
    steps, positions = program(fn)
    ops = _ops()
    sizes = [fn.numel_out(i) for i in range(fn.n_out())]
    n_work = fn.sz_w()

    def evaluate(*args):
        import jax.numpy as jnp
        dtype = jnp.result_type(float, *args)     # a float, the inputs' own if they are
        inputs = [jnp.ravel(jnp.asarray(a, dtype)) for a in args]
        work = [None] * n_work
        outs = [[jnp.zeros((), dtype)] * n for n in sizes]
        for code, o, i, const in steps:
            if code == ca.OP_CONST:
                work[o[0]] = jnp.asarray(const, dtype)
            elif code == ca.OP_INPUT:
                work[o[0]] = inputs[i[0]][i[1]]
            elif code == ca.OP_OUTPUT:
                outs[o[0]][positions[o[0]][o[1]]] = work[i[0]]
            else:
                work[o[0]] = jnp.asarray(ops[code][1](*(work[j] for j in i)), dtype)
        return [jnp.stack(v) if v else jnp.zeros((0,), dtype) for v in outs]
    return evaluate


ROLES = ("x", "u", "p", "t")       # what the function's inputs may be, in this order


def roles(fn) -> tuple:
    """What each input of `fn` is: by name when every input is named x, u, p or t, else by
    position in the order of ROLES."""
    names = tuple(fn.name_in())
    if set(names) <= set(ROLES) and len(set(names)) == len(names):
        return names
    return ROLES[: fn.n_in()]


def rhs(fn, n_states: int, n_inputs: int, p_names: tuple = ()) -> Callable:
    """f(t, x, u, p) -> dx/dt of a casadi.Function of x, u (and optionally p, a vector of
    the parameters `p_names` in order, and t [s]) whose first output is dx/dt; ValueError
    (one line) when its inputs or output do not fit n_states, n_inputs and p_names."""
    if fn.n_in() > len(ROLES) or fn.n_out() < 1:
        raise ValueError(f"CasADi function {fn.name()!r} has {fn.n_in()} inputs and "
                         f"{fn.n_out()} outputs; give inputs x, u (and optionally p, t) and "
                         "dx/dt as its first output")
    role = roles(fn)
    want = {"x": n_states, "u": n_inputs, "p": len(p_names), "t": 1}
    for needed in ("x", "u", "p"):
        if needed not in role and want[needed]:
            raise ValueError(f"CasADi function {fn.name()!r} takes inputs {list(fn.name_in())}"
                             f", none of them {needed} ({want[needed]} values); give inputs "
                             "named x, u, p, t or in that order")
    for k, r in enumerate(role):
        sp = fn.sparsity_in(k)
        if not (sp.is_dense() and sp.is_vector() or sp.numel() == 0) \
                or sp.numel() != want[r]:
            raise ValueError(f"CasADi function {fn.name()!r}: input {k} ({r}, "
                             f"{fn.name_in(k)!r}) is {sp.size1()}x{sp.size2()}"
                             f"{'' if sp.is_dense() else ' sparse'}, but the model has "
                             f"{want[r]} {'values' if r != 't' else 'value (time [s])'} "
                             f"of {r}; give a dense vector of that size")
    if fn.numel_out(0) != n_states or not fn.sparsity_out(0).is_vector():
        raise ValueError(f"CasADi function {fn.name()!r}: output 0 is "
                         f"{fn.size1_out(0)}x{fn.size2_out(0)}, but the model has "
                         f"{n_states} states; return dx/dt as a vector of that size")
    evaluate = to_jax(fn)
    names = tuple(p_names)

    def casadi_rhs(t, x, u, p):
        """dx/dt of the CasADi function, from x, u, the parameters p [name] and t [s]."""
        import jax.numpy as jnp
        given = {"x": x, "u": u, "t": jnp.reshape(t, (1,)),
                 "p": jnp.stack([jnp.asarray(p[k]) for k in names]) if names
                 else jnp.zeros((0,))}
        return evaluate(*(given[r] for r in role))[0].astype(jnp.result_type(x))
    return casadi_rhs
