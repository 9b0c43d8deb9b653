"""Frozen-Jacobian stability prediction for any model: the eigenvalues of df/dx (jax.jacfwd)
along a trajectory, and each method's largest stable step for them, the smallest over the
trajectory, with the time and eigenvalue where it binds. Exact for a linear model.

Eigenvalues that constrain no step: those below REL_ZERO of the largest modulus (zero modes
such as positions that only integrate velocities, whose computed eigenvalues are round-off)
and those with Re > REL_ZERO |lambda| (modes that grow in the exact solution too)."""
from __future__ import annotations

from functools import cache

import numpy as np

from stepzoo.integrators.stability import ray_exit

RULE = ("h_pred: the smallest over the reference trajectory (ALONG samples over the horizon) "
        "of the largest h with h*lambda in the method's stability region for every "
        "eigenvalue lambda of df/dx there; eigenvalues below 1e-8 of the largest modulus, or "
        "with Re lambda > 1e-8 |lambda| (growing in the exact solution too), bound nothing")
REL_ZERO = 1e-8
# Candidates are ranked with their ray angle rounded to RANK_ANGLE [rad] (a few cached ray
# scans serve a whole trajectory); those within RANK_SPREAD of the best are then exact.
RANK_ANGLE = 1e-2
RANK_SPREAD = 0.2
AXIS_BAND = 2 * RANK_ANGLE    # [rad] rays this close to the imaginary axis are always exact


@cache
def _jacobians(f):
    """Jitted (B, T) grid of Jacobians df/dx at states xs (B, T, n), inputs u (B, m) and
    parameters p {k: (B,)}, time ts (T,)."""
    import jax
    one = jax.jacfwd(f, argnums=1)
    over_t = jax.vmap(one, in_axes=(0, 0, None, None))
    return jax.jit(jax.vmap(over_t, in_axes=(None, 0, 0, 0)))


def jacobians(f, ts, xs, u, p) -> np.ndarray:
    """(B, T, n, n) df/dx along each lane's trajectory."""
    import jax.numpy as jnp
    return np.asarray(_jacobians(f)(jnp.asarray(ts), jnp.asarray(xs), jnp.asarray(u),
                                    {k: jnp.asarray(v) for k, v in p.items()}))


def eigenvalues(jac) -> np.ndarray:
    """Eigenvalues [1/s] of every Jacobian (..., n, n); non-finite Jacobians give NaN."""
    jac = np.asarray(jac)
    ok = np.isfinite(jac).all(axis=(-1, -2))
    out = np.full(jac.shape[:-1], np.nan, complex)
    if ok.any():
        out[ok] = np.linalg.eigvals(jac[ok])
    return out


def constraining(lam) -> np.ndarray:
    """Mask of the eigenvalues (..., n) that bound a method's step (see the module doc)."""
    lam = np.asarray(lam)
    mod = np.abs(lam)
    big = np.nanmax(mod, axis=-1, keepdims=True, initial=0.0)
    with np.errstate(invalid="ignore"):
        return np.isfinite(lam) & (mod > REL_ZERO * big) & (lam.real <= REL_ZERO * mod)


def _exit(m, theta):
    return ray_exit(m, float(np.round(theta, 12)))


def predicted_limit(m, lam) -> tuple[float, int, int]:
    """(largest stable step [s], time index, eigenvalue index where it binds) of a method for
    eigenvalues lam (T, n) along a trajectory; (inf, -1, -1) when nothing bounds it."""
    lam = np.atleast_2d(np.asarray(lam, complex))
    mask = constraining(lam)
    if not mask.any():
        return float("inf"), -1, -1
    idx = np.argwhere(mask)
    vals = lam[mask]
    theta = np.abs(np.angle(vals))
    mod = np.abs(vals)
    coarse = np.round(theta / RANK_ANGLE) * RANK_ANGLE
    table = {a: _exit(m, a) for a in np.unique(coarse)}
    rough = np.array([table[a] for a in coarse]) / mod
    # Near the imaginary axis a region's exit changes fast with the angle (Euler's is
    # -2 cos theta) and jumps at the axis itself (to 0 where the boundary is tangent to it
    # at the origin, as rk4's): rounded angles rank those rays wrongly, so they are exact.
    axis = theta < np.pi / 2 + AXIS_BAND
    best = np.min(rough[~axis], initial=np.inf)
    near = np.where(axis | (rough <= best * (1 + RANK_SPREAD)))[0]
    exact = np.array([_exit(m, theta[i]) / mod[i] for i in near])
    k = int(np.argmin(exact))
    if np.isinf(exact[k]):
        return float("inf"), -1, -1
    t, j = idx[near[k]]
    return float(exact[k]), int(t), int(j)
