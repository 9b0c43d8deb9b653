"""Without the command's XLA loop option the library runs bigger chunks (driver.chunk_size),
with the same trajectories to round-off; it only reads XLA_FLAGS."""
import re
from collections import Counter

import jax
import numpy as np
import pytest

from stepzoo import dynamics
from stepzoo.cli import XLA_OPTION
from stepzoo.integrators import driver, method

MODEL = dynamics.model("dynamic5")
BATCH = driver.CHUNK_CALLS + 5         # several chunks of CHUNK, two padded ones of CHUNK_CALLS


def problem(rng):
    """(x0, u, p) of BATCH bicycles at seeded speeds, lateral speeds and steers."""
    p = {k: np.full(BATCH, float(v)) for k, v in MODEL.params(None, 15.0).items()}
    p["vx"] = rng.uniform(5.0, 25.0, BATCH)
    x0 = np.zeros((BATCH, 5))
    x0[:, 3] = rng.uniform(-1.0, 1.0, BATCH)
    return x0, rng.uniform(-0.5, 0.5, (BATCH, 1)), p


def traced_fresh(monkeypatch, flags):
    """_batch traced anew (a new function, so no cached trace) with XLA_FLAGS = flags."""
    monkeypatch.setenv("XLA_FLAGS", flags)
    x0, u, p = problem(np.random.default_rng(3))
    fresh = jax.jit(lambda m, f, x0, u, p, h, n, t0, mx, libm:
                    driver._batch(m, f, x0, u, p, h, n, t0, mx, libm),
                    static_argnames=("m", "f", "n", "mx", "libm"))
    tr, far, _ = fresh(m=method("rk4"), f=MODEL.rhs, x0=x0, u=u, p=p, h=0.01, n=40, t0=0.0,
                       mx=None, libm=False)
    assert not bool(far)
    return tr


def test_library_chunks_give_the_command_s_trajectories(monkeypatch):
    assert driver.chunk_size(method("rk4")) == driver.CHUNK       # conftest set the option
    command = traced_fresh(monkeypatch, f"--xla_backend_extra_options={XLA_OPTION}")
    library = traced_fresh(monkeypatch, "")
    assert driver.chunk_size(method("rk4")) == driver.CHUNK_CALLS
    x, ref = np.asarray(library.x), np.asarray(command.x)
    scale = np.abs(ref).max(axis=-2, keepdims=True)
    assert np.all(np.abs(x - ref) <= 1e-12 * scale)
    np.testing.assert_array_equal(library.evals, command.evals)


@pytest.mark.parametrize("flags, native", [
    ("", False), ("--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000",
                  False),
    (f"--xla_force_host_platform_device_count=2 --xla_backend_extra_options=a=1,{XLA_OPTION}",
     True)])
def test_native_loops_are_read_from_xla_flags(monkeypatch, flags, native):
    monkeypatch.setenv("XLA_FLAGS", flags)
    assert driver.loops_native() is native
    assert driver.chunk_size(method("bdf2")) == driver.CHUNK_IMPLICIT


def test_the_last_chunk_overlaps_instead_of_padding(monkeypatch):
    """A batch the chunks do not divide: the last chunk ends at the last trajectory, so it
    also runs trajectories of the one before it; every trajectory, with its own step size,
    is still its own run, and every time row its own."""
    monkeypatch.setenv("XLA_FLAGS", "")
    assert driver.chunk_size(method("rk4")) == driver.CHUNK_CALLS
    rng = np.random.default_rng(4)
    x0, u, p = problem(rng)
    h = rng.uniform(0.005, 0.01, BATCH)
    fresh = jax.jit(lambda x0, u, p, h: driver._batch(method("rk4"), MODEL.rhs, x0, u, p, h,
                                                        30, 0.0, None, False))
    tr, far, _ = fresh(x0, u, p, h)
    assert not bool(far) and tr.x.shape == (BATCH, 31, 5)
    one = jax.jit(lambda x0, u, p, h: driver._integrate(method("rk4"), MODEL.rhs, x0, u, p, h,
                                                         30, 0.0, None))
    for b in range(BATCH):
        ref = one(x0[b], u[b], {k: v[b] for k, v in p.items()}, h[b])[0]
        scale = np.abs(np.asarray(ref.x)).max(axis=0)
        assert np.all(np.abs(np.asarray(tr.x[b]) - np.asarray(ref.x)) <= 1e-12 * scale), b
        np.testing.assert_allclose(tr.t[b], ref.t, rtol=1e-15)
    np.testing.assert_array_equal(tr.evals, np.full(BATCH, 4.0 * 30))
    assert bool(np.all(tr.converged))


@pytest.mark.parametrize("d, chunk", [(9, driver.CHUNK_IMPLICIT), (29, 32)])
def test_implicit_chunks_hold_at_most_system_bytes_of_the_retry_matrix(d, chunk):
    """Radau IIA 5's full-Newton retry factorises its whole 3d x 3d stage system: at 29
    states (order 87, 61 kB a trajectory in float64) a chunk of 64 made the step loop count
    more bytes than XLA's threshold, which then ran it operation by operation; its chunks
    are 32 there, and stay CHUNK_IMPLICIT at 9 states (whose results the regression tables
    hold)."""
    batch, n = 2 * driver.ONE_CHUNK_IMPLICIT + 3, 3 * d        # chunks on one device or two
    x0 = np.zeros((batch, d))
    fn = jax.jit(lambda x0: driver._batch(method("radau_iia5"), lambda t, x, u, p: -x, x0,
                                          np.zeros((batch, 1)), np.zeros(batch), 0.01, 2,
                                          0.0, None, False))
    # The stage values of a chunk's lanes, (lanes, 3d), are its most common 3d-long rows.
    rows = Counter(re.findall(rf"tensor<(\d+)x{n}xf64>", fn.lower(x0).as_text()))
    assert int(rows.most_common(1)[0][0]) == chunk, rows
    assert chunk * n * n * 8 <= driver.SYSTEM_BYTES
