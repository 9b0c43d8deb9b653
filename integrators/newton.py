"""Newton's method with the exact Jacobian (forward-mode AD) for the implicit methods' stage
equations: stops when the update is below tolerance or after a bounded number of iterations."""
import jax
import jax.numpy as jnp
from jax import lax

NEWTON_TOL = 1e-12     # relative update size at which Newton stops
NEWTON_MAX_ITER = 8    # bound on iterations per step


def newton_solve(residual, z0, scale):
    """Solve residual(z) = 0 from z0 (flat vector); `scale` sets the relative tolerance
    (|dz| <= tol * (1 + scale)). Returns (z, iterations)."""
    jac = jax.jacfwd(residual)

    def cond(state):
        _, k, err = state
        return (k < NEWTON_MAX_ITER) & (err > NEWTON_TOL * (1.0 + scale))

    def body(state):
        z, k, _ = state
        dz = jnp.linalg.solve(jac(z), residual(z))
        return z - dz, k + 1, jnp.max(jnp.abs(dz))

    z, k, _ = lax.while_loop(cond, body, (z0, jnp.asarray(0), jnp.asarray(jnp.inf, z0.dtype)))
    return z, k
