"""Stiff test problems as data, like `detest`: Robertson's chemical kinetics, Van der Pol with
mu = 1000, HIRES, and a stiff linear system with a closed-form solution. Where the Test Set
for IVP Solvers (Mazzia and Magherini, release 2.4, 2008) publishes the solution at the end
of the interval, it is in `PUBLISHED_END`."""
from typing import Any

import jax.numpy as jnp
import numpy as np


def _robertson(t, x, u, p):
    """Rate constants k1, k2, k3 in p (0.04, 3e7, 1e4 as published: y1 -> y2 at k1,
    2 y2 -> y2 + y3 at k2, y2 + y3 -> y1 + y3 at k3)."""
    y1, y2, y3 = x[0], x[1], x[2]
    slow, fast, square = p["k1"] * y1, p["k3"] * y2 * y3, p["k2"] * y2**2
    return jnp.stack([-slow + fast, slow - fast - square, square])


def _vdp(t, x, u, p):
    """x'' - mu (1 - x^2) x' + x = 0 as a first-order system; mu in p."""
    return jnp.stack([x[1], p["mu"] * (1 - x[0] ** 2) * x[1] - x[0]])


def _hires(t, x, u, p):
    y1, y2, y3, y4, y5, y6, y7, y8 = (x[i] for i in range(8))
    return jnp.stack([-1.71 * y1 + 0.43 * y2 + 8.32 * y3 + 0.0007,
                      1.71 * y1 - 8.75 * y2,
                      -10.03 * y3 + 0.43 * y4 + 0.035 * y5,
                      8.32 * y2 + 1.71 * y3 - 1.12 * y4,
                      -1.745 * y5 + 0.43 * y6 + 0.43 * y7,
                      -280.0 * y6 * y8 + 0.69 * y4 + 1.71 * y5 - 0.43 * y6 + 0.69 * y7,
                      280.0 * y6 * y8 - 1.81 * y7,
                      -280.0 * y6 * y8 + 1.81 * y7])


def _stiff_linear(t, x, u, p):
    """x' = A x + g(t), A = [[-2, 1], [998, -999]] (eigenvalues -1 and -1000)."""
    return jnp.stack([-2 * x[0] + x[1] + 2 * jnp.sin(t),
                      998 * x[0] - 999 * x[1] + 999 * (jnp.cos(t) - jnp.sin(t))])


def _stiff_linear_exact(ts):
    return np.column_stack([2 * np.exp(-ts) + np.sin(ts), 2 * np.exp(-ts) + np.cos(ts)])


TEST_SET = "Test Set for IVP Solvers, release 2.4 (Mazzia, Magherini, Univ. Bari, 2008)"

PROBLEMS: dict[str, dict[str, Any]] = {
    "robertson": dict(
        rhs=_robertson, x0=(1.0, 0.0, 0.0), t_span=(0.0, 40.0), exact=None,
        params={"k1": 0.04, "k2": 3e7, "k3": 1e4},
        description="Robertson's autocatalytic reaction (3 species), on [0, 40]",
        source="Robertson, 'The solution of a set of reaction rate equations', 1966; "
               "Hairer and Wanner, Solving ODEs II, 2nd ed., 1996, sec. IV.1 (interval [0, 40])"),
    "vdp1000": dict(
        rhs=_vdp, x0=(2.0, 0.0), t_span=(0.0, 2000.0), exact=None, params={"mu": 1000.0},
        description="Van der Pol oscillator x'' - mu (1 - x^2) x' + x = 0, mu = 1000",
        source=f"{TEST_SET}, problem VDPOL (unscaled form, t in [0, 2000])"),
    "hires": dict(
        rhs=_hires, x0=(1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0057), t_span=(0.0, 321.8122),
        exact=None,
        description="HIRES: high irradiance responses of photomorphogenesis (8 species)",
        source=f"Schaefer 1975; Hairer and Wanner, Solving ODEs II, 1996; {TEST_SET}, "
               "problem HIRES"),
    "stiff_linear": dict(
        rhs=_stiff_linear, x0=(2.0, 3.0), t_span=(0.0, 10.0), exact=_stiff_linear_exact,
        description="stiff linear system, eigenvalues -1 and -1000, exact 2 e^-t + (sin t, cos t)",
        source="Lambert, Numerical Methods for Ordinary Differential Systems, Wiley, 1991, "
               "ch. 6 (the introductory example of stiffness)"),
}

# Solutions at the end of the interval as the Test Set publishes them (RADAU5 at tolerance
# 1.1e-18 in extended precision), for the tests.
PUBLISHED_END = {
    "vdp1000": (1.706167732170469, -0.8928097010248125e-3),
    "hires": (0.7371312573325668e-3, 0.1442485726316185e-3, 0.5888729740967575e-4,
              0.1175651343283149e-2, 0.2386356198831331e-2, 0.6238968252742796e-2,
              0.2849998395185769e-2, 0.2850001604814231e-2),
}
