import os

from stepzoo.bench.cli import _with_xla_option

# The tests compute as the `stepzoo` command does, so that tables made in-process equal those
# of a command run in a subprocess bit for bit: the same XLA option (it changes how loops are
# compiled, hence the rounding), set before JAX starts, and float64. The library itself
# changes no JAX setting; the tests ask for these as any caller would.
os.environ["XLA_FLAGS"] = _with_xla_option(os.environ.get("XLA_FLAGS", ""))

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from stepzoo import dynamics  # noqa: E402

jax.config.update("jax_enable_x64", True)


@pytest.fixture
def paper_point():
    """The paper's test: vx = 15 m/s, delta = pi/4, on the default vehicle, from rest."""
    m = dynamics.model("dynamic5")
    p = m.params(None, 15.0)
    x0, u = m.from_rest(15.0, np.pi / 4)
    return m, p, x0, u
