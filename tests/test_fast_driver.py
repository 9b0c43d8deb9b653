"""The fast paths agree with the plain driver to 1e-12 of each trajectory's scale: small
batches (vmapped), batches in several chunks (padded), shared among host devices, and the
vectorisable sin/cos."""
import os
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo import dynamics
from stepzoo.integrators import integrate, integrate_batch, method
from stepzoo.integrators.driver import CHUNK, CHUNK_IMPLICIT, SHARE, SMALL_BATCH
from stepzoo.integrators.fast_trig import cos, fast_trig, sin

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


# Batches of one, a vmap below SMALL_BATCH, and chunks with the last one padded.
CASES = [(name, batch) for name in ("rk4", "ab4", "dopri5")
         for batch in (1, SMALL_BATCH - 1, SMALL_BATCH + 3)] + [("bdf2", CHUNK_IMPLICIT + 3)]


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


def test_fast_sin_cos_are_within_two_ulp_of_libm():
    a = np.random.default_rng(2).uniform(-2.0 ** 20, 2.0 ** 20, 200_000)
    a[:4] = [0.0, np.pi / 4, -np.pi / 2, 3 * np.pi / 4]
    for fast, exact in ((sin, np.sin), (cos, np.cos)):
        assert np.max(np.abs(np.asarray(fast(jnp.asarray(a))) - exact(a))) <= 2.3e-16
    assert np.all(np.isnan(np.asarray(sin(jnp.array([np.inf, np.nan])))))


@pytest.mark.parametrize("name", ["rk4", "trapezoidal"])
def test_fast_trig_model_agrees_with_the_model(name):
    x0, u, p, _ = envelope(64, seed=3)
    plain = integrate_batch(method(name), MODEL.rhs, x0, u, p, 0.01, 300)
    fast = integrate_batch(method(name), fast_trig(MODEL.rhs), x0, u, p, 0.01, 300)
    assert_close(fast.x, plain.x)
    assert fast_trig(MODEL.rhs) is fast_trig(MODEL.rhs)    # one static function: one compile


@pytest.mark.parametrize("name, max_steps, devices", [("rk4", None, 2), ("ab4", None, 2),
                                                       ("ab4", 60, 1), ("trapezoidal", None, 1)])
def test_batch_shared_among_host_devices_equals_one_device(tmp_path, name, max_steps, devices):
    # XLA reads the device count when JAX starts: a fresh interpreter with two devices.
    # Implicit methods and run-time step counts are kept on one device (see the driver).
    out = tmp_path / "x.npy"
    n = 40 if max_steps is None else "jax.numpy.asarray(40)"
    code = ("import numpy as np, jax; jax.config.update('jax_enable_x64', True); "
            "from tests.test_fast_driver import *; "
            "assert len(jax.devices()) == 2; x0, u, p, _ = envelope(2 * SHARE + 5, 4); "
            f"tr = integrate_batch(method({name!r}), MODEL.rhs, x0, u, p, 0.002, {n}, "
            f"max_steps={max_steps}); assert len(tr.x.sharding.device_set) == {devices}; "
            f"np.save({str(out)!r}, np.asarray(tr.x))")
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=300,
                   cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    x0, u, p, _ = envelope(2 * SHARE + 5, 4)
    one = integrate_batch(method(name), MODEL.rhs, x0, u, p, 0.002, 40)
    assert_close(np.load(out)[:, :41], one.x)
