"""Every method's observed order of convergence (regression of log error on log h over the
asymptotic range) is within 0.2 of its declared order, against the exact solution."""
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.dynamics import model
from stepzoo.dynamics.exact import exact_reduced
from stepzoo.integrators import METHODS, integrate

pytestmark = pytest.mark.slow      # run first: see tests/conftest.py

T, K = 2.0, 20                       # horizon [s]; checkpoints where the error is taken
NS = K * np.array([2, 3, 4, 6, 8, 11, 16, 23, 32, 45, 64, 90, 128])


@pytest.fixture(scope="module")
def problem():
    m = model("dynamic5")
    p = m.params(None, 15.0)
    x0 = jnp.array([0.0, 0.0, 0.0, 0.5, -0.2])      # lateral modes excited
    u = jnp.array([0.3])
    truth = exact_reduced(np.linspace(0, T, K + 1), np.asarray(x0), 0.3, p)
    return m, p, x0, u, truth


def observed_order(hs, errors):
    """Slope of log error on log h over the six finest steps above the round-off floor."""
    e = np.asarray(errors)
    sel = np.where((e > 1e-11) & (e < 1e-1))[0][-6:]
    assert len(sel) >= 4, f"too few points in the asymptotic range: {e}"
    return np.polyfit(np.log(hs[sel]), np.log(e[sel]), 1)[0]


@pytest.mark.parametrize("name", list(METHODS))
def test_observed_order_matches_declared(problem, name):
    m, p, x0, u, truth = problem
    meth = METHODS[name]
    errors = []
    for n in NS:      # one compilation: the step count is a run-time value
        tr = integrate(meth, m.rhs, x0, u, p, T / n, jnp.asarray(n), max_steps=int(NS[-1]))
        errors.append(np.max(np.abs(np.asarray(tr.x)[: n + 1: n // K] - truth)))
    order = observed_order(T / NS, errors)
    assert abs(order - meth.order) <= 0.2, f"{name}: observed {order:.2f}, declared {meth.order}"
