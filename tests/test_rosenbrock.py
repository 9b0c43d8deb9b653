"""The Rosenbrock methods: their coefficients meet Hairer & Wanner's order conditions up to the
declared order and no further; the step factorises once and evaluates f once per distinct
stage argument; a time-dependent f gives what its autonomous form gives; observed orders on a
stiff linear system and on DETEST A3 match the declared ones (ROS3P's also on a stiff forced
one); R(z) is the published one."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import expm

from stepzoo.dynamics.problems import detest
from stepzoo.dynamics.problems import stiff
from stepzoo.integrators import METHODS, integrate, method, newton
from stepzoo.integrators.stability import amplification_empirical, amplification_theory

ROSENBROCK = [n for n, m in METHODS.items() if m.is_rosenbrock]


def order_residuals(alpha, gamma, b):
    """Residuals of the order conditions of HW IV.7, Table 7.1 (orders 1-4), by order; beta
    is alpha + Gamma without its diagonal, beta'_i and alpha_i its and alpha's row sums."""
    g = gamma[0, 0]
    beta = alpha + np.tril(gamma, -1)
    bp, a = beta.sum(axis=1), alpha.sum(axis=1)
    return {1: [b.sum() - 1],
            2: [b @ bp - (1 / 2 - g)],
            3: [b @ a ** 2 - 1 / 3, b @ beta @ bp - (1 / 6 - g + g * g)],
            4: [b @ a ** 3 - 1 / 4, b @ (a * (alpha @ bp)) - (1 / 8 - g / 3),
                b @ beta @ a ** 2 - (1 / 12 - g / 3),
                b @ beta @ beta @ bp - (1 / 24 - g / 2 + 3 * g * g / 2 - g ** 3)]}


def test_the_zoo_has_ros2_ros3p_and_rodas3():
    assert set(ROSENBROCK) == {"ros2", "ros3p", "rodas3"}
    assert {METHODS[n].family for n in ROSENBROCK} == {"Rosenbrock"}


@pytest.mark.parametrize("name", ROSENBROCK)
def test_order_conditions_hold_to_the_declared_order_and_fail_beyond(name):
    """b meets every condition up to the declared order p and not all of order p + 1; the
    embedded b_hat likewise with p - 1. (The conditions were checked on RODAS4, order 4.)"""
    m = method(name)
    ros, p = m.scheme, m.order
    for weights, q in ((ros.b, p), (ros.b_hat, p - 1)):
        res = order_residuals(ros.alpha, ros.gamma, weights)
        assert max(abs(r) for k in range(1, q + 1) for r in res[k]) < 1e-14, (name, q, res)
        assert max(abs(r) for r in res[q + 1]) > 1e-3, (name, q + 1, res[q + 1])


def test_ros2_stability_function_is_the_published_one_by_both_routes():
    """Verwer et al. 1999: R(z) = (1 + (1 - 2 gamma) z) / (1 - gamma z)^2, gamma = 1 + 1/sqrt 2
    (the z^2 term of the numerator vanishes: L-stable)."""
    g = 1 + 1 / np.sqrt(2)
    rng = np.random.default_rng(0)
    z = rng.normal(scale=20.0, size=200) + 1j * rng.normal(scale=20.0, size=200)
    want = np.abs((1 + (1 - 2 * g) * z) / (1 - g * z) ** 2)
    for got in (amplification_theory(method("ros2"), z),
                amplification_empirical(method("ros2"), z)):
        np.testing.assert_allclose(got, want, rtol=1e-12)


def _primitives(jaxpr) -> list:
    """Names of the primitives of a jaxpr, nested ones (jit, custom rules) included."""
    names = []
    for eqn in jaxpr.eqns:
        names.append(eqn.primitive.name)
        for v in eqn.params.values():
            for sub in (v if isinstance(v, (list, tuple)) else [v]):
                if isinstance(sub, jax.extend.core.ClosedJaxpr):
                    names += _primitives(sub.jaxpr)
                elif isinstance(sub, jax.extend.core.Jaxpr):
                    names += _primitives(sub)
    return names


def _calls_and_primitives(name, d=3):
    """Python calls of f while one step is traced, and the primitives of that step."""
    m = method(name)
    calls = []
    mat = -jnp.arange(1.0, 1.0 + d * d).reshape(d, d) / d

    def fun(t, y):
        calls.append(t)
        return mat @ y + jnp.sin(t)

    y0 = jnp.ones(d)
    factorisations = []
    lu_factor = newton.lu_factor
    newton.lu_factor = lambda mat: factorisations.append(mat.shape) or lu_factor(mat)
    try:
        jaxpr = jax.make_jaxpr(lambda t, y, h: m.step(fun, t, y, h, m.init_state(y))[0])(
            0.0, y0, 0.1)
    finally:
        newton.lu_factor = lu_factor
    return len(calls), _primitives(jaxpr.jaxpr), len(factorisations)


@pytest.mark.parametrize("name", ROSENBROCK)
def test_one_factorisation_per_step_and_one_evaluation_per_distinct_stage(name):
    """The traced step holds one LU, no loop (no Newton) and calls f once per distinct stage
    argument (the first comes with the derivatives' forward pass); evals counts those plus
    the d + 1 columns of [f_t, J]."""
    m = method(name)
    n_calls, prims, n_lu = _calls_and_primitives(name)
    assert n_lu == 1 and "while" not in prims, prims
    assert n_calls == m.rhs_evals_per_step == len(set(m.scheme.same_as))
    assert m.rhs_evals_per_step == {"ros2": 2, "ros3p": 2, "rodas3": 3}[name]
    tr = integrate(m, lambda t, y, u, p: -y, jnp.ones(3), h=0.1, n_steps=4)
    assert float(tr.evals) == 4 * (3 + 1 + m.rhs_evals_per_step)


@pytest.mark.parametrize("name", ROSENBROCK)
def test_a_time_dependent_problem_equals_its_autonomous_form(name):
    """DETEST A3, y' = y cos t, against (y, t)' = (y cos t, 1): a Rosenbrock method with
    gamma_i = sum_j gamma_ij and the df/dt term is invariant under autonomisation (HW IV.7),
    so both give the same y to round-off; without the df/dt term they differ by O(h^2)."""
    f = detest.PROBLEMS["detest_a3"]["rhs"]
    auto = lambda t, z, u, p: jnp.concatenate([f(z[1], z[:1], u, p), jnp.ones(1)])
    h, n = 0.05, 100
    y = integrate(name, f, jnp.ones(1), h=h, n_steps=n).x[:, 0]
    z = integrate(name, auto, jnp.array([1.0, 0.0]), h=h, n_steps=n).x
    np.testing.assert_allclose(z[:, 1], h * np.arange(n + 1), rtol=1e-14)
    np.testing.assert_allclose(y, z[:, 0], rtol=1e-12)
    assert float(jnp.max(jnp.abs(y - jnp.exp(jnp.sin(z[:, 1]))))) < 1e-2


def _slope(name, f, y0, t_end, hs, truth):
    """Fitted slope of log |error at t_end| against log h, one compilation for all h."""
    n_max = int(round(t_end / min(hs)))
    errs = []
    for h in hs:
        n = int(round(t_end / h))
        tr = integrate(name, f, y0, h=h, n_steps=jnp.asarray(n), max_steps=n_max)
        assert bool(tr.converged)
        errs.append(np.max(np.abs(np.asarray(tr.x[n]) - truth)))
    return np.polyfit(np.log(hs), np.log(errs), 1)[0], errs


@pytest.mark.parametrize("name", ROSENBROCK)
def test_observed_order_on_a_stiff_linear_problem(name):
    """y' = A y with eigenvalues -1e3 and -1, exact expm(A t) y0 at t = 4: slope within 0.2 of
    the order. h from 0.025 down: above it ROS3P's stiff mode (|R(-inf)| = 0.73) still
    shows in the error at t = 4."""
    a = np.array([[-1e3, 999.0], [0.0, -1.0]])
    y0 = np.array([2.0, 1.0])
    slope, errs = _slope(name, lambda t, y, u, p: jnp.asarray(a) @ y, jnp.asarray(y0), 4.0,
                         np.array([0.025, 0.0125, 0.00625]), expm(4.0 * a) @ y0)
    assert abs(slope - method(name).order) <= 0.2, (name, slope, errs)


@pytest.mark.parametrize("name", ROSENBROCK)
def test_observed_order_on_detest_a3(name):
    """DETEST A3 (time-dependent), exact exp(sin t) at t = 20: slope within 0.2 of the order.
    ROS2's error constant is small on A3, its h^3 term dominates down to h ~ 0.01: the
    asymptotic range starts below."""
    d = detest.PROBLEMS["detest_a3"]
    slope, errs = _slope(name, d["rhs"], jnp.ones(1), 20.0, np.array([1, 1 / 2, 1 / 4]) / 256,
                         d["exact"](np.array([20.0]))[0])
    assert abs(slope - method(name).order) <= 0.2, (name, slope, errs)


def test_ros2_equals_verwer_s_own_form_on_robertson():
    """ROS2 as Verwer et al. 1999 write it, (I - gamma h J) k1 = f(y), (I - gamma h J) k2 =
    f(y + h k1) - 2 k1, y1 = y + 3/2 h k1 + 1/2 h k2, in NumPy: the same 20 steps on Robertson's
    problem (nonlinear, stiff). From y2 = 0 the first Jacobian misses the stiff coupling, and
    y2 goes negative at once: the method's own result, which both forms share."""
    d = stiff.PROBLEMS["robertson"]
    f = lambda t, y, u, p: d["rhs"](t, y, u, d["params"])
    g, h, n = 1 + 1 / np.sqrt(2), 0.01, 20
    fn = lambda y: np.asarray(f(0.0, jnp.asarray(y), None, None))
    jac = jax.jit(jax.jacfwd(lambda y: f(0.0, y, None, None)))
    y, want = np.array(d["x0"]), [np.array(d["x0"])]
    for _ in range(n):
        w = np.eye(3) - g * h * np.asarray(jac(jnp.asarray(y)))
        k1 = np.linalg.solve(w, fn(y))
        k2 = np.linalg.solve(w, fn(y + h * k1) - 2 * k1)
        y = y + 1.5 * h * k1 + 0.5 * h * k2
        want.append(y)
    got = np.asarray(integrate("ros2", f, jnp.asarray(d["x0"]), h=h, n_steps=n).x)
    np.testing.assert_allclose(got, np.array(want), rtol=1e-10, atol=1e-15)
    assert got[1, 1] < 0


def test_ros3p_keeps_its_order_on_a_stiff_forced_problem():
    """Lambert's x' = A x + g(t) (eigenvalues -1 and -1000), exact at t = 2, with h lambda from
    -50 to -12.5: ROS3P was built to show no order reduction there (Lang & Verwer 2001); its
    slope is 3 within 0.2. (Rodas3 measures 1.1 to 1.6 on the same steps: order reduction.)"""
    d = stiff.PROBLEMS["stiff_linear"]
    slope, errs = _slope("ros3p", d["rhs"], jnp.asarray(d["x0"]), 2.0,
                         np.array([0.05, 0.025, 0.0125]), d["exact"](np.array([2.0]))[0])
    assert abs(slope - 3) <= 0.2, (slope, errs)


def test_no_nonlinear_solve_so_converged_stays_true_through_a_blow_up():
    """At h lambda = 1/gamma, R's pole, I - h gamma J is singular: the state goes non-finite,
    the method's own result, and converged stays True."""
    m = method("ros2")
    lam = 2.0
    tr = integrate(m, lambda t, y, u, p: lam * y, jnp.ones(1),
                   h=1 / (lam * m.scheme.gamma_diag), n_steps=3)
    assert bool(tr.converged) and not np.all(np.isfinite(np.asarray(tr.x)))
