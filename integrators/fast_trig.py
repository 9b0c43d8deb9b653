"""Vectorisable sin and cos: a Cody-Waite range reduction and Taylor polynomials in plain
multiply-adds, which XLA on CPU vectorises across a batch (its own sin and cos are scalar
libm calls, ~12 ns each, in float64 and float32 alike). The reduction of sin(a) and cos(a) is
the same expression, so XLA computes it once. Each dtype works in its own precision.

The polynomials are within a few ulp of libm for |a| < `BOUND[dtype]`, and return NaN for NaN
and inf as libm does; beyond the bound the reduction loses digits. `fast_trig(f)` uses them
unguarded (opt-in). `flagged_trig(fn)` uses them and also says whether any finite argument
reached the bound, so that the driver can redo that chunk with libm: exact for every
argument, with no guard on the fast path but one flag."""
from fractions import Fraction
from functools import cache, reduce, wraps
from math import factorial

import jax
import jax.extend.core as jcore
import jax.numpy as jnp
import numpy as np
from jax import lax

_HALF_PI = Fraction("1.57079632679489661923132169163975144209858469968755291048747229615390820")
# pi/2 as parts of `bits` significant bits then a full-precision tail: k * part is exact while
# |k| < 2**(mantissa - bits), so a - k pi/2 keeps full precision for |a| < BOUND.
_PARTS = {np.dtype(np.float64): (33, 2), np.dtype(np.float32): (12, 4)}
BOUND = {np.dtype(np.float64): 2.0 ** 20, np.dtype(np.float32): 2.0 ** 12}   # [rad]
# Taylor terms: on |r| <= pi/4 the first omitted one is under half an ulp of the result
# (float64: r**19/19! < 1e-19; float32: r**13/13! < 1e-11).
_TERMS = {np.dtype(np.float64): 9, np.dtype(np.float32): 6}


def _parts(dtype):
    bits, n = _PARTS[dtype]
    parts, rest = [], _HALF_PI
    for _ in range(n):
        e = rest.numerator.bit_length() - rest.denominator.bit_length()
        scale = Fraction(2) ** (bits - 1 - e)
        part = Fraction(int(rest * scale)) / scale      # rest truncated to `bits` bits
        parts.append(float(part))
        rest -= part
    return parts + [float(rest)]


def _horner(coeffs, z):
    acc = jnp.full_like(z, coeffs[-1])
    for c in reversed(coeffs[:-1]):
        acc = acc * z + c
    return acc


def _reduced(a):
    """(sin r, cos r, quadrant) with a = k pi/2 + r, |r| <= pi/4, quadrant = k mod 4 (as a
    float, exact for any integral k)."""
    dt = np.dtype(a.dtype)
    k = jnp.round(a * (2 / np.pi))
    r = a
    for part in _parts(dt):
        r = r - k * part
    z = r * r
    n = _TERMS[dt]
    s = [(-1.0) ** j / factorial(2 * j + 1) for j in range(n)]
    c = [(-1.0) ** j / factorial(2 * j) for j in range(n + 1)]
    return r * _horner(s, z), _horner(c, z), k - 4 * jnp.floor(k * 0.25)


def _sincos(a):
    s, c, q = _reduced(a)
    return (jnp.where(q == 0, s, jnp.where(q == 1, c, jnp.where(q == 2, -s, -c))),
            jnp.where(q == 0, c, jnp.where(q == 1, -s, jnp.where(q == 2, -c, s))))


def _vectorisable(a):
    return np.dtype(jnp.result_type(a)) in BOUND


def sin(a):
    return _sincos(a)[0] if _vectorisable(a) else lax.sin(a)


def cos(a):
    return _sincos(a)[1] if _vectorisable(a) else lax.cos(a)


def beyond_bound(a):
    """Which finite elements of a have |a| >= BOUND."""
    mag = jnp.abs(a)
    return (mag >= BOUND[np.dtype(a.dtype)]) & (mag < jnp.inf)


