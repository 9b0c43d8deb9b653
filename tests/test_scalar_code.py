"""The replay's right-hand sides as plain Python float code (search/plans/scalar_code.py)
compute what the jitted JAX functions compute, to rounding, and DOP853 driven by them ends
where DOP853 driven by the jitted function ends, within its tolerance; a function the code
cannot express is refused, not approximated."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stepzoo import dynamics
from stepzoo.dynamics.models import steered
from stepzoo.search.plans import replay
from stepzoo.search.plans.scalar_code import scalar_function

VEHICLE = {"m": 1500.0, "Iz": 2500.0, "Lf": 1.2, "Lr": 1.4, "Caf": 8e4, "Car": 9e4}
# (model, steered, states, inputs): every right-hand side the replay drives.
CASES = [("dynamic5", False, 5, 1), ("dynamic5", True, 6, 1), ("kinematic", False, 4, 2),
         ("kinematic", True, 5, 2)]


def _jitted(model, is_steered, p):
    rhs = dynamics.model(model).rhs
    fun = jax.jit(steered(rhs) if is_steered else rhs)

    def call(t, x, u):
        with jax.enable_x64(True):
            return np.asarray(fun(t, jnp.asarray(x, float), jnp.asarray(u, float),
                                  {k: jnp.asarray(v, float) for k, v in p.items()}))
    return call


def _params(model):
    return dict(replay._params(model, VEHICLE), **({"vx": 7.5} if model == "dynamic5" else {}))


@pytest.mark.parametrize("model, is_steered, n, k", CASES)
def test_the_float_code_computes_the_jitted_right_hand_side(model, is_steered, n, k):
    p = _params(model)
    keys = tuple(sorted(p))
    code = scalar_function(dynamics.model(model).rhs if not is_steered
                           else steered(dynamics.model(model).rhs), n, k, keys)
    jitted = _jitted(model, is_steered, p)
    rng = np.random.default_rng(3)
    for _ in range(20):
        x, u = rng.uniform(-3, 3, n), rng.uniform(-0.5, 0.5, k)
        want = jitted(0.0, x, u)
        got = code(0.0, list(x), list(u), [p[key] for key in keys])
        assert got.dtype == np.float64 and got.shape == want.shape
        np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("model, is_steered, n, k", CASES)
def test_dop853_on_the_float_code_ends_where_dop853_on_the_jitted_function_ends(
        model, is_steered, n, k):
    p = _params(model)
    x0 = np.r_[0.0, 0.0, 0.3, (0.2, 0.1) if model == "dynamic5" else (4.0,),
               (0.1,) if is_steered else ()]
    u = [0.25, 400.0][:k]   # [rad, N]
    end, _, fine = replay._solve(model, x0, u, p, 2.0, np.zeros(0), 8.0, is_steered)
    jitted = _jitted(model, is_steered, p)
    sol = solve_ivp(lambda t, x: jitted(t, x, u), (0.0, 2.0), x0, method=replay.METHOD,
                    rtol=replay.RTOL, atol=replay.ATOL)
    assert np.all(np.abs(end - x0) > 1e-3)      # it moved
    np.testing.assert_allclose(end, sol.y[:, -1], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(fine[-1], end, rtol=1e-12, atol=1e-12)


def test_what_the_float_code_cannot_express_is_refused():
    with pytest.raises(ValueError, match="more than one axis"):
        scalar_function(lambda t, x, u, p: jnp.outer(x, x).sum(axis=0), 3, 1, ())
    with pytest.raises(ValueError, match="no float code for cumsum"):
        scalar_function(lambda t, x, u, p: jnp.cumsum(x), 3, 1, ())
