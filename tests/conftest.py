import jax
import numpy as np
import pytest

from stepzoo import dynamics

# The tests are a caller of the library like any other: they ask for float64 themselves
# (the library changes no JAX setting; the `stepzoo` command turns float64 on at start-up).
jax.config.update("jax_enable_x64", True)


@pytest.fixture
def paper_point():
    """The paper's test: vx = 15 m/s, delta = pi/4, on the default vehicle, from rest."""
    m = dynamics.model("dynamic5")
    p = m.params(None, 15.0)
    x0, u = m.from_rest(15.0, np.pi / 4)
    return m, p, x0, u