def _eval(jaxpr, consts, args, flags):
    """Evaluate a jaxpr with the vectorisable sin and cos, once per argument, recursing into
    nested jaxprs of jit and into while loops' bodies (an implicit step's Newton iterations).
    With `flags` (a list), each sin or cos argument's elements at or beyond the bound are
    appended to it."""
    env, shared = {}, {}

    def read(v):
        return v.val if isinstance(v, jcore.Literal) else env[v]

    env.update(zip(jaxpr.constvars, consts))
    env.update(zip(jaxpr.invars, args))
    for eqn in jaxpr.eqns:
        ins = [read(v) for v in eqn.invars]
        if eqn.primitive in (lax.sin_p, lax.cos_p):
            if id(ins[0]) not in shared:    # keeps ins[0] alive, so its id stays unique
                if flags is not None and _vectorisable(ins[0]):
                    flags.append(beyond_bound(ins[0]).ravel())
                shared[id(ins[0])] = (ins[0], _vector_sincos(ins[0]))
            outs = [shared[id(ins[0])][1][eqn.primitive is lax.cos_p]]
        elif eqn.primitive.name in ("pjit", "jit"):
            inner = eqn.params["jaxpr"]
            outs = _eval(inner.jaxpr, inner.consts, ins, flags)
        elif eqn.primitive.name == "while":
            outs = _while(eqn.params, ins, flags)
        else:
            outs = eqn.primitive.bind(*ins, **eqn.params)
            outs = outs if eqn.primitive.multiple_results else [outs]
        env.update(zip(eqn.outvars, outs))
    return [read(v) for v in jaxpr.outvars]


def _while(params, ins, flags):
    """A while loop with the vectorisable sin and cos in its body; with `flags`, whether any
    of their arguments in any iteration reached the bound is carried through the loop and
    appended once. The condition keeps libm's (it has no way to report one). A vmapped loop
    has a predicate per trajectory: it runs while any holds, each trajectory's carry kept
    where its own does not, as XLA lowers it."""
    n_cond, n_body = params["cond_nconsts"], params["body_nconsts"]
    cond_consts, body_consts = ins[:n_cond], ins[n_cond:n_cond + n_body]
    cond_j, body_j = params["cond_jaxpr"], params["body_jaxpr"]

    def pred(values):
        return jax.core.eval_jaxpr(cond_j.jaxpr, cond_j.consts, *cond_consts, *values)[0]

    def body(carry):
        values, far = carry
        inner = None if flags is None else []
        new = _eval(body_j.jaxpr, body_j.consts, [*body_consts, *values], inner)
        go = pred(values)
        if go.ndim:
            new = [jnp.where(go.reshape(go.shape + (1,) * (v.ndim - go.ndim)), n, v)
                   for n, v in zip(new, values)]
        return new, far | jnp.any(jnp.concatenate(inner)) if inner else far

    init = ins[n_cond + n_body:]
    # Like the carry's values, so that under shard_map the flag varies as they do.
    none = reduce(jnp.logical_or, [jnp.zeros_like(v, bool, shape=()) for v in init])
    values, far = lax.while_loop(lambda carry: jnp.any(pred(carry[0])), body, (init, none))
    if flags is not None:
        flags.append(far.ravel())
    return values


def _rewritten(f, args, flags):
    closed, shape = jax.make_jaxpr(f, return_shape=True)(*args)
    outs = _eval(closed.jaxpr, closed.consts, jax.tree.leaves(args), flags)
    return jax.tree.unflatten(jax.tree.structure(shape), outs)


def _vector_sincos(a):
    return _sincos(a) if _vectorisable(a) else (lax.sin(a), lax.cos(a))


@cache
def fast_trig(f):
    """f(t, x, u, p) with the unguarded vectorisable sin and cos; cached, so the result is one
    static function for `jax.jit` (the driver compiles once per f)."""
    @wraps(f)
    def g(*args):
        return _rewritten(f, args, None)
    return g


def flagged_trig(fn):
    """fn with vectorisable sin and cos, returning (fn's value, whether any of their finite
    arguments reached the bound, or None if fn has none). For a function of whole arrays
    such as a batched step."""
    @wraps(fn)
    def g(*args):
        far = []
        out = _rewritten(fn, args, far)
        # One reduction for all calls: each one alone was a separate loop kernel on XLA:CPU.
        return out, jnp.any(jnp.concatenate(far)) if far else None
    return g
