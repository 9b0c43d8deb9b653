"""Implicit solves never lie: a run either solves its stage equations (and then lands where
the method's equations, solved to round-off, land) or says it did not (converged False, NaN
from the failed step on)."""
import contextlib
import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stepzoo.dynamics.problems import detest
from stepzoo.integrators import driver, integrate, integrate_batch, method
from stepzoo.integrators.newton import NewtonOptions
from helpers import retrying


def robertson(t, y, u, p):
    """Robertson's chemical kinetics (Hairer & Wanner II, IV.1): stiffness ratio ~1e11."""
    return jnp.array([-0.04 * y[0] + 1e4 * y[1] * y[2],
                      0.04 * y[0] - 1e4 * y[1] * y[2] - 3e7 * y[1] ** 2,
                      3e7 * y[1] ** 2])


Y0 = jnp.array([1.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def robertson_at_40():
    """SciPy's Radau on a NumPy copy of the equations and their Jacobian: independent of the
    JAX code under test (and fast: no JAX dispatch per call)."""
    def f(t, y):
        return [-0.04 * y[0] + 1e4 * y[1] * y[2],
                0.04 * y[0] - 1e4 * y[1] * y[2] - 3e7 * y[1] ** 2, 3e7 * y[1] ** 2]

    def jac(t, y):
        return [[-0.04, 1e4 * y[2], 1e4 * y[1]],
                [0.04, -1e4 * y[2] - 6e7 * y[1], -1e4 * y[1]],
                [0.0, 6e7 * y[1], 0.0]]
    sol = solve_ivp(f, (0, 40), np.asarray(Y0), method="Radau", rtol=1e-12, atol=1e-16,
                    jac=jac)
    return sol.y[:, -1]


# (method, h, bound on max|x - ref| / max|ref| at t = 40: the method's own error there)
CASES = [("trapezoidal", 0.1, 2e-2), ("gauss_legendre4", 4.0, 1e-4)]


@pytest.mark.parametrize("name, h, bound", CASES)
def test_robertson_either_converges_to_the_method_s_solution_or_says_it_did_not(
        robertson_at_40, name, h, bound):
    n = int(round(40 / h))
    tr = integrate(method(name), robertson, Y0, jnp.zeros(1), {}, h, n)
    x = np.asarray(tr.x)
    if bool(tr.converged):
        assert np.all(np.isfinite(x))
        err = np.max(np.abs(x[-1] - robertson_at_40)) / np.max(np.abs(robertson_at_40))
        assert err <= bound, err
        # The same equations solved to round-off give the same trajectory: the flag is true.
        tight = method(name).with_newton(rtol=1e-14, atol=1e-14, max_iter_full=100)
        exact = integrate(tight, robertson, Y0, jnp.zeros(1), {}, h, n)
        assert bool(exact.converged)
        np.testing.assert_allclose(x, np.asarray(exact.x), rtol=0, atol=1e-8)
    else:
        first = np.argmax(np.isnan(x).any(axis=1))
        assert first > 0 and np.all(np.isnan(x[first:]))


# The step counts of the other tests' Robertson runs of these methods (Newton's options are
# run-time values): the same compiled programs.
STEPS = {"trapezoidal": 400, "gauss_legendre4": 10, "bdf2": 8}


@pytest.mark.parametrize("name", list(STEPS))
def test_a_solve_that_cannot_converge_is_flagged_and_nan(name):
    # Two simplified iterations from Robertson's start, with no full-Newton retry, cannot
    # reach the tolerance: the first step fails, and so does the run.
    m = method(name).with_newton(max_iter=2, max_iter_full=0)
    tr = integrate(m, robertson, Y0, jnp.zeros(1), {}, 0.1, STEPS[name])
    assert not bool(tr.converged)
    assert np.all(np.isnan(np.asarray(tr.x[m.n_start + 1:])))


@pytest.mark.parametrize("name", ["backward_euler", "bdf2"])
def test_newton_options_are_run_time_values_of_the_method_s_program(name):
    """A method with other Newton options (the sweep's retry with more iterations, a
    config's [newton]) runs the method's own compiled program: the driver's jitted function
    gains no entry. The options still decide: two simplified iterations with no full-Newton
    retry fail Robertson's first step, which the defaults solve; four times the defaults'
    iterations give the defaults' converged steps to their tolerance."""
    from stepzoo.integrators import driver
    fn = driver._jitted[(driver._batch, True)]
    f = lambda t, y, u, p: robertson(t, y, u, p)    # a new f: its programs start here
    x0 = jnp.tile(Y0, (40, 1))

    def run(m):
        return integrate_batch(m, f, x0, jnp.zeros((40, 1)), {}, 0.1, 12, max_steps=16)

    base = run(method(name))
    entries = fn._cache_size()
    failed = run(method(name).with_newton(max_iter=2, max_iter_full=0))
    more = run(method(name, NewtonOptions(max_iter=40, max_iter_full=160)))
    assert fn._cache_size() == entries
    assert bool(base.converged.all()) and not bool(failed.converged.any())
    assert bool(more.converged.all())
    x, ref = np.asarray(more.x[:, :13]), np.asarray(base.x[:, :13])
    assert np.max(np.abs(x - ref) / (1 + np.abs(ref))) <= 1e-8


def test_batch_flags_each_trajectory():
    # At y3 = 0 nothing couples y2 back; from a start with y2 already near equilibrium the
    # simplified iteration converges; from (1, 0, 0) it needs the retry, here forbidden.
    m = method("backward_euler").with_newton(max_iter_full=0)
    x0 = jnp.array([[1.0, 0.0, 0.0], [0.9999, 3.6e-5, 6.4e-5]] * 20)
    tr = integrate_batch(m, robertson, x0, jnp.zeros((40, 1)), {}, 0.1, 5)
    assert tr.converged.shape == (40,)
    ok = np.asarray(tr.converged)
    assert not ok[0] and ok[1] and np.all(ok[::2] == ok[0]) and np.all(ok[1::2] == ok[1])
    assert np.all(np.isfinite(np.asarray(tr.x[1::2])))
    assert np.all(np.isnan(np.asarray(tr.x[::2, 1:])))


def test_explicit_methods_always_converge_even_when_they_blow_up():
    f = lambda t, y, u, p: -1e4 * y
    tr = integrate(method("rk4"), f, jnp.array([1.0]), jnp.zeros(1), {}, 0.1, 50)
    assert bool(tr.converged) and not np.all(np.isfinite(np.asarray(tr.x)))


def test_an_implicit_method_s_own_blow_up_is_not_a_solver_failure():
    # am3's region is bounded (real interval -6): at h lambda = -1e3 it grows by 1.7 a step to
    # overflow,
    # each linear solve being exact.
    f = lambda t, y, u, p: -1e4 * y
    tr = integrate(method("am3"), f, jnp.array([1.0]), jnp.zeros(1), {}, 0.1, 1500)
    assert bool(tr.converged) and not np.all(np.isfinite(np.asarray(tr.x)))


def test_newton_options_are_checked():
    with pytest.raises(ValueError, match="max_iter"):
        method("trapezoidal").with_newton(max_iter=0)
    with pytest.raises(ValueError, match="tolerances"):
        method("trapezoidal").with_newton(rtol=0.0, atol=0.0)


@pytest.mark.parametrize("newton, words", [
    ({"max_iter": 20}, "newton must be a NewtonOptions (stepzoo.integrators.newton), got dict"),
    (20, "newton must be a NewtonOptions"),
])
def test_newton_options_of_the_wrong_type_are_one_clear_type_error(newton, words):
    """A dict or a number where NewtonOptions belongs is named as such (it failed in
    asdict(), or as an unhashable cache key), and so is an option of the wrong type."""
    with pytest.raises(TypeError) as err:
        method("trapezoidal", newton)
    assert words in str(err.value)
    with pytest.raises(TypeError, match="NewtonOptions.max_iter must be a number, got '5'"):
        NewtonOptions(max_iter="5")
    with pytest.raises(TypeError, match="NewtonOptions.rtol must be a number, got True"):
        NewtonOptions(rtol=True)


@pytest.mark.parametrize("name", ["radau_iia5", "kvaerno3", "bdf3", "bdf4", "bdf5"])
def test_stiff_methods_observe_their_order_on_a_stiff_linear_problem(name):
    """y' = A y with eigenvalues -1e3 and -1 (a stiff mode coupled to a smooth one), exact
    y = expm(A t) y0: the fitted slope of log error against log h is the declared order
    within 0.2. (A smooth forcing of the stiff mode, as in Prothero-Robinson, would show the
    stage order instead: order reduction, not a defect.)"""
    from scipy.linalg import expm
    a = np.array([[-1e3, 999.0], [0.0, -1.0]])
    f = lambda t, y, u, p: jnp.asarray(a) @ y
    y0 = np.array([2.0, 1.0])
    exact = expm(a * 4.0) @ y0
    hs = np.array([0.4, 0.2, 0.1])
    errs = []
    for h in hs:
        n = int(round(4 / h))      # a run-time step count: one compilation for all h
        tr = integrate(method(name), f, jnp.asarray(y0), jnp.zeros(1), {}, h, n, max_steps=40)
        assert bool(tr.converged)
        errs.append(np.max(np.abs(np.asarray(tr.x[n]) - exact)))
    slope = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert abs(slope - method(name).order) <= 0.2, (name, slope, errs)


@pytest.mark.parametrize("name", ["radau_iia5", "kvaerno3"])
def test_stiff_methods_observe_their_order_on_detest_a2(name):
    """DETEST A2 (Hull, Enright, Fellen & Sedgwick 1972): y' = -y^3/2, y(0) = 1, exact
    y = 1/sqrt(1 + t) on [0, 20]; slope of log error against log h within 0.2 of the order."""
    f = lambda t, y, u, p: -0.5 * y ** 3
    hs = np.array([0.5, 0.25, 0.125])
    errs = []
    for h in hs:
        tr = integrate(method(name), f, jnp.ones(1), jnp.zeros(1), {}, h, int(round(20 / h)))
        assert bool(tr.converged)
        errs.append(abs(float(tr.x[-1, 0]) - 1 / np.sqrt(21.0)))
    slope = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert abs(slope - method(name).order) <= 0.2, (name, slope, errs)


@pytest.mark.parametrize("name", ["bdf3", "bdf4", "bdf5"])
def test_bdf_observes_its_order_on_detest_a4(name):
    """DETEST A4, the logistic curve y' = y/4 (1 - y/20), y(0) = 1, against its closed form
    at t = 20: slope of log error against log h within 0.2 of the order, so the Radau IIA 5
    start-up keeps it."""
    prob = detest.A["a4"]
    truth = float(prob["exact"](np.array([20.0]))[0, 0])
    hs = np.array([0.2, 0.1, 0.05])
    errs = []
    for h in hs:
        n = int(round(20 / h))
        tr = integrate(method(name), prob["rhs"], jnp.asarray(prob["x0"]), None, None, h, n,
                       max_steps=400)
        assert bool(tr.converged)
        errs.append(abs(float(tr.x[n, 0]) - truth))
    slope = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert abs(slope - method(name).order) <= 0.2, (name, slope, errs)


def test_lu_solves_as_numpy_does_batched_and_with_row_swaps():
    """The unrolled elimination (orders up to newton.SMALL) and the looped one (above: Radau
    IIA 5's stage system of a 5-state model is 15) under vmap with the batch last, as the
    driver runs them, against numpy.linalg.solve on seeded well-conditioned matrices; the
    permuted identity plus a small perturbation needs a row swap at every column."""
    import jax

    from stepzoo.integrators.newton import SMALL, lu_factor, lu_solve
    rng = np.random.default_rng(7)
    solve = jax.vmap(lambda a, b: lu_solve(lu_factor(a), b), in_axes=(-1, -1), out_axes=-1)
    for n in (1, 2, 5, SMALL, SMALL + 1, 15):
        a = rng.normal(size=(16, n, n)) + 4 * np.eye(n)
        a[:8] = np.eye(n)[::-1] + 0.1 * a[:8]
        assert np.max(np.linalg.cond(a)) < 1000
        b = rng.normal(size=(16, n))
        x = np.asarray(solve(jnp.asarray(a.transpose(1, 2, 0)), jnp.asarray(b.T))).T
        np.testing.assert_allclose(x, np.linalg.solve(a, b[..., None])[..., 0], rtol=0,
                                   atol=1e-12)


def test_inverse_as_numpy_does_batched_and_with_row_swaps():
    """newton.inverse (Gauss-Jordan, the kept iteration matrices above order SMALL: up to
    58 for Radau IIA 5's complex pair at 29 states) under vmap with the batch last, against
    numpy.linalg.inv, on the matrices of the test above."""
    import jax

    from stepzoo.integrators.newton import inverse
    rng = np.random.default_rng(7)
    invert = jax.jit(jax.vmap(inverse, in_axes=-1, out_axes=-1))  # compiled, as in the driver
    for n in (1, 2, 9, 18, 58):
        a = 2 * rng.normal(size=(16, n, n)) / np.sqrt(n) + 4 * np.eye(n)
        a[:8] = np.eye(n)[::-1] + 0.1 * a[:8]
        assert np.max(np.linalg.cond(a)) < 1000
        x = np.asarray(invert(jnp.asarray(a.transpose(1, 2, 0)))).transpose(2, 0, 1)
        np.testing.assert_allclose(x, np.linalg.inv(a), rtol=0, atol=1e-12)


def test_kept_factors_and_iterations_compile_without_library_calls():
    """What an implicit step runs in its loops, at 29 states over a chunk of 64 lanes (Radau
    IIA 5's inverses of orders 29 and 58, its stage residual and the iteration's error
    norms) compiles without scatters and custom fusions (XLA:CPU's library calls, such as
    its YNNPACK dots and reductions): a while loop holding one is not compiled into one
    native function, and then every operation of every step is a separate call."""
    import jax

    from stepzoo.integrators import method
    from stepzoo.integrators.newton import Stages, largest
    from stepzoo.integrators.steps import stage_system
    tab = method("radau_iia5").scheme
    stages = Stages.of(tab.a)
    d, lanes = 29, 64
    rng = np.random.default_rng(3)
    fun = lambda t, y: -y + 0.1 * jnp.sin(y)

    def step_parts(jac, y, z):
        blocks, size = stages.factors(0.01, jac, 1.0)
        residual = stage_system(tab, fun, 0.0, y, 0.01)[1]
        dz = stages.solver((blocks, size))[0](residual(z))
        return largest(jnp.abs(dz)) + largest(jnp.abs(z)) / size

    args = (rng.normal(size=(lanes, d, d)), rng.normal(size=(lanes, d)),
            rng.normal(size=(lanes, 3 * d)))
    text = jax.jit(jax.vmap(step_parts)).lower(*args).compile().as_text()
    for call in ("scatter(", "kind=kCustom", "custom-call("):
        assert call not in text, call


def test_full_newton_retry_compiles_without_library_calls_in_float32():
    """The full-Newton retry's elimination and solve of Radau IIA 5's whole stage system at
    29 states (order 87) over a chunk of 64 lanes, in float32 as `make bench` runs it,
    compile without custom fusions: XLA:CPU made the looped substitution's dots YNNPACK
    calls, and the retry program's step loop then ran operation by operation."""
    import jax

    from stepzoo.integrators.newton import factorised
    n, lanes = 87, 64
    rng = np.random.default_rng(4)
    mat = (np.eye(n) + 0.1 * rng.normal(size=(lanes, n, n))).astype(np.float32)
    r = rng.normal(size=(lanes, n)).astype(np.float32)
    solve = jax.jit(jax.vmap(lambda m, v: factorised(m)[0](v)))
    text = solve.lower(mat, r).compile().as_text()
    for call in ("scatter(", "kind=kCustom", "custom-call("):
        assert call not in text, call
    x = np.asarray(solve(mat, r), float)
    want = np.linalg.solve(mat.astype(float), r.astype(float)[..., None])[..., 0]
    assert np.max(np.abs(x - want)) <= 1e-4 * np.max(np.abs(want))


@pytest.mark.parametrize("name", ["trapezoidal", "backward_euler", "bdf3"])
def test_unrolled_elimination_steps_as_the_looped_one_does(monkeypatch, name):
    """Robertson's steps with the unrolled elimination land where the looped one's
    (newton.SMALL = 0) land, to the Newton tolerance (1e-10, weighted by 1 + |y|), and agree
    on convergence. Another step count, so that the looped run compiles afresh; the
    trapezoidal rule's is its Robertson run's above, the same program."""
    from stepzoo.integrators import newton
    n = STEPS["trapezoidal"] if name == "trapezoidal" else 30
    # From Robertson's start the simplified iteration fails: the retry from the first run.
    # SMALL = 0 makes 3 states "large" to the kept factors' rule too: one rate for both.
    same = lambda: retrying(name).with_newton(keep_large=newton.THETA_KEEP)
    ours = integrate(same(), robertson, Y0, jnp.zeros(1), {}, 0.1, n)
    monkeypatch.setattr(newton, "SMALL", 0)
    looped = integrate(same(), robertson, Y0, jnp.zeros(1), {}, 0.1, n + 1)
    assert bool(ours.converged) and bool(looped.converged)
    x, ref = np.asarray(ours.x), np.asarray(looped.x[:n + 1])
    assert np.max(np.abs(x - ref) / (1 + np.abs(ref))) <= 1e-10


@pytest.mark.parametrize("name", ["radau_iia5", "radau_iia3", "gauss_legendre4"])
def test_transformed_stage_system_solves_as_the_whole_one_does(name):
    """(I - h A (x) J)^-1 r through A's eigenvalues (one real and one complex d x d system
    for Radau IIA 5, RADAU5's transformation) against numpy.linalg.solve of the s d x s d
    system, with the size 1 + |h A (x) J|_inf, on a seeded J."""
    from stepzoo.integrators.newton import Stages
    a = method(name).scheme.a
    s, d, h = a.shape[0], 5, 0.3
    rng = np.random.default_rng(3)
    jac, r = rng.normal(size=(d, d)) * 10, rng.normal(size=s * d)
    solve, size = Stages.of(a).factorised(h, jnp.asarray(jac),
                                          float(np.max(np.abs(a).sum(axis=1))))
    whole = np.eye(s * d) - h * np.kron(a, jac)
    exact = np.linalg.solve(whole, r)
    np.testing.assert_allclose(np.asarray(solve(jnp.asarray(r))), exact, rtol=0,
                               atol=1e-12 * np.max(np.abs(exact)))
    assert float(size) == pytest.approx(1 + np.max(np.abs(h * np.kron(a, jac)).sum(axis=1)),
                                        rel=1e-14)


def _new_program(name):
    """A copy of the zoo's method: a program of its own, nothing compiled or retried yet."""
    return dataclasses.replace(method(name))


def _with_retry(m, f, x0, h, n):
    """The driver's program with the full-Newton retry compiled in, run directly."""
    fn = driver._jitted[(driver._integrate, False)]
    return fn(m.program, f, x0, jnp.zeros(1), {}, h, n, 0.0, None, newton=m.run_options(),
              retry=True)[0]


def test_a_run_whose_solves_converge_runs_one_program_without_the_retry():
    """Every solve converges by the simplified iteration: one program is compiled (without
    the full-Newton retry) and its states are the program-with-retry's, bit for bit."""
    m = _new_program("bdf2")
    x0 = jnp.array([0.9999, 3.6e-5, 6.4e-5])
    fn = driver._jitted[(driver._integrate, False)]
    before = fn._cache_size()
    tr = integrate(m, robertson, x0, jnp.zeros(1), {}, 0.1, 8)
    assert fn._cache_size() == before + 1 and m.program not in driver._RETRIED
    assert bool(tr.converged)
    assert np.array_equal(np.asarray(tr.x), np.asarray(_with_retry(m, robertson, x0, 0.1, 8).x))


def test_a_failed_simplified_solve_runs_again_with_the_full_newton_retry():
    """Two simplified iterations fail Robertson's first step; the run is made again with the
    retry, which solves it, and later runs of the program take the retry at once."""
    m = _new_program("backward_euler").with_newton(max_iter=2)
    tr = integrate(m, robertson, Y0, jnp.zeros(1), {}, 0.1, 5)
    assert bool(tr.converged) and m.program in driver._RETRIED
    assert np.array_equal(np.asarray(tr.x), np.asarray(_with_retry(m, robertson, Y0, 0.1, 5).x))
    # Without the retry allowed, the failure is the result: no run is made again.
    fn = driver._jitted[(driver._integrate, False)]
    lean = _new_program("backward_euler").with_newton(max_iter=2, max_iter_full=0)
    before = fn._cache_size()
    assert not bool(integrate(lean, robertson, Y0, jnp.zeros(1), {}, 0.1, 5).converged)
    assert fn._cache_size() == before + 1 and lean.program not in driver._RETRIED


def test_a_solve_failing_from_a_blown_up_state_is_retried_too():
    """Beyond finfo.max^(1/4) a failed solve leaves `converged` true (the method's own
    blow-up), but the retry might have solved it: the run is made again with it."""
    m = _new_program("backward_euler")
    cubic = lambda t, y, u, p: -y ** 3
    tr = integrate(m, cubic, jnp.array([1e110]), jnp.zeros(1), {}, 0.1, 2)
    assert bool(tr.converged) and np.isnan(np.asarray(tr.x)[-1, 0])
    assert m.program in driver._RETRIED


def test_a_sweep_s_runs_carry_the_retry_from_the_first():
    """A sweep probes steps where solves fail: its runner compiles the program with the
    retry only, not the one without it first."""
    from stepzoo.bench.sweep.runs.method_runs import Runner
    m = _new_program("backward_euler")
    spec = type("Spec", (), {"rhs": staticmethod(robertson)})()
    watch = type("Watch", (), {"split": lambda self: contextlib.nullcontext({"run": 0.0})})()
    fn = driver._jitted[(driver._batch, True)]
    before = fn._cache_size()
    run = Runner(spec, 4, watch)(m, np.tile(np.asarray(Y0), (3, 1)), np.zeros((3, 1)), {},
                                 0.1, 4)
    assert run.converged.all() and fn._cache_size() == before + 1
    assert m.program in driver._RETRIED


def _iterate_on_errors(rate_far, rate_near, near=0.5):
    """newton._iterate on the fixed-point map z -> 1 - rate(e) e, e = 1 - z the error (the
    identity as the iteration matrix, so the increment is the residual z - 1 + rate(e) e):
    the error shrinks by `rate_far` while above `near`, then by `rate_near`. Tolerance
    1e-10 on a start of zeros: ten orders of magnitude to go."""
    from stepzoo.integrators.newton import _iterate

    def residual(z):
        e = 1.0 - z
        return -(e - jnp.where(jnp.abs(e) > near, rate_far, rate_near) * e)

    opts = NewtonOptions()
    ident = (lambda r: r), jnp.asarray(1.0)
    return _iterate(residual, ident, jnp.zeros(1), jnp.zeros(1), opts, False,
                    jnp.asarray(False))


def test_a_slow_first_rate_does_not_give_up_a_solve_that_converges_within_the_limit():
    """Errors 1, 0.3, 3e-4, 3e-7, ...: the first rate (0.43, of the increments 0.7 and 0.3)
    forecast over the eight iterations left reaches 1e-10 nowhere near; the rates after it
    (1e-3) do within five. The solve converges to the tolerance (newton.FORECAST_FROM)."""
    z, k, ok, theta = _iterate_on_errors(0.3, 1e-3)
    assert bool(ok) and int(k) <= 6
    assert abs(1.0 - float(z[0])) <= 1e-10
    assert float(theta) <= 2e-3


def test_a_solve_that_keeps_a_slow_rate_is_still_given_up_early():
    """A rate of 0.5 throughout cannot take 1 to 1e-10 in ten iterations: the forecast gives
    up at the third iterate, not at the iteration limit."""
    _, k, ok, theta = _iterate_on_errors(0.5, 0.5)
    assert not bool(ok) and int(k) == 3
    assert float(theta) == pytest.approx(0.5)
