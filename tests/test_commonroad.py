"""The CommonRoad single-track drift (9 states) and multi-body (29 states) models as ported
to JAX give what the published Python functions (package `vehiclemodels`, plain floats and
`math`) give, at seeded states across both speed branches and the input constraints."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.dynamics import commonroad

vm = pytest.importorskip("vehiclemodels")
from vehiclemodels.parameters_vehicle2 import parameters_vehicle2  # noqa: E402
from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb  # noqa: E402
from vehiclemodels.vehicle_dynamics_std import vehicle_dynamics_std  # noqa: E402
from vehiclemodels.init_mb import init_mb  # noqa: E402
from vehiclemodels.init_std import init_std  # noqa: E402

# (speed [m/s], steering velocity [rad/s], acceleration [m/s^2]): driving, braking hard,
# past the steering rate limit, and slow enough for the kinematic branches and blends.
POINTS = [(15.0, 0.1, 1.0), (25.0, -0.3, -8.0), (8.0, 0.6, 3.0), (0.15, 0.05, 0.5),
          (0.05, 0.0, -1.0)]


def _states(v, rng, init, n_states):
    """A published initial state at speed v, then every state moved by a seeded amount so
    that slips, rolls and deflections are not zero. The yaw rate scales with the speed: at
    walking pace a faster one turns a wheel backwards, where the published MB model divides
    by its zero speed."""
    core = [0.0, 0.0, rng.uniform(-0.1, 0.1), v, 0.1, rng.uniform(-0.3, 0.3) * min(1, v / 10),
            rng.uniform(-0.05, 0.05)]
    x = np.array(init(core, parameters_vehicle2()), float)
    assert x.shape == (n_states,)
    return x * (1 + rng.uniform(-0.02, 0.02, n_states)) + rng.uniform(-1e-3, 1e-3, n_states)


@pytest.mark.parametrize("name", ["std", "mb"])
def test_the_port_gives_the_published_right_hand_side(name):
    rhs, published, init, n = {"std": (commonroad.std_rhs, vehicle_dynamics_std, init_std, 9),
                               "mb": (commonroad.mb_rhs, vehicle_dynamics_mb, init_mb, 29)}[name]
    f = jax.jit(lambda x, u: rhs(0.0, x, u, commonroad.BMW_320I))
    rng = np.random.default_rng(7)
    for v, steer_rate, accel in POINTS:
        x = _states(v, rng, init, n)
        u = [steer_rate, accel]
        want = np.array(published(list(x), list(u), parameters_vehicle2()), float)
        got = np.asarray(f(jnp.asarray(x), jnp.asarray(u)))
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max(),
                                   err_msg=f"{name} at v={v}")


@pytest.mark.parametrize("name", ["std", "mb"])
def test_the_initial_states_are_the_published_ones(name):
    state, init = {"std": (commonroad.std_state, init_std),
                   "mb": (commonroad.mb_state, init_mb)}[name]
    core = [1.0, -2.0, 0.05, 12.0, 0.3, 0.2, 0.04]
    np.testing.assert_allclose(np.asarray(state(*core)),
                               np.array(init(list(core), parameters_vehicle2()), float),
                               rtol=1e-14, atol=1e-15)
