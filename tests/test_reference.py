"""The adaptive Dormand-Prince reference against the exact solution and against scipy."""
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

from stepzoo.dynamics import model
from stepzoo.dynamics.exact import exact_reduced
from stepzoo.integrators.reference import reference


def test_reference_matches_exact_solution_of_the_reduced_model(paper_point):
    m, p, x0, u = paper_point
    ts = np.linspace(0.0, 5.0, 51)
    ref = reference(m.rhs, x0, u, p, ts, rtol=1e-10, atol=1e-12)
    truth = exact_reduced(ts, np.asarray(x0), np.pi / 4, p)
    assert bool(ref.success)
    rel = np.max(np.abs(np.asarray(ref.x) - truth)) / np.max(np.abs(truth))
    assert rel < 1e-8, rel
    assert int(ref.accepted) > 0 and int(ref.evals) == 2 + 6 * int(ref.accepted + ref.rejected)


def test_reference_matches_dop853_on_the_full_model():
    m = model("dynamic6")
    p = m.params(None, 15.0)
    x0 = jnp.array([0.0, 0.0, 0.0, 15.0, 0.0, 0.0])
    u = jnp.array([np.pi / 4, 300.0, 500.0])            # steer and braking forces
    ts = np.linspace(0.0, 5.0, 26)
    ref = reference(m.rhs, x0, u, p, ts, rtol=1e-10, atol=1e-12)
    sol = solve_ivp(lambda t, y: np.asarray(m.rhs(t, y, u, p)), (0, 5), np.asarray(x0),
                    method="DOP853", rtol=1e-12, atol=1e-12, t_eval=ts)
    rel = np.max(np.abs(np.asarray(ref.x) - sol.y.T)) / np.max(np.abs(sol.y))
    assert rel < 1e-8, rel


def test_reference_lands_on_repeated_and_start_times(paper_point):
    m, p, x0, u = paper_point
    ts = np.array([0.0, 0.0, 0.5, 0.5, 1.0])
    ref = reference(m.rhs, x0, u, p, ts)
    x = np.asarray(ref.x)
    np.testing.assert_array_equal(x[0], x0)
    np.testing.assert_array_equal(x[2], x[3])
    assert np.all(np.isfinite(x))


def test_reference_reports_failure_when_out_of_steps(paper_point):
    m, p, x0, u = paper_point
    ref = reference(m.rhs, x0, u, p, np.linspace(0, 5, 3), max_steps=5)
    assert not bool(ref.success)
