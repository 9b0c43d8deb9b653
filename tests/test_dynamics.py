"""The models: closed-form lateral matrix equals the AD Jacobian, NOTES.md's eigenvalues,
and the right-hand sides work under jit, vmap and jacfwd."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.dynamics import model, physical, vehicle, vehicle_names
from stepzoo.dynamics.linear import lateral_eigenvalues, lateral_matrix, state_jacobian


@pytest.mark.parametrize("vx,delta", [(15.0, np.pi / 4), (2.0, 0.0), (30.0, -0.3)])
@pytest.mark.parametrize("name", ["bmw320i", "ge2021", "notes_example"])
def test_lateral_matrix_equals_ad_jacobian(name, vx, delta):
    m = model("dynamic5")
    p = m.params(name, vx)
    x = jnp.array([3.0, -1.0, 0.4, 0.2, -0.1])
    J = state_jacobian(m.rhs, 0.0, x, jnp.array([delta]), p)
    A, _ = lateral_matrix(vx, delta, p)
    np.testing.assert_allclose(J[3:, 3:], A, rtol=1e-13, atol=1e-12)


def test_lateral_affine_term_matches_rhs_at_zero_lateral_motion():
    m = model("dynamic5")
    p = m.params("notes_example", 15.0)
    _, b = lateral_matrix(15.0, 0.3, p)
    f = m.rhs(0.0, jnp.zeros(5), jnp.array([0.3]), p)
    np.testing.assert_allclose(f[3:], b, rtol=1e-14)


def test_notes_example_eigenvalues():
    p = physical("notes_example")
    ev = np.sort_complex(np.asarray(lateral_eigenvalues(15.0, np.pi / 4, p)))
    np.testing.assert_allclose(ev.real, [-6.85, -6.85], atol=0.01)
    np.testing.assert_allclose(np.abs(ev.imag), [4.38, 4.38], atol=0.01)
    ev2 = np.sort(np.asarray(lateral_eigenvalues(2.0, np.pi / 4, p)).real)
    np.testing.assert_allclose(ev2, [-67.2, -35.5], atol=0.1)


def test_eigenvalues_scale_like_inverse_speed():
    p = physical(None)
    lam = [np.max(np.abs(np.asarray(lateral_eigenvalues(v, 0.0, p)))) for v in (2.0, 4.0)]
    assert 1.7 < lam[0] / lam[1] < 2.1


@pytest.mark.parametrize("name", ["dynamic5", "dynamic6", "kinematic"])
def test_rhs_under_jit_vmap_jacfwd(name):
    m = model(name)
    p = m.params(None, 10.0)
    x0, u = m.from_rest(10.0, 0.2)
    f = jax.jit(m.rhs)
    xs = jnp.stack([x0 + 0.01 * i for i in range(4)])
    batched = jax.vmap(lambda x: f(0.0, x, u, p))(xs)
    one = jnp.stack([m.rhs(0.0, x, u, p) for x in xs])
    np.testing.assert_allclose(batched, one, rtol=1e-14)
    J = jax.jacfwd(m.rhs, argnums=1)(0.0, x0, u, p)
    assert J.shape == (len(m.states), len(m.states)) and np.all(np.isfinite(J))


def test_full_model_reduces_to_reduced_at_constant_speed():
    """With no longitudinal forces the 6-state model's lateral equations are the 5-state ones."""
    m5, m6 = model("dynamic5"), model("dynamic6")
    p5 = m5.params(None, 12.0)
    x5 = jnp.array([1.0, 2.0, 0.3, 0.4, 0.1])
    x6 = jnp.array([1.0, 2.0, 0.3, 12.0, 0.4, 0.1])
    f5 = m5.rhs(0.0, x5, jnp.array([0.2]), p5)
    f6 = m6.rhs(0.0, x6, jnp.array([0.2, 0.0, 0.0]), m6.params(None, 12.0))
    np.testing.assert_allclose(np.asarray(f6)[[0, 1, 2, 4, 5]], f5, rtol=1e-14)


def test_every_vehicle_names_a_published_source():
    for name in vehicle_names():
        v = vehicle(name)
        assert len(v["source"]) > 20
        assert all(v[k] > 0 for k in ("m", "Iz", "Lf", "Lr", "Caf", "Car", "length", "width"))


def test_unknown_vehicle_and_model_name_the_known_ones():
    with pytest.raises(KeyError, match="bmw320i"):
        vehicle("nope")
    with pytest.raises(KeyError, match="dynamic5"):
        model("nope")
