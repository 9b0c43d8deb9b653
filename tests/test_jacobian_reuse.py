"""Implicit steps keep their Jacobian's factors across steps while Newton contracts fast
(newton.Held, NewtonOptions.keep): the results are the ones a new Jacobian every step gives, to the
Newton tolerance; a Jacobian that changes fast is taken anew where a kept one would not do;
and the kept factors keep a float32 state in float32."""
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.bench.perf.workloads.bicycle import H_S, MODEL, problem
from stepzoo.integrators import integrate, integrate_batch, method, newton
from helpers import retrying

pytestmark = pytest.mark.slow      # run first: see tests/conftest.py

# One method of each step code. BDF2 (not BDF3) for the multistep one: the float32 test's
# BDF2 reference is then this test's program, not one more to compile.
IMPLICIT = ["backward_euler", "trapezoidal", "bdf2", "radau_iia5", "kvaerno3"]
N_STEPS = 100       # of the bicycle's float64 runs: one program per method serves both tests


@pytest.mark.parametrize("name", IMPLICIT)
def test_kept_jacobians_give_what_new_ones_give_to_the_newton_tolerance(name):
    """Never kept (keep < 0) is a run-time option: both runs are one compiled program."""
    n, x0, u, p = N_STEPS, *problem(40, seed=3)
    kept = integrate_batch(name, MODEL.rhs, x0, u, p, H_S, n)
    fresh = integrate_batch(method(name).with_newton(keep=-1.0), MODEL.rhs, x0, u, p, H_S, n)
    assert bool(kept.converged.all()) and bool(fresh.converged.all())
    # Each step's solve is within rtol = atol = 1e-10 of the exact stage values, both ways;
    # over n steps of a stable problem the differences add up to at most about n of them.
    scale = np.abs(np.asarray(fresh.x)).max(axis=1, keepdims=True) + 1.0
    diff = np.abs(np.asarray(kept.x) - np.asarray(fresh.x)) / scale
    assert diff.max() <= n * 1e-10, diff.max()
    # ... and the kept ones saved evaluations: a Jacobian is 5 of them on the bicycle.
    assert float(kept.evals.mean()) < 0.75 * float(fresh.evals.mean())


def lam(t):
    """A stiffness that swings between 100 and 1900 1/s ten times a second."""
    return 1000.0 * (1.0 + 0.9 * jnp.sin(60.0 * t))


def lam_np(t):
    return 1000.0 * (1.0 + 0.9 * np.sin(60.0 * t))


def forced(t, y, u, p):
    """y' = -lambda(t) (y - cos t) - sin t: y = cos t + (y0 - 1) exp(-int lambda)."""
    return -lam(t) * (y - jnp.cos(t)) - jnp.sin(t)


def f_np(t, y):
    return -lam_np(t) * (y - np.cos(t)) - np.sin(t)


# The methods' own recurrences on `forced` (NumPy), solved for y_{n+1}, f being affine in y:
# backward Euler y_{n+1} = y_n + h f(t_{n+1}, y_{n+1}); the trapezoidal rule averages f.
ORACLES = {"backward_euler": lambda y, t, h: ((y + h * (f_np(t + h, 0.0)))
                                              / (1 + h * lam_np(t + h))),
           "trapezoidal": lambda y, t, h: ((y + h / 2 * (f_np(t, y) + f_np(t + h, 0.0)))
                                           / (1 + h / 2 * lam_np(t + h)))}


@pytest.mark.parametrize("keep", [newton.THETA_KEEP, np.inf])
@pytest.mark.parametrize("name", sorted(ORACLES))
def test_a_jacobian_that_changes_fast_is_taken_anew(name, keep):
    """With keep = inf a step keeps any Jacobian whose solve converged, so only the retry
    with the step's own rescues the steps where lambda has moved on: from 100 to 1900 1/s,
    a kept one's iteration diverges. No full-Newton retry, which would rescue them too."""
    h, n = 0.002, 500
    tr = integrate(method(name).with_newton(max_iter_full=0, keep=keep), forced,
                   jnp.array([1.0, -2.0]), h=h, n_steps=n)
    assert bool(tr.converged)
    want = [np.array([1.0, -2.0])]
    for k in range(n):
        want.append(ORACLES[name](want[-1], k * h, h))
    np.testing.assert_allclose(np.asarray(tr.x), np.array(want), rtol=1e-8, atol=1e-9)


