"""The public Python API on a user's own ODE: method names, array-likes and scalars for x0,
optional u and p, unbatched p shared by a batch, the work dtype of x0 (float32 included,
with the observed order of convergence in float32 and float64), and one clear error per bad
argument, naming it."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.integrators import METHODS, integrate, integrate_batch, method, reference


def oscillator(t, x, u, p):
    """x'' = -x: from (1, 0) the exact solution is (cos t, -sin t)."""
    return jnp.stack([x[1], -x[0]])


def decay(t, x, u, p):
    """x' = -p x (p defaults to 1 when None), a scalar state: exact x0 exp(-p t)."""
    return -(1.0 if p is None else p) * x


@pytest.mark.parametrize("name", ["rk4", "trapezoidal", "ab3"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_observed_order_holds_in_float32_and_float64(name, dtype):
    # Step sizes where the error per unit time lies between 1e-2 and 1e-4 of an order-p
    # method: far above float32's round-off (1e-7) after 20 steps, so the slope is the
    # method's, not the arithmetic's. One batch of step sizes: one compilation per dtype.
    m = method(name)
    hs = (10 ** (-np.linspace(1.0, 3.0, 5) / m.order) / 2).astype(dtype)
    n = 20
    traj = integrate_batch(name, oscillator, np.tile(np.array([1.0, 0.0], dtype), (5, 1)),
                           h=hs, n_steps=n)
    assert traj.x.dtype == dtype
    t_end = n * hs.astype(float)
    last = np.asarray(traj.x[:, -1], float)
    err = np.hypot(last[:, 0] - np.cos(t_end), last[:, 1] + np.sin(t_end)) / t_end
    slope = np.polyfit(np.log(hs.astype(float)), np.log(err), 1)[0]
    assert abs(slope - m.order) < 0.15, (name, dtype, slope)


def test_a_method_name_a_list_and_keyword_parameters_give_what_the_objects_give():
    by_name = integrate("rk4", decay, [1.0, 2.0], p=3.0, h=0.01, n_steps=50)
    by_object = integrate(METHODS["rk4"], decay, jnp.array([1.0, 2.0]), None, 3.0, 0.01, 50)
    np.testing.assert_array_equal(by_name.x, by_object.x)
    np.testing.assert_allclose(by_name.x[-1], np.array([1.0, 2.0]) * np.exp(-1.5), rtol=1e-7)


@pytest.mark.parametrize("name", ["rk4", "backward_euler", "radau_iia3", "bdf2"])
def test_a_scalar_state_is_a_one_state_system_for_explicit_and_implicit_methods(name):
    traj = integrate(name, decay, 1.0, h=0.01, n_steps=100)
    assert traj.x.shape == (101,)
    assert abs(float(traj.x[-1]) - np.exp(-1.0)) < 3e-3     # backward Euler: h/2 e^-1
    batch = integrate_batch(name, decay, np.array([1.0, 2.0]), h=0.01, n_steps=100)
    assert batch.x.shape == (2, 101)
    np.testing.assert_allclose(batch.x[:, -1], [traj.x[-1], 2 * traj.x[-1]], rtol=1e-12)


def test_an_unbatched_parameter_is_shared_by_the_batch_and_a_batched_one_is_not():
    x0 = np.ones((3, 1))
    shared = integrate_batch("heun", decay, x0, p=2.0, h=0.1, n_steps=10)
    per_row = integrate_batch("heun", decay, x0, p=np.array([2.0, 2.0, 1.0]), h=0.1,
                              n_steps=10)
    np.testing.assert_array_equal(shared.x[0], shared.x[2])
    np.testing.assert_array_equal(shared.x[:2], per_row.x[:2])
    assert per_row.x[2, -1, 0] > per_row.x[0, -1, 0]


def test_float32_state_keeps_float32_with_float64_parameters():
    traj = integrate("radau_iia3", decay, np.array([1.0], np.float32), p=np.float64(1.0),
                     h=0.1, n_steps=10)
    assert traj.x.dtype == np.float32
    assert abs(float(traj.x[-1, 0]) - np.exp(-1.0)) < 1e-5


def test_the_reference_is_exported_and_refuses_a_tolerance_float32_cannot_reach():
    ts = np.linspace(0.0, 2.0, 5)
    ref = reference(oscillator, [1.0, 0.0], ts=ts)
    np.testing.assert_allclose(ref.x[:, 0], np.cos(ts), atol=1e-9)
    with pytest.raises(ValueError, match="rtol.*float32.*jax_enable_x64"):
        reference(oscillator, np.array([1.0, 0.0], np.float32), ts=ts)
    loose = reference(oscillator, np.array([1.0, 0.0], np.float32), ts=ts, rtol=1e-5)
    assert loose.x.dtype == np.float32 and bool(loose.success)
    np.testing.assert_allclose(loose.x[:, 0], np.cos(ts), atol=1e-4)


@pytest.mark.parametrize("kwargs, error, words", [
    (dict(h=-0.1), ValueError, "h must be a finite step size > 0"),
    (dict(h=0.0), ValueError, "h must be a finite step size > 0"),
    (dict(h=float("inf")), ValueError, "h must be a finite step size > 0"),
    (dict(h="0.1"), TypeError, "h must be a step size"),
    (dict(n_steps=-1), ValueError, "n_steps must be a whole number"),
    (dict(n_steps=2.5), ValueError, "n_steps must be a whole number"),
    (dict(n_steps=20, max_steps=10), ValueError, r"n_steps must be a whole number in \[0, "),
    (dict(method="rk5"), ValueError, "method 'rk5' is not in the zoo; choose one of euler"),
    (dict(method=4), TypeError, "method must be a method name"),
    (dict(f="decay"), TypeError, "f must be a function"),
    (dict(x0=[[1.0, 2.0]]), ValueError, r"x0 must have shape \(d,\), or a scalar"),
    (dict(x0=["a", "b"]), TypeError, "x0 must be a number, a list of numbers or an array"),
    (dict(x0=np.array(["a"])), TypeError, "x0 must hold real numbers"),
    (dict(t0=float("nan")), ValueError, "t0 must be a finite time"),
])
def test_a_bad_argument_is_one_clear_error_naming_it(kwargs, error, words):
    args = dict(method="rk4", f=decay, x0=[1.0], h=0.1, n_steps=10) | kwargs
    with pytest.raises(error, match=words):
        integrate(**args)


def test_a_batch_needs_a_leading_batch_axis_and_one_step_per_trajectory():
    with pytest.raises(ValueError, match=r"x0 must have shape \(B, d\)"):
        integrate_batch("rk4", decay, 1.0, h=0.1, n_steps=3)
    with pytest.raises(ValueError, match="h must be a number or one per trajectory"):
        integrate_batch("rk4", decay, np.ones((3, 1)), h=np.full(2, 0.1), n_steps=3)


def test_float64_input_without_float64_enabled_says_what_to_enable():
    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.raises(TypeError, match=r"x0 is float64.*jax_enable_x64"):
            integrate("rk4", decay, np.array([1.0]), h=0.1, n_steps=3)
        traj = integrate("rk4", decay, [1.0], h=0.1, n_steps=3)      # a list: JAX's default
        assert traj.x.dtype == np.float32
    finally:
        jax.config.update("jax_enable_x64", True)
