"""Tight reference solutions for models without a closed form, by SciPy's solve_ivp:
DOP853 for non-stiff problems and LSODA (with the jacfwd Jacobian) for stiff ones, each run
once per model and output grid and kept in memory. LSODA, not Radau: at rtol 1e-13 it meets
the Test Set's published VDPOL and HIRES end values to 1e-11 in seconds, where Radau at
rtol 1e-12 takes 45 s for VDPOL (2e5 evaluations, SciPy's per-step overhead)."""
from functools import lru_cache

import numpy as np

NONSTIFF = dict(method="DOP853", rtol=1e-13, atol=1e-14)
STIFF = dict(method="LSODA", rtol=1e-13, atol=1e-16)


def solve(f, x0, u, p, ts, stiff=False, **options):
    """States (len(ts), n) at the sorted times ts [s], from x0 at ts[0], by solve_ivp.
    Needs float64 in JAX (jax_enable_x64), which the `stepzoo` command and tests turn on."""
    import jax
    import jax.numpy as jnp
    from scipy.integrate import solve_ivp
    if not jax.config.jax_enable_x64:
        raise RuntimeError("a reference solution needs float64: "
                           "jax.config.update('jax_enable_x64', True) first")
    u = jnp.asarray(u, float)
    p = {k: jnp.asarray(v, float) for k, v in p.items()}
    fun = jax.jit(lambda t, x: f(t, x, u, p))
    kw = dict(STIFF if stiff else NONSTIFF, **options)
    if kw["method"] in ("Radau", "BDF", "LSODA"):
        jac = jax.jit(jax.jacfwd(lambda t, x: f(t, x, u, p), argnums=1))
        kw["jac"] = lambda t, x: np.asarray(jac(t, x))
    ts = np.asarray(ts, float)
    sol = solve_ivp(lambda t, x: np.asarray(fun(t, x)), (ts[0], ts[-1]), np.asarray(x0, float),
                    t_eval=ts, **kw)
    if not sol.success:
        raise RuntimeError(f"reference solution failed: {sol.message}")
    return sol.y.T


@lru_cache(maxsize=64)
def cached(model, ts: tuple):
    """The reference of a model's default problem at the times ts (a tuple, for the cache)."""
    x = solve(model.rhs, model.x0, model.u0, model.params(), ts, stiff=model.stiff)
    x.setflags(write=False)
    return x
