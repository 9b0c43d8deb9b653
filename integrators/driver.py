"""The one driver: `lax.scan` over fixed steps, batched with `vmap` over initial states, inputs
and parameters. Everything that integrates with a fixed step goes through `integrate`.

With `max_steps` given, the step count may be a run-time value: the scan runs in blocks of
`BLOCK` steps inside a loop, so one compilation serves every step size (output rows past the
last step are NaN)."""
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

BLOCK = 32


class Trajectory(NamedTuple):
    t: jax.Array       # [s], shape (N+1,)
    x: jax.Array       # states, shape (N+1, d); NaN rows past the last step
    evals: jax.Array   # right-hand-side evaluations spent


def _bound(f, u, p):
    return lambda t, y: f(t, y, u, p)


def _integrate(method, f, x0, u, p, h, n_steps, t0, max_steps):
    fun = _bound(f, u, p)
    h = jnp.asarray(h, x0.dtype)
    m = method.n_start
    ys0, state = method.start(fun, t0, x0, h)
    y_m = ys0[-1] if m else x0

    def body(carry, _):
        k, y, st = carry
        y, st = method.step(fun, t0 + k * h, y, h, st)
        return (k + 1, y, st), y

    if max_steps is None:
        count = max(n_steps - m, 0)
        (_, _, state), ys = lax.scan(body, (m, y_m, state), None, length=count)
        xs = jnp.concatenate([x0[None], ys0, ys])[: n_steps + 1]
        if n_steps < m:
            state = dict(state, evals=jnp.nan)
    else:
        xs, state = _blocked(body, method, x0, ys0, y_m, state, n_steps, max_steps)
    ts = t0 + h * jnp.arange(xs.shape[0])
    return Trajectory(ts, xs, state["evals"])


def _blocked(body, method, x0, ys0, y_m, state, n_steps, max_steps):
    """Run-time step count: blocks of BLOCK steps; steps past n_steps leave the carry alone."""
    m = method.n_start
    n_blocks_max = -(-(max_steps - m) // BLOCK)
    buf = jnp.full((n_blocks_max * BLOCK, x0.shape[0]), jnp.nan, x0.dtype)

    def masked(carry, x):
        new, y = body(carry, x)
        active = carry[0] < n_steps
        new = jax.tree.map(lambda a, b: jnp.where(active, a, b), new, carry)
        return new, jnp.where(active, y, jnp.nan)

    def block(i, c):
        carry, buf = c
        carry, ys = lax.scan(masked, carry, None, length=BLOCK)
        return carry, lax.dynamic_update_slice(buf, ys, (i * BLOCK, 0))

    n_blocks = (jnp.maximum(n_steps - m, 0) + BLOCK - 1) // BLOCK
    (_, _, state), buf = lax.fori_loop(0, n_blocks, block, ((m, y_m, state), buf))
    xs = jnp.concatenate([x0[None], ys0, buf])[: max_steps + 1]
    rows = jnp.arange(max_steps + 1)[:, None]
    return jnp.where(rows <= n_steps, xs, jnp.nan), state


def _batch(method, f, x0, u, p, h, n_steps, t0, max_steps):
    one = lambda x, uu, pp, hh: _integrate(method, f, x, uu, pp, hh, n_steps, t0, max_steps)
    return jax.vmap(one, in_axes=(0, 0, 0, 0 if jnp.ndim(h) else None))(x0, u, p, h)


_STATIC = ("method", "f", "n_steps", "max_steps")
_DYNAMIC = ("method", "f", "max_steps")
_jitted = {(fn, dyn): jax.jit(fn, static_argnames=_DYNAMIC if dyn else _STATIC)
           for fn in (_integrate, _batch) for dyn in (False, True)}


def integrate(method, f, x0, u, p, h, n_steps, t0=0.0, max_steps=None) -> Trajectory:
    """Integrate dx/dt = f(t, x, u, p) from (t0, x0) with `n_steps` steps of size h [s].

    `n_steps` is a Python int (compiled in), or, with `max_steps` a Python int bound, a
    run-time integer: then one compilation serves every step count up to max_steps."""
    fn = _jitted[(_integrate, max_steps is not None)]
    return fn(method, f, x0, u, p, h, n_steps, t0, max_steps)


def integrate_batch(method, f, x0, u, p, h, n_steps, t0=0.0, max_steps=None) -> Trajectory:
    """`integrate` vmapped over the leading axis of x0, u and every leaf of p, and of h when
    h is an array (one step size per trajectory); t0 and the step count are shared."""
    fn = _jitted[(_batch, max_steps is not None)]
    return fn(method, f, x0, u, p, h, n_steps, t0, max_steps)
