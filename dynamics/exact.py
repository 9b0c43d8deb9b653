"""Exact solution of the 5-state model at constant vx and delta: the lateral part (vy, r) and
psi by the matrix exponential of the augmented linear system, X and Y by adaptive quadrature.
The truth that the reference and every method's convergence order are checked against."""
import numpy as np
from scipy.integrate import quad_vec
from scipy.linalg import expm

from stepzoo.dynamics.linear import lateral_matrix


def _augmented(vx, delta, p):
    """M with d/dt [vy, r, psi, 1] = M [vy, r, psi, 1]."""
    A, b = (np.asarray(v) for v in lateral_matrix(vx, delta, p))
    M = np.zeros((4, 4))
    M[:2, :2], M[:2, 3], M[2, 1] = A, b, 1.0
    return M


def exact_reduced(ts, x0, delta, p):
    """States [X, Y, psi, vy, r] at the times ts [s] (ts[0] is the start) from x0."""
    ts = np.asarray(ts, dtype=float)
    vx = float(p["vx"])
    M = _augmented(vx, delta, p)
    z0 = np.array([x0[3], x0[4], x0[2], 1.0])

    def lateral(t):
        return expm(M * (t - ts[0])) @ z0

    def velocity(t):
        vy, _, psi, _ = lateral(t)
        return np.array([vx * np.cos(psi) - vy * np.sin(psi), vx * np.sin(psi) + vy * np.cos(psi)])

    xy = np.empty((len(ts), 2))
    xy[0] = x0[0], x0[1]
    for i in range(1, len(ts)):
        step, _ = quad_vec(velocity, ts[i - 1], ts[i], epsabs=1e-13, epsrel=1e-13)
        xy[i] = xy[i - 1] + step
    lat = np.array([lateral(t) for t in ts])
    return np.column_stack([xy, lat[:, 2], lat[:, 0], lat[:, 1]])
