"""Linearisation: the state Jacobian by `jax.jacfwd`, and the closed-form lateral matrix
A(vx, delta) of the 5-state model, for which d/dt [vy, r] = A [vy, r] + b exactly."""
import jax
import jax.numpy as jnp


def state_jacobian(f, t, x, u, p):
    """df/dx at (t, x, u) by forward-mode differentiation."""
    return jax.jacfwd(f, argnums=1)(t, x, u, p)


def lateral_matrix(vx, delta, p, xp=jnp):
    """A [1/s, m/s^2 per rad/s ...] and b of the lateral (vy, r) dynamics at speed vx [m/s],
    steer delta [rad]; exact (not an approximation) for the reduced model. `xp`: the array
    module (NumPy for many steers at once outside a trace: A (2, 2, n), b (2, n))."""
    jnp = xp
    cf = p["Caf"] * jnp.cos(delta)
    cr, m, Iz, Lf, Lr = p["Car"], p["m"], p["Iz"], p["Lf"], p["Lr"]
    A = jnp.array([
        [-(cf + cr) / (m * vx), -(cf * Lf - cr * Lr) / (m * vx) - vx],
        [-(Lf * cf - Lr * cr) / (Iz * vx), -(Lf**2 * cf + Lr**2 * cr) / (Iz * vx)],
    ])
    front = cf * delta - p.get("Fxf", 0.0) * jnp.sin(delta)
    b = jnp.array([front / m, Lf * front / Iz])
    return A, b


def lateral_eigenvalues(vx, delta, p):
    """Eigenvalues [1/s] of A(vx, delta); they set every integrator's stability limit."""
    A, _ = lateral_matrix(vx, delta, p)
    return jnp.linalg.eigvals(A)
