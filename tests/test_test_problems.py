"""The DETEST and stiff test problems: every closed form satisfies its ODE and its published
initial value; every reference agrees with an independent solver or a published value."""
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.dynamics import MODELS, model
from stepzoo.dynamics.detest import kepler_exact
from stepzoo.dynamics.solutions import solve
from stepzoo.dynamics.stiff import PUBLISHED_END

PROBLEMS = [n for n, m in MODELS.items() if m.family in ("detest", "stiff")]
EXACT = [n for n in PROBLEMS if MODELS[n].exact is not None]
REFERENCE = [n for n in PROBLEMS if MODELS[n].exact is None]


def test_the_sets_are_complete():
    assert {f"detest_{c}{i}" for c in "abcde" for i in range(1, 6)} <= set(PROBLEMS)
    assert {"robertson", "vdp1000", "hires", "stiff_linear"} <= set(PROBLEMS)
    assert set(REFERENCE) == {"detest_b1", "detest_c5", "detest_e2", "detest_e3",
                              "robertson", "vdp1000", "hires"}


@pytest.mark.parametrize("name", EXACT)
def test_closed_form_satisfies_the_ode_and_the_published_initial_value(name):
    """Fourth-order central differences of the closed form equal f at interior points."""
    m = model(name)
    t0, t1 = m.t_span
    ts = np.linspace(t0, t1, 9)[1:-1]
    h = 1e-4
    x = m.exact
    dx = (x(ts - 2 * h) - 8 * x(ts - h) + 8 * x(ts + h) - x(ts + 2 * h)) / (12 * h)
    f = np.array([m.rhs(t, jnp.asarray(xi), jnp.zeros(0), m.params()) for t, xi in zip(ts, x(ts))])
    np.testing.assert_allclose(dx, f, rtol=1e-8, atol=1e-8 * np.max(np.abs(f)))
    np.testing.assert_allclose(x(np.array([t0]))[0], m.x0, rtol=1e-15, atol=1e-15)


def test_kepler_orbits_close_after_one_period():
    """Unit semi-major axis and mean motion: period 2 pi, for every eccentricity of D1-D5."""
    for e in (0.1, 0.3, 0.5, 0.7, 0.9):
        x = kepler_exact(np.array([0.0, 2 * np.pi, 6 * np.pi]), e)
        np.testing.assert_allclose(x[1:], x[[0, 0]], atol=1e-12)


@pytest.mark.parametrize("name", [n for n in REFERENCE if n.startswith("detest")])
def test_detest_reference_agrees_with_an_independent_solver(name):
    """DOP853 at rtol 1e-13 against LSODA's Adams at rtol 1e-12 over the whole interval."""
    m = model(name)
    ts = np.linspace(*m.t_span, 5)
    other = solve(m.rhs, m.x0, m.u0, m.params(), ts, method="LSODA", rtol=1e-12, atol=1e-14)
    scale = np.max(np.abs(other))
    np.testing.assert_allclose(m.solution(ts), other, atol=1e-8 * scale)


@pytest.mark.parametrize("name", sorted(PUBLISHED_END))
def test_stiff_reference_meets_the_test_sets_published_end_value(name):
    m = model(name)
    x_end = m.solution(np.array(m.t_span))[-1]
    np.testing.assert_allclose(x_end, PUBLISHED_END[name], rtol=1e-9)


def test_robertson_reference_agrees_with_radau_and_conserves_mass():
    m = model("robertson")
    ts = np.array([0.0, 0.4, 4.0, 40.0])
    x = m.solution(ts)
    radau = solve(m.rhs, m.x0, m.u0, m.params(), ts, method="Radau", rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(x, radau, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(x.sum(axis=1), 1.0, atol=1e-12)


def test_stiff_linear_is_stiff_and_its_solution_is_smooth():
    """Eigenvalues -1 and -1000 (Jacobian by jacfwd), while the exact solution varies on the
    slow scale only: the regime where explicit methods are limited by stability."""
    import jax
    m = model("stiff_linear")
    J = jax.jacfwd(m.rhs, argnums=1)(0.0, jnp.asarray(m.x0), jnp.zeros(0), m.params())
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(np.asarray(J)).real), [-1000, -1])
    ts = np.linspace(0.0, 1e-3, 3)
    assert np.max(np.abs(np.diff(m.solution(ts), axis=0))) < 3e-3


def test_vehicle_truth_of_the_paper_point_is_its_closed_form():
    """dynamic5's default problem (15 m/s, pi/4, from rest) has the exact solution of
    exact.py; the DOP853 reference path agrees with it."""
    m = model("dynamic5")
    ts = np.linspace(0.0, 2.0, 5)
    x = solve(m.rhs, m.x0, m.u0, m.params(), ts)
    np.testing.assert_allclose(m.solution(ts), x, rtol=1e-9, atol=1e-9)
