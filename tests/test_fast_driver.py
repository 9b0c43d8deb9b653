"""The fast paths agree with the plain driver to 1e-12 of each trajectory's scale: small
batches (vmapped), batches in several chunks (padded), shared among host devices, and the
vectorisable sin/cos."""
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax

from stepzoo import dynamics
from stepzoo.integrators import integrate, integrate_batch, method
from stepzoo.integrators.driver import (CHUNK, CHUNK_IMPLICIT, ONE_CHUNK_IMPLICIT, SHARE,
                                        SMALL_BATCH)
from stepzoo.integrators.fast_trig import BOUND, cos, fast_trig, flagged_trig, sin

pytestmark = pytest.mark.slow      # run first: see tests/conftest.py

MODEL = dynamics.model("dynamic5")


def envelope(batch, seed=0):
    rng = np.random.default_rng(seed)
    ps = [MODEL.params(None, v) for v in rng.uniform(2.0, 30.0, batch)]
    p = {k: np.array([q[k] for q in ps]) for k in ps[0]}
    x0 = np.zeros((batch, 5))
    x0[:, 3:] = rng.uniform(-0.5, 0.5, (batch, 2))
    return x0, rng.uniform(-0.78, 0.78, (batch, 1)), p, ps


def assert_close(a, b):
    """|a - b| <= 1e-12 max|b| per trajectory (components pass through zero)."""
    a, b = np.asarray(a), np.asarray(b)
    scale = np.abs(b).max(axis=-2, keepdims=True)
    assert np.all(np.abs(a - b) <= 1e-12 * scale)


# Batches of one, a vmap below SMALL_BATCH, and chunks with the last one padded (an implicit
# method's batch up to ONE_CHUNK_IMPLICIT is one chunk).
CASES = [(name, batch) for name in ("rk4", "ab4", "dopri5")
         for batch in (1, SMALL_BATCH - 1, SMALL_BATCH + 3)] + [("bdf2", ONE_CHUNK_IMPLICIT + 3)]


@pytest.mark.parametrize("name, batch", CASES)
def test_batch_equals_one_by_one(name, batch):
    x0, u, p, ps = envelope(batch)
    tr = integrate_batch(method(name), MODEL.rhs, x0, u, p, 0.002, 60)
    assert tr.x.shape == (batch, 61, 5) and tr.t.shape == (batch, 61)
    chunk = CHUNK_IMPLICIT if method(name).implicit else CHUNK
    for i in sorted({0, min(chunk, batch) - 1, min(chunk, batch - 1), batch - 1}):
        one = integrate(method(name), MODEL.rhs, x0[i], u[i], ps[i], 0.002, 60)
        assert_close(tr.x[i], one.x)
        assert float(tr.evals[i]) == float(one.evals)


@pytest.mark.parametrize("batch", [3, SMALL_BATCH + 1])
def test_run_time_step_counts_and_step_sizes_per_trajectory(batch):
    x0, u, p, ps = envelope(batch, seed=1)
    hs = np.linspace(0.0005, 0.003, batch)    # stable for ab4 down to 2 m/s
    tr = integrate_batch(method("ab4"), MODEL.rhs, x0, u, p, hs, jnp.asarray(37), max_steps=80)
    for i in (0, batch - 1):
        one = integrate(method("ab4"), MODEL.rhs, x0[i], u[i], ps[i], hs[i], 37)
        assert_close(tr.x[i, :38], one.x)
        assert np.all(np.isnan(np.asarray(tr.x[i, 38:])))
        np.testing.assert_allclose(tr.t[i, :38], one.t, rtol=1e-15)


@pytest.mark.parametrize("dtype, ulps", [(np.float64, 3), (np.float32, 3)])
def test_polynomial_sin_cos_are_within_a_few_ulp_of_libm(dtype, ulps):
    """Over the whole reduction range, and at the arguments nearest to multiples of pi/2,
    where the reduction cancels most: in ulp of the result, against libm in float64."""
    bound = BOUND[np.dtype(dtype)]
    near = (np.arange(1, int(bound / (np.pi / 2))) * (np.pi / 2)).astype(dtype)
    a = np.concatenate([np.random.default_rng(2).uniform(-bound, bound, 100_000).astype(dtype),
                        near, np.nextafter(near, dtype(0)), np.nextafter(near, dtype(bound)),
                        np.array([0.0, np.pi / 4, -np.pi / 2, 3 * np.pi / 4], dtype)])
    for fast, exact in ((sin, np.sin), (cos, np.cos)):
        out = np.asarray(jax.jit(fast)(jnp.asarray(a)))
        assert out.dtype == dtype
        ref = exact(a.astype(np.float64))
        assert np.max(np.abs(out - ref) / np.spacing(np.abs(ref).astype(dtype))) <= ulps
        assert np.all(np.isnan(np.asarray(fast(jnp.array([np.inf, -np.inf, np.nan], dtype)))))


def test_arguments_beyond_the_bound_are_flagged():
    """The flag that sends a chunk to libm: set by a finite argument at or beyond the bound
    only (NaN and inf give NaN from the polynomials, as from libm)."""
    for dtype in (np.float64, np.float32):
        bound = BOUND[np.dtype(dtype)]
        value, far = flagged_trig(lambda a: jnp.sin(a) * jnp.cos(a))(jnp.array([1.0, 2.0], dtype))
        assert not far and value.dtype == dtype
        for beyond in (bound, -1e30, np.finfo(dtype).max):
            assert flagged_trig(jnp.cos)(jnp.array([1.0, beyond], dtype))[1]
        assert not flagged_trig(jnp.sin)(jnp.array([np.nan, np.inf, -np.inf], dtype))[1]
    assert flagged_trig(jnp.exp)(jnp.ones(3))[1] is None


