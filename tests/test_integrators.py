"""The zoo and its driver: coefficients, validation, batching, stiff behaviour."""
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.integrators import METHODS, integrate, integrate_batch, method
from stepzoo.integrators.multistep import adams_bashforth, adams_moulton, bdf
from stepzoo.integrators.tableau import ButcherTableau


def test_multistep_factories_give_the_textbook_coefficients():
    np.testing.assert_allclose(adams_bashforth(4).beta, [-9 / 24, 37 / 24, -59 / 24, 55 / 24, 0])
    np.testing.assert_allclose(adams_moulton(3).beta, [1 / 24, -5 / 24, 19 / 24, 9 / 24])
    lmm = bdf(2)
    np.testing.assert_allclose(lmm.alpha, [1 / 3, -4 / 3, 1])
    np.testing.assert_allclose(lmm.beta, [0, 0, 2 / 3])


def test_tableau_validation_rejects_inconsistent_data():
    with pytest.raises(ValueError, match="weights"):
        ButcherTableau(np.zeros((2, 2)), np.array([0.5, 0.4]), np.zeros(2))
    with pytest.raises(ValueError, match="row sums"):
        ButcherTableau(np.array([[0, 0], [1, 0]]), np.array([0.5, 0.5]), np.array([0, 0.5]))


def test_dopri5_fixed_step_skips_its_fsal_stage():
    assert METHODS["dopri5"].stages == 7 and METHODS["dopri5"].rhs_evals_per_step == 6


def test_run_time_step_count_equals_compiled_step_count(paper_point):
    """The same 137 steps, counted at run time or compiled in: the same states to a
    rounding (the two programs are compiled apart, and LLVM may contract a multiply and an
    add into one in either: 1 element of 690 differed by 2e-16 relative, 4e-19 absolute)."""
    m, p, x0, u = paper_point
    for name in ("rk4", "ab4", "trapezoidal"):
        a = integrate(method(name), m.rhs, x0, u, p, 0.01, 137)
        b = integrate(method(name), m.rhs, x0, u, p, 0.01, jnp.asarray(137), max_steps=300)
        np.testing.assert_allclose(a.x, b.x[:138], rtol=1e-13, atol=1e-15)
        assert np.all(np.isnan(b.x[138:]))
        assert float(a.evals) == float(b.evals)


@pytest.mark.parametrize("name", ["rk4", "ab4", "radau_iia3", "bdf2"])
def test_vmapped_batch_equals_one_by_one(name):
    from stepzoo.dynamics import model
    m = model("dynamic5")
    vxs, deltas = np.array([2.0, 8.0, 15.0, 30.0]), np.array([-0.7, 0.1, 0.785, 0.3])
    x0 = jnp.array([[0, 0, 0, 0.1 * i, -0.05 * i] for i in range(4)], dtype=float)
    u = jnp.asarray(deltas)[:, None]
    ps = [m.params(None, v) for v in vxs]
    p = {k: jnp.array([q[k] for q in ps]) for k in ps[0]}
    batch = integrate_batch(method(name), m.rhs, x0, u, p, 0.002, 200)
    for i in range(4):
        one = integrate(method(name), m.rhs, x0[i], u[i], ps[i], 0.002, 200)
        np.testing.assert_allclose(batch.x[i], one.x, rtol=1e-13, atol=1e-13)


def _decay(t, y, u, p):
    return p["lam"] * y


# Adams-Moulton methods of order >= 3 are implicit but not A-stable: their stability regions
# are bounded (real interval about -6 and -3), so they must blow up here; see the next test.
A_STABLE_IMPLICIT = ["backward_euler", "trapezoidal", "gauss_legendre4", "radau_iia3", "bdf2"]


@pytest.mark.parametrize("name", A_STABLE_IMPLICIT)
def test_implicit_methods_stay_bounded_on_a_stiff_problem(name):
    tr = integrate(method(name), _decay, jnp.array([1.0]), jnp.zeros(1), {"lam": -1e4}, 0.1, 50)
    x = np.asarray(tr.x[:, 0])
    assert np.all(np.isfinite(x)) and np.max(np.abs(x)) <= 1.0 + 1e-12


@pytest.mark.parametrize("name", ["rk4", "ab2", "am3", "am4"])
def test_methods_with_bounded_regions_blow_up_on_the_same_stiff_problem(name):
    tr = integrate(method(name), _decay, jnp.array([1.0]), jnp.zeros(1), {"lam": -1e4}, 0.1, 50)
    assert not np.all(np.abs(np.asarray(tr.x)) < 1e3)


def test_backward_euler_decays_monotonically_on_the_stiff_problem():
    tr = integrate(method("backward_euler"), _decay, jnp.array([1.0]), jnp.zeros(1),
                   {"lam": -1e4}, 0.1, 50)
    x = np.asarray(tr.x[:, 0])
    assert np.all(x > 0) and np.all(np.diff(x) < 0)
    np.testing.assert_allclose(x[1], 1.0 / (1.0 + 1e3), rtol=1e-12)


def test_explicit_evaluation_count_is_stages_times_steps(paper_point):
    m, p, x0, u = paper_point
    tr = integrate(method("rk6"), m.rhs, x0, u, p, 0.01, 100)
    assert float(tr.evals) == 700


def test_batch_with_one_step_size_per_trajectory(paper_point):
    m, p, x0, u = paper_point
    hs = jnp.array([0.01, 0.02, 0.05])
    pb = {k: jnp.full(3, v) for k, v in p.items()}
    batch = integrate_batch(method("rk4"), m.rhs, jnp.stack([x0] * 3), jnp.stack([u] * 3), pb,
                            hs, 40)
    for i, h in enumerate([0.01, 0.02, 0.05]):
        one = integrate(method("rk4"), m.rhs, x0, u, p, h, 40)
        np.testing.assert_allclose(batch.x[i], one.x, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(batch.t[i], one.t, rtol=1e-15)
