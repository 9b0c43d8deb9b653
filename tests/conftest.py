import numpy as np
import pytest

import dynamics  # noqa: F401  (float64 on the CPU)


@pytest.fixture
def paper_point():
    """The paper's test: vx = 15 m/s, delta = pi/4, on the default vehicle, from rest."""
    m = dynamics.model("dynamic5")
    p = m.params(None, 15.0)
    x0, u = m.from_rest(15.0, np.pi / 4)
    return m, p, x0, u