@pytest.mark.parametrize("dtype, psi, tol", [(np.float64, [1e7, -3e300, np.nan, np.inf], 1e-12),
                                             (np.float32, [1e5, -3e30, np.nan, 0.5], 1e-5)])
def test_batches_equal_libm_for_every_heading(dtype, psi, tol):
    """The default batched path against one trajectory at a time (libm's sin and cos), with
    headings beyond the polynomials' bound, NaN and inf in one chunk, in the caller's dtype."""
    batch = SMALL_BATCH + 3
    x0, u, p, ps = envelope(batch, seed=5)
    x0[1:1 + len(psi), 2] = psi
    x0, u = x0.astype(dtype), u.astype(dtype)
    cast = lambda q: {k: np.asarray(v, dtype) for k, v in q.items()}
    tr = integrate_batch(method("rk4"), MODEL.rhs, x0, u, cast(p), 0.002, 40)
    assert tr.x.dtype == dtype
    for i in range(len(psi) + 2):
        one = np.asarray(integrate(method("rk4"), MODEL.rhs, x0[i], u[i], cast(ps[i]), 0.002,
                                   40).x)
        got, ok = np.asarray(tr.x[i]), np.isfinite(one)
        assert np.array_equal(got[~ok], one[~ok], equal_nan=True)
        scale = np.abs(np.where(ok, one, 0.0)).max(axis=0)
        assert np.all(np.abs(got[ok] - one[ok]) <= tol * np.broadcast_to(scale, one.shape)[ok])


def test_sin_and_cos_in_a_loop_body_are_rewritten_and_flagged():
    """A while loop's body (Newton's iterations) gets the polynomials too: a vmapped loop
    whose elements stop after their own number of iterations lands where libm's does to a
    few ulp per iteration, and an argument beyond the bound met in any iteration sets the
    flag."""
    def walk(a, n):
        def body(c):
            x, k = c
            return x + 0.5 * jnp.cos(x * a), k + 1
        return lax.while_loop(lambda c: c[1] < n, body, (a, 0))[0]

    a, n = jnp.array([0.3, 1.7, -2.0, 5.0]), jnp.array([1, 4, 9, 16])
    plain = jax.vmap(walk)(a, n)
    value, far = jax.jit(flagged_trig(jax.vmap(walk)))(a, n)
    np.testing.assert_allclose(np.asarray(value), np.asarray(plain), rtol=1e-14)
    assert not far
    # The cosine's argument x a is beyond 2^20 from the first iteration for a = 1.5e6 only.
    _, far = jax.jit(flagged_trig(jax.vmap(lambda a, n: walk(a * 1e6, n))))(
        jnp.array([1e-3, 1.5]), jnp.array([3, 3]))
    assert far


@pytest.mark.parametrize("name", ["rk4", "trapezoidal"])
def test_fast_trig_model_agrees_with_the_model(name):
    x0, u, p, _ = envelope(64, seed=3)
    plain = integrate_batch(method(name), MODEL.rhs, x0, u, p, 0.01, 300)
    fast = integrate_batch(method(name), fast_trig(MODEL.rhs), x0, u, p, 0.01, 300)
    assert_close(fast.x, plain.x)
    assert fast_trig(MODEL.rhs) is fast_trig(MODEL.rhs)    # one static function: one compile


SHARED = [("rk4", None), ("ab4", None), ("ab4", 60), ("trapezoidal", None),
          ("radau_iia5", None)]


@pytest.fixture(scope="module")
def two_devices(tmp_path_factory):
    """{(name, max_steps): the batch's states} of each SHARED case run on two host devices:
    one fresh interpreter for them all, since XLA reads the device count when JAX starts."""
    out = tmp_path_factory.mktemp("shared")
    code = ("import numpy as np, jax; jax.config.update('jax_enable_x64', True); "
            "from tests.test_fast_driver import *; "
            "assert len(jax.devices()) == 2; x0, u, p, _ = envelope(2 * SHARE + 5, 4)\n"
            f"for i, (name, max_steps) in enumerate({SHARED!r}):\n"
            "    n = 40 if max_steps is None else jax.numpy.asarray(40)\n"
            "    tr = integrate_batch(method(name), MODEL.rhs, x0, u, p, 0.002, n, "
            "max_steps=max_steps)\n"
            "    assert len(tr.x.sharding.device_set) == 2, name\n"
            f"    np.save({str(out)!r} + f'/{{i}}.npy', np.asarray(tr.x))")
    # This process's XLA flags too (conftest's loop option, make test's optimisation level):
    # the interpreter compiles as this one does (in half the time it took without them).
    env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} "
               "--xla_force_host_platform_device_count=2")
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=600,
                   cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    return {case: np.load(out / f"{i}.npy") for i, case in enumerate(SHARED)}


@pytest.mark.parametrize("name, max_steps", SHARED)
def test_batch_shared_among_host_devices_equals_one_device(two_devices, name, max_steps):
    # Radau IIA 5 factorises its 15 x 15 stage system in newton's loop: with LAPACK's
    # there, two devices hung. A run-time step count (ab4, 60) is shared as well.
    x0, u, p, _ = envelope(2 * SHARE + 5, 4)
    one = integrate_batch(method(name), MODEL.rhs, x0, u, p, 0.002, 40)
    assert_close(two_devices[name, max_steps][:, :41], one.x)