@pytest.mark.parametrize("name", ["trapezoidal", "bdf2", "radau_iia5"])
def test_a_float32_state_stays_float32_in_chunks(name):
    x0, u, p = problem(40, seed=1)
    # In float32, BDF2's and Radau IIA 5's simplified iterations fail and the full-Newton
    # retry solves: the program with it from the first run.
    m = retrying(name) if name != "trapezoidal" else name
    tr = integrate_batch(m, MODEL.rhs, x0.astype(np.float32), u, p, H_S, 20)
    assert tr.x.dtype == np.float32
    assert bool(tr.converged.all())
    ref = integrate_batch(name, MODEL.rhs, x0, u, p, H_S, N_STEPS).x[:, :21]
    np.testing.assert_allclose(np.asarray(tr.x), np.asarray(ref), rtol=1e-4, atol=1e-4)



def nine_a2(t, y, u, p):
    """Nine copies of DETEST A2, y' = -y^3/2, exact y = y0 / sqrt(1 + y0^2 t): a system of
    more than newton.SMALL states, whose steps keep their factors at rates up to keep_large."""
    return -0.5 * y ** 3


Y9 = np.linspace(0.5, 1.0, 9)


def test_above_small_states_keep_large_decides_whether_factors_are_kept():
    """Backward Euler at 9 states: with keep (the small systems' rate) set to never, the
    steps still keep their factors and save evaluations (a Jacobian is 9 of them, an
    iteration 1); with keep_large set to never, every step takes a new Jacobian. Both runs
    are one program (run-time options) and land within the Newton tolerance (1e-10 a step)
    of each other."""
    h, n = 0.05, 80
    run = lambda **kw: integrate(method("backward_euler").with_newton(**kw), nine_a2,
                                 jnp.asarray(Y9), h=h, n_steps=n)
    kept, fresh = run(keep=-1.0), run(keep_large=-1.0)
    assert bool(kept.converged) and bool(fresh.converged)
    assert np.max(np.abs(np.asarray(kept.x) - np.asarray(fresh.x))) <= n * 1e-10
    assert float(fresh.evals) >= 9 * n and float(kept.evals) < 0.6 * float(fresh.evals)


def test_radau_iia5_with_kept_factors_has_the_error_of_new_ones_at_each_step_size():
    """Radau IIA 5 on nine_a2 over [0, 20], h = 2, 1, 1/2, with the default options (keep_large)
    and with new factors at every step: the errors against the exact solution differ by at
    most the accumulated Newton tolerance (n steps of 1e-10), so the kept factors keep
    the method's convergence (its order on A2 itself: test_newton). One program for every
    run (run-time options and step count)."""
    exact = Y9 / np.sqrt(1 + Y9 ** 2 * 20.0)
    for h in (2.0, 1.0, 0.5):
        n = int(round(20 / h))
        run = lambda **kw: integrate(method("radau_iia5").with_newton(**kw), nine_a2,
                                     jnp.asarray(Y9), h=h, n_steps=n, max_steps=40)  # noqa: B023
        kept, fresh = run(), run(keep_large=-1.0)
        assert bool(kept.converged) and bool(fresh.converged)
        xk, xf = np.asarray(kept.x[:n + 1]), np.asarray(fresh.x[:n + 1])
        assert np.max(np.abs(xk - xf)) <= n * 1e-10
        err_k, err_f = np.max(np.abs(xk[n] - exact)), np.max(np.abs(xf[n] - exact))
        assert abs(err_k - err_f) <= n * 1e-10 < 0.2 * err_f, h
