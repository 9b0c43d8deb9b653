"""The model registry, the tyre laws and the CommonRoad single-track model: every model is
data of one shape; each nonlinear tyre reduces to the linear cornering stiffness at small
slip; ST reproduces CommonRoad's published derivative and trajectories."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.dynamics import MODELS, model, vehicle
from stepzoo.dynamics.solutions import solve
from stepzoo.dynamics.tyres import TYRES, tyre_law

G = 9.81


@pytest.mark.parametrize("name", list(MODELS))
def test_every_model_is_data_of_one_shape_and_keeps_the_callers_dtype(name):
    m = model(name)
    assert len(m.x0) == len(m.states) and len(m.u0) == len(m.inputs)
    assert m.t_span[1] > m.t_span[0] and m.description and m.source
    assert m.solution_kind in ("exact", "reference")
    p = m.params()
    assert all(isinstance(v, float) for v in p.values())
    for dtype in (jnp.float32, jnp.float64):
        f = jax.eval_shape(m.rhs, jnp.asarray(m.t_span[0], dtype), jnp.asarray(m.x0, dtype),
                           jnp.asarray(m.u0, dtype), p)
        assert f.shape == (len(m.states),) and f.dtype == dtype
    f = jax.jit(m.rhs)(m.t_span[0], jnp.asarray(m.x0), jnp.asarray(m.u0), p)
    assert np.all(np.isfinite(f))


@pytest.mark.parametrize("name", ["st", "detest_c5", "hires"])
def test_rhs_under_jit_vmap_and_jacfwd_agrees_with_finite_differences(name):
    m = model(name)
    x0, u, p = jnp.asarray(m.x0), jnp.asarray(m.u0), m.params()
    x = x0 * 1.01 + 0.01
    f = jax.jit(jax.vmap(lambda x: m.rhs(0.3, x, u, p)))
    h = 1e-6 * (1 + np.abs(np.asarray(x)))
    steps = np.diag(h)
    fx = np.asarray(f(jnp.concatenate([x[None], x + steps, x - steps])))
    np.testing.assert_allclose(fx[0], m.rhs(0.3, x, u, p), rtol=1e-13)
    n = len(m.states)
    fd = ((fx[1:n + 1] - fx[n + 1:]) / (2 * h[:, None])).T
    J = np.asarray(jax.jit(jax.jacfwd(m.rhs, argnums=1))(0.3, x, u, p))
    np.testing.assert_allclose(J, fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(J)))


def test_model_objects_are_shared_and_options_checked():
    assert model("dynamic5", tyre="pacejka") is model("dynamic5", "pacejka")
    assert model("dynamic5") is model("dynamic5", tyre="linear") is MODELS["dynamic5"]
    assert model("dynamic5", "fiala").rhs is not model("dynamic5").rhs
    with pytest.raises(KeyError, match="pacejka"):
        model("dynamic5", tyre="brush")
    with pytest.raises(KeyError, match="dynamic5, dynamic6"):
        model("st", tyre="pacejka")
    with pytest.raises(KeyError, match="vdp1000"):
        model("vdp")
    with pytest.raises(KeyError, match="takes no vehicle"):
        model("detest_a1").params("bmw320i")


# -- tyres ---------------------------------------------------------------------------------
def test_pacejka_bcd_equals_the_linear_cornering_stiffness():
    p = model("dynamic5", tyre="pacejka").params()
    for axle in "fr":
        bcd = p["B" + axle] * p["C" + axle] * p["D" + axle]
        assert abs(bcd / p["Ca" + axle] - 1) < 0.01


@pytest.mark.parametrize("tyre", ["pacejka", "fiala"])
def test_each_tyre_law_has_the_cornering_stiffness_as_its_slope_at_zero_slip(tyre):
    p = model("dynamic5", tyre=tyre).params()
    for axle in "fr":
        slope = jax.grad(lambda a, axle=axle: tyre_law(tyre)(a, p, axle))(0.0)
        assert abs(-slope / p["Ca" + axle] - 1) < 0.01


@pytest.mark.parametrize("tyre", ["pacejka", "fiala"])
def test_each_tyre_saturates_at_the_friction_limit(tyre):
    """The largest force is D (Pacejka) or mu Fz (Fiala), with mu Fz = D for this set; Fiala
    is continuous at its sliding angle atan(3 mu Fz / Ca) and flat beyond it."""
    p = model("dynamic5", tyre=tyre).params()
    grip = 1.0489 * p["m"] * G * p["Lr"] / (p["Lf"] + p["Lr"])
    F = jax.jit(jax.vmap(lambda a: tyre_law(tyre)(a, p, "f")))(jnp.linspace(-1.0, 1.0, 4001))
    np.testing.assert_allclose([-F.min(), F.max()], [grip, grip], rtol=1e-6)
    if tyre == "fiala":
        slide = np.arctan(3 * grip / p["Caf"])
        law = lambda a: float(tyre_law(tyre)(a, p, "f"))
        assert abs(law(slide * (1 - 1e-9)) - law(slide * (1 + 1e-9))) < 1e-3
        assert law(slide * 1.5) == law(0.9) == pytest.approx(-grip)


@pytest.mark.parametrize("tyre", ["pacejka", "fiala"])
@pytest.mark.parametrize("name", ["dynamic5", "dynamic6"])
def test_nonlinear_tyre_bicycle_linearises_to_the_linear_one(name, tyre):
    """In a straight line the state Jacobians agree within the 1% of the stiffnesses (to 1%
    of each row's largest entry: front and rear yaw moments nearly cancel in dr/dvy)."""
    lin, non = model(name), model(name, tyre=tyre)
    x0, u = lin.from_rest(15.0, 0.0)
    J = [np.asarray(jax.jacfwd(m.rhs, argnums=1)(0.0, x0, u, m.params(None, 15.0)))
         for m in (lin, non)]
    row_scale = np.max(np.abs(J[0]), axis=1, keepdims=True)
    assert np.all(np.abs(J[1] - J[0]) <= 0.01 * row_scale)


def test_nonlinear_tyre_sets_name_their_sources():
    v = vehicle("bmw320i")
    for tyre in TYRES[1:] + ("st",):
        assert "CommonRoad" in v[tyre]["source"] or "Fiala" in v[tyre]["source"]
    with pytest.raises(KeyError, match="bmw320i"):
        model("dynamic5", tyre="pacejka").params("ge2021")


# -- CommonRoad single-track model ----------------------------------------------------------
def test_st_derivative_equals_commonroads_published_value():
    """State, input and derivative of test_derivatives.py::test_st in commonroad-vehicle-models
    3.0.2 (vehicle 2); the acceleration is cut to a_max v_switch / v above v_switch."""
    m = model("st")
    x = jnp.array([2.0233348142065677, 0.0041907137716636, 0.0197545248559617,
                   15.7216236334290116, 0.0025857914776859, 0.0529001056654038,
                   0.0033012170610298])
    published = [15.7213512030862397, 0.0925527979719355, 0.15, 5.3536773276413925,
                 0.0529001056654038, 0.6435589397748606, 0.0313297971641291]
    f = m.rhs(0.0, x, jnp.array([0.15, 0.63 * G]), m.params())
    np.testing.assert_allclose(f, published, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("u,published", [
    ((0.15, 0.63 * G), [3.0731976046859715, 0.2869835398304389, 0.15, 6.1803, 0.1097747074946325,
                        0.3248268063223301, 0.0697547542798040]),
    ((0.0, -0.7 * G), [-3.4335, 0.0, 0.0, -6.867, 0.0, 0.0, 0.0]),
])
def test_st_from_standstill_matches_commonroads_published_trajectory(u, published):
    """1 s from rest through the switch at |v| = 0.1 m/s (test_zeroInitialVelocity.py of
    commonroad-vehicle-models, which checks to 1e-2 against odeint)."""
    m = model("st")
    x = solve(m.rhs, np.zeros(7), np.array(u), m.params(), np.array([0.0, 1.0]))[-1]
    np.testing.assert_allclose(x, published, atol=2e-3)


def test_st_switches_to_the_kinematic_model_below_a_tenth_of_a_metre_per_second():
    """Below 0.1 m/s the yaw rate follows the kinematic bicycle; derivatives stay finite
    (both branches are evaluated) at v = 0 and across the switch."""
    m = model("st")
    p = m.params()
    x = jnp.array([0.0, 0.0, 0.2, 0.05, 0.0, 0.0, 0.0])
    f = m.rhs(0.0, x, jnp.array([0.0, 1.0]), p)
    L = p["Lf"] + p["Lr"]
    beta = np.arctan(np.tan(0.2) * p["Lr"] / L)
    np.testing.assert_allclose(f[4], 0.05 * np.cos(beta) * np.tan(0.2) / L, rtol=1e-14)
    np.testing.assert_allclose(f[5], 1.0 * np.tan(0.2) / L, rtol=1e-14)
    speeds = jnp.array([0.0, 0.05, 0.1, 0.5])
    J = jax.jit(jax.vmap(lambda v: jax.jacfwd(m.rhs, argnums=1)(0.0, x.at[3].set(v),
                                                                jnp.array([0.1, 1.0]), p)))(speeds)
    assert np.all(np.isfinite(J))


def test_st_yaw_and_slip_modes_stiffen_like_inverse_speed():
    """Above the switch the dynamic model's yaw/slip eigenvalues scale as 1/v: 30 times
    faster at 0.5 m/s than at 15 m/s, the regime where explicit steps must shrink."""
    m = model("st")
    p = m.params()

    def fastest(v):
        x = jnp.array([0.0, 0.0, 0.0, v, 0.0, 0.0, 0.0])
        J = np.asarray(jax.jacfwd(m.rhs, argnums=1)(0.0, x, jnp.zeros(2), p))
        return np.max(np.abs(np.linalg.eigvals(J[5:, 5:])))
    np.testing.assert_allclose(fastest(0.5) / fastest(15.0), 30.0, rtol=1e-6)
    assert 400 < fastest(0.5) < 450          # [1/s]
