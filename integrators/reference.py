"""The reference: adaptive Dormand-Prince 5(4) with PI step-size control, stepping exactly
onto every requested output time (no interpolation error), with step statistics.

Error norm: RMS of (y5 - y4) / (atol + rtol * max(|y|, |y_next|)); a step is accepted when
it is <= 1. PI control (Gustafsson): h_next = h * 0.9 * err^-(0.7/5) * err_prev^(0.4/5),
clipped to [0.2, 10]; after a rejection the step may only shrink."""
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from stepzoo.integrators import arguments
from stepzoo.integrators.methods import TABLEAUS
from stepzoo.integrators.steps import rk_slopes, weighted

_TAB = TABLEAUS["dopri5"]
SAFETY, FAC_MIN, FAC_MAX = 0.9, 0.2, 10.0
K_I, K_P = 0.7 / 5, 0.4 / 5


class Reference(NamedTuple):
    t: jax.Array          # requested times [s]
    x: jax.Array          # (len(t), d) states at those times
    accepted: jax.Array   # accepted steps
    rejected: jax.Array   # rejected steps
    evals: jax.Array      # right-hand-side evaluations
    success: jax.Array    # False if max_steps ran out or the solution left the finite range


def _dp_step(fun, t, y, f0, h):
    """One Dormand-Prince step with FSAL slope f0: (y5, error vector, slope at the end)."""
    k = rk_slopes(_TAB.a, _TAB.c, fun, t, y, h, k0=f0)
    return y + h * weighted(_TAB.b, k), h * weighted(_TAB.e, k), k[-1]


def _initial_step(fun, t0, y0, f0, rtol, atol):
    """Hairer-Norsett-Wanner starting step for a fifth-order method."""
    scale = atol + rtol * jnp.abs(y0)
    d0 = jnp.sqrt(jnp.mean((y0 / scale) ** 2))
    d1 = jnp.sqrt(jnp.mean((f0 / scale) ** 2))
    h0 = jnp.where((d0 < 1e-5) | (d1 < 1e-5), 1e-6, 0.01 * d0 / d1)
    f1 = fun(t0 + h0, y0 + h0 * f0)
    d2 = jnp.sqrt(jnp.mean(((f1 - f0) / scale) ** 2)) / h0
    h1 = jnp.where(jnp.maximum(d1, d2) <= 1e-15, jnp.maximum(1e-6, h0 * 1e-3),
                   (0.01 / jnp.maximum(d1, d2)) ** (1 / 5))
    return jnp.minimum(100 * h0, h1)


def reference(f, x0, u=None, p=None, ts=None, rtol=1e-10, atol=1e-12,
              max_steps=100_000) -> Reference:
    """Solve dx/dt = f(t, x, u, p) from (ts[0], x0) and return x at every time of `ts`
    (sorted, non-decreasing [s]) to the tolerances rtol, atol, in x0's float dtype (the
    default rtol needs float64). Arguments as for `integrate`; bad ones raise ValueError or
    TypeError naming them.

    >>> import jax.numpy as jnp
import numpy as np
    >>> vdp = lambda t, x, u, p: jnp.stack([x[1], p * (1 - x[0] ** 2) * x[1] - x[0]])
    >>> ref = reference(vdp, [2.0, 0.0], p=1.0, ts=jnp.linspace(0.0, 10.0, 11), rtol=1e-6)
    >>> bool(ref.success), ref.x.shape
    (True, (11, 2))
    """
    arguments.check_rhs(f)
    x0, scalar = arguments.state(x0, batched=False)
    if ts is None or np.ndim(ts) != 1 or np.shape(ts)[0] == 0:
        raise ValueError("ts must be a 1-D array of output times [s], the first the start")
    if not isinstance(ts, jax.core.Tracer):
        times = np.asarray(ts, float)
        if not (np.all(np.isfinite(times)) and np.all(np.diff(times) >= 0)):
            raise ValueError("ts must be finite, non-decreasing times [s]")
    arguments.check_tolerance(rtol, atol, x0.dtype)
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise ValueError(f"max_steps must be a whole number >= 1, got {max_steps!r}")
    ref = _reference(arguments.scalar_rhs(f) if scalar else f, x0, u, p, ts, rtol, atol,
                     max_steps)
    return ref._replace(x=ref.x[..., 0]) if scalar else ref


@partial(jax.jit, static_argnames=("f", "max_steps"))
def _reference(f, x0, u, p, ts, rtol, atol, max_steps) -> Reference:
    """The compiled solve of `reference`, its arguments checked."""
    fun = lambda t, y: jnp.asarray(f(t, y, u, p), y.dtype)
    ts = jnp.asarray(ts, x0.dtype)
    n_out = ts.shape[0]
    f0 = fun(ts[0], x0)
    h0 = _initial_step(fun, ts[0], x0, f0, rtol, atol)
    out = jnp.full((n_out, x0.shape[0]), jnp.nan, x0.dtype)
    idx0 = jnp.sum(ts <= ts[0])                 # outputs at the start time
    out = jnp.where((jnp.arange(n_out) < idx0)[:, None], x0, out)

    def cond(s):
        t, y, fy, h, idx, out, err_prev, acc, rej, ok = s
        return (idx < n_out) & (acc + rej < max_steps) & ok

    def body(s):
        t, y, fy, h, idx, out, err_prev, acc, rej, ok = s
        target = ts[jnp.minimum(idx, n_out - 1)]
        lands = h >= target - t
        h_try = jnp.where(lands, target - t, h)
        y5, e, f5 = _dp_step(fun, t, y, fy, h_try)
        scale = atol + rtol * jnp.maximum(jnp.abs(y), jnp.abs(y5))
        err = jnp.sqrt(jnp.mean((e / scale) ** 2))
        accept = err <= 1.0
        err_safe = jnp.maximum(err, 1e-10)
        fac_acc = SAFETY * err_safe ** (-K_I) * err_prev ** K_P
        fac_rej = SAFETY * err_safe ** (-1 / 5)
        fac = jnp.clip(jnp.where(accept, fac_acc, jnp.minimum(fac_rej, 1.0)), FAC_MIN, FAC_MAX)
        # A step clipped to land on an output time does not shrink the proposal.
        h_next = jnp.where(accept & lands, jnp.maximum(h, h_try * fac), h_try * fac)
        t_new = jnp.where(lands, target, t + h_try)
        landed = accept & lands
        # Every output time equal to the landing time is filled at once.
        fill = landed & (ts == target) & (jnp.arange(n_out) >= idx)
        out = jnp.where(fill[:, None], y5, out)
        ok = jnp.all(jnp.isfinite(y5)) | ~accept
        return (jnp.where(accept, t_new, t), jnp.where(accept, y5, y), jnp.where(accept, f5, fy),
                h_next, idx + jnp.sum(fill), out, jnp.where(accept, err_safe, err_prev),
                acc + accept, rej + (~accept), ok & jnp.isfinite(h_next) & (h_next > 0))

    init = (ts[0], x0, f0, h0, idx0, out, jnp.asarray(1e-4, x0.dtype), jnp.asarray(0),
            jnp.asarray(0), jnp.asarray(True))
    t, y, fy, h, idx, out, _, acc, rej, ok = lax.while_loop(cond, body, init)
    evals = 2 + 6 * (acc + rej)
    return Reference(ts, out, acc, rej, evals, ok & (idx == n_out))
