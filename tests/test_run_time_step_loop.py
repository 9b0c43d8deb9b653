"""A run-time step count (`max_steps`) takes the same steps as a compiled one: the while loop
over the steps gives the compiled scan's states to round-off in both batch layouts (a vmap
below SMALL_BATCH, chunks with the batch last above it), for a one-step method, a multistep
method with its starter's rows, and an implicit one with Newton's evaluations counted alike;
rows past the step count are NaN."""
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.integrators import integrate_batch, method
from stepzoo.integrators.driver import SMALL_BATCH

MAX_STEPS = 64


def vdp(t, x, u, p):
    """Van der Pol with damping p, forced by u: small, nonlinear, stiff for large p."""
    return jnp.stack([x[1], p * (1 - x[0] ** 2) * x[1] - x[0] + u[0]])


def lanes(batch):
    rng = np.random.default_rng(4)
    return (rng.uniform(-2, 2, (batch, 2)), rng.uniform(-0.5, 0.5, (batch, 1)),
            rng.uniform(0.5, 5.0, batch), rng.uniform(0.005, 0.02, batch))


@pytest.mark.parametrize("name, batch", [("rk4", SMALL_BATCH + 3), ("ab4", 5),
                                         ("ab4", SMALL_BATCH + 3), ("trapezoidal", 5)])
def test_run_time_step_count_takes_the_compiled_steps(name, batch):
    x0, u, p, h = lanes(batch)
    n = 41
    fixed = integrate_batch(method(name), vdp, x0, u, p, h, n)
    run = integrate_batch(method(name), vdp, x0, u, p, h, jnp.asarray(n), max_steps=MAX_STEPS)
    a, b = np.asarray(run.x), np.asarray(fixed.x)
    assert a.shape == (batch, MAX_STEPS + 1, 2)
    scale = np.abs(b).max(axis=1, keepdims=True)
    assert np.all(np.abs(a[:, : n + 1] - b) <= 4 * np.finfo(float).eps * scale)
    assert np.all(np.isnan(a[:, n + 1:]))
    np.testing.assert_array_equal(run.evals, fixed.evals)
    np.testing.assert_array_equal(run.converged, fixed.converged)


def test_step_counts_at_the_ends_and_inside_the_starter():
    """n = max_steps fills every row; n = 0 keeps x0 alone; a count below ab4's three
    starting steps keeps the starter's rows up to it."""
    x0, u, p, h = lanes(3)
    full = integrate_batch("ab4", vdp, x0, u, p, h, MAX_STEPS)
    for n in (MAX_STEPS, 0, 2):
        run = integrate_batch("ab4", vdp, x0, u, p, h, jnp.asarray(n), max_steps=MAX_STEPS)
        x = np.asarray(run.x)
        np.testing.assert_array_equal(x[:, : n + 1], np.asarray(full.x)[:, : n + 1])
        assert np.all(np.isnan(x[:, n + 1:]))
