"""Where a model's right-hand side is not finite: per operating point, the first time [s] on
its reference at which f(t, x, u, p) or df/dx is NaN or infinite at a finite state. Such a
point is a result ("model returned NaN at t = ..."), recorded beside the others, not a crash:
it has no stable step to measure or predict."""
from __future__ import annotations

from functools import cache

import numpy as np

COLUMN = "model_nan_t"       # [s] the limits table's column; NaN where the model is finite
PREFIX = "model returned NaN"


def cause(t: float) -> str:
    """The limit's cause at a point where the model stops being finite at time t [s]."""
    return f"{PREFIX} at t = {t:g} s"


@cache
def _values(f):
    """Jitted f over a (B, T) grid: times ts (T,), states xs (B, T, n), u (B, m), p {k: (B,)}."""
    import jax
    over_t = jax.vmap(f, in_axes=(0, 0, None, None))
    return jax.jit(jax.vmap(over_t, in_axes=(None, 0, 0, 0)))


def first_times(f, ts, xs, u, p, jac) -> np.ndarray:
    """(B,) the first of the times ts (T,) [s] at which f or its Jacobians jac (B, T, n, n)
    are not finite at a finite state of xs (B, T, n); NaN for a lane finite throughout. A
    state that is itself not finite is the reference's failure, which ref_ok records."""
    import jax.numpy as jnp
    values = np.asarray(_values(f)(jnp.asarray(ts), jnp.asarray(xs), jnp.asarray(u),
                                   {k: jnp.asarray(v) for k, v in p.items()}))
    bad = np.isfinite(xs).all(axis=-1) & ~(np.isfinite(values).all(axis=-1)
                                           & np.isfinite(jac).all(axis=(-1, -2)))
    return np.where(bad.any(axis=1), np.asarray(ts)[np.argmax(bad, axis=1)], np.nan)


def lane_times(work) -> np.ndarray:
    """`first_times` of a sweep block's lanes (a bench.sweep.block.Block) along its reference."""
    def make():
        along = work.along()
        return first_times(work.spec.rhs, along.ts, along.xs, work.points.u, work.points.p,
                           along.jac)
    return work.cached(COLUMN, make)


def record(limits: list[dict], times) -> None:
    """Each limits row (one per lane, in order) gets its model_nan_t; where the model is not
    finite, the cause says so and neither limit is a number (none was measured or can be
    predicted: every step 'blows up' on the model's own NaN)."""
    for row, t in zip(limits, times):
        row[COLUMN] = t
        if np.isfinite(t):
            row.update(limit_cause=cause(t), h_meas=np.nan, h_pred=np.nan, ratio=np.nan)


def note(limits, variables) -> str:
    """One line on the points where the model returned NaN ('' where none did), for a
    command's summary: how many, and the first few of them with their times."""
    if COLUMN not in limits:
        return ""
    bad = limits[np.isfinite(limits[COLUMN].to_numpy(float))].drop_duplicates("point")
    if bad.empty:
        return ""
    shown = "; ".join(", ".join(f"{v} = {r[v]:g}" for v in variables) + f" (t = {r[COLUMN]:g} s)"
                      for _, r in bad.head(3).iterrows())
    more = f"; and {len(bad) - 3} more" if len(bad) > 3 else ""
    return (f"model returned NaN at {len(bad)} of {limits['point'].nunique()} operating points: "
            f"{shown}{more}; their limits are NaN, limit_cause says so")
