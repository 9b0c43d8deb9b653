"""The non-stiff DETEST problems (Hull, Enright, Fellen and Sedgwick, 'Comparing numerical
methods for ordinary differential equations', SIAM J. Numer. Anal. 9(4), 1972, 603-637):
classes A (single equations), B (small systems), C (moderate systems), D (orbits) and
E (second-order equations), all on t in [0, 20].

Each problem is data: a right-hand side f(t, x, u, p) (pure JAX, no inputs, no parameters),
its published initial value, and a closed-form solution exact(ts) (NumPy, float64) where one
exists. Closed forms not stated in the paper are derived here and proved by the tests (each
satisfies its ODE and its initial value): A5 (a logarithmic spiral), B3 (a Riccati equation
solved by modified Bessel functions), B4 (polar coordinates), B5 (Jacobi elliptic
functions), D1-D5 (Kepler's equation), E1 (Bessel J_1/2), E4 and E5 (quadratures). B1, C5,
E2 and E3 have none; their truth is a tight reference solution."""
from typing import Any

import jax.numpy as jnp
import numpy as np

# SciPy (special functions, expm) is imported inside the closed forms that need it: every
# command that imports the model registry (`stepzoo plan` among them) would otherwise pay
# for scipy.linalg and scipy.special before its first step.

T_SPAN = (0.0, 20.0)
SOURCE = ("Hull, Enright, Fellen, Sedgwick, 'Comparing numerical methods for ordinary "
          "differential equations', SIAM J. Numer. Anal. 9(4), 1972")


def _vec(*parts):
    return jnp.stack(parts)


def _linear(A):
    """f = A x for a constant matrix A, and its exact solution expm(A t) x0."""
    A = np.asarray(A, float)

    def rhs(t, x, u, p):
        return jnp.asarray(A, x.dtype) @ x

    def exact(ts, x0):
        from scipy.linalg import expm
        return np.stack([expm(A * t) @ x0 for t in ts])
    return rhs, exact


def _chain(diag, sub, super_=0.0, n=10):
    A = np.diag(np.asarray(diag, float) * np.ones(n))
    A += np.diag(np.asarray(sub, float) * np.ones(n - 1), -1)
    A += np.diag(super_ * np.ones(n - 1), 1)
    return A


# -- class A ---------------------------------------------------------------------------------
def _a5_exact(ts):
    """y' = (y - t)/(y + t), y(0) = 4 is homogeneous: in polar coordinates (t, y) = r (cos phi,
    sin phi) its solution is the spiral r = 4 exp(pi/2 - phi), phi falling from pi/2 and above
    -pi/4 while t <= 4 exp(3 pi/4)/sqrt(2) ~ 29.8. Solved for phi by bisection (monotone)."""
    ts = np.asarray(ts, float)
    lo, hi = np.full_like(ts, -np.pi / 4), np.full_like(ts, np.pi / 2)
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        t_mid = 4 * np.exp(np.pi / 2 - mid) * np.cos(mid)
        lo, hi = np.where(t_mid > ts, mid, lo), np.where(t_mid > ts, hi, mid)
    phi = 0.5 * (lo + hi)
    return (4 * np.exp(np.pi / 2 - phi) * np.sin(phi))[:, None]


A = {
    "a1": dict(rhs=lambda t, x, u, p: -x, x0=(1.0,), exact=lambda ts: np.exp(-ts)[:, None],
               description="A1: negative exponential y' = -y"),
    "a2": dict(rhs=lambda t, x, u, p: -0.5 * x**3, x0=(1.0,),
               exact=lambda ts: (1 / np.sqrt(1 + ts))[:, None],
               description="A2: Riccati special case y' = -y^3/2"),
    "a3": dict(rhs=lambda t, x, u, p: x * jnp.cos(t), x0=(1.0,),
               exact=lambda ts: np.exp(np.sin(ts))[:, None],
               description="A3: oscillatory y' = y cos t"),
    "a4": dict(rhs=lambda t, x, u, p: 0.25 * x * (1 - x / 20), x0=(1.0,),
               exact=lambda ts: (20 / (1 + 19 * np.exp(-ts / 4)))[:, None],
               description="A4: logistic curve y' = y/4 (1 - y/20)"),
    "a5": dict(rhs=lambda t, x, u, p: (x - t) / (x + t), x0=(4.0,), exact=_a5_exact,
               description="A5: spiral curve y' = (y - t)/(y + t)"),
}


# -- class B ---------------------------------------------------------------------------------
def _b1(t, x, u, p):
    return _vec(2 * (x[0] - x[0] * x[1]), -(x[1] - x[0] * x[1]))


_B2, _b2_exact = _linear([[-1, 1, 0], [1, -2, 1], [0, 1, -1]])


def _b3(t, x, u, p):
    return _vec(-x[0], x[0] - x[1] ** 2, x[1] ** 2)


def _b3_exact(ts):
    """y1 = e^-t; y2 = w'/w with w'' = e^-t w, w = K1(2) I0(s) + I1(2) K0(s), s = 2 e^(-t/2)
    (so that y2(0) = 0); y3 = 1 - y1 - y2 (the sum is conserved)."""
    from scipy.special import i0, i1, k0, k1
    s = 2 * np.exp(-ts / 2)
    y2 = -(s / 2) * (k1(2) * i1(s) - i1(2) * k1(s)) / (k1(2) * i0(s) + i1(2) * k0(s))
    y1 = np.exp(-ts)
    return np.column_stack([y1, y2, 1 - y1 - y2])


def _b4(t, x, u, p):
    r = jnp.sqrt(x[0] ** 2 + x[1] ** 2)
    return _vec(-x[1] - x[0] * x[2] / r, x[0] - x[1] * x[2] / r, x[0] / r)


def _b4_exact(ts):
    """In polar coordinates: angle t, radius r' = -y3, y3' = cos t: r = 2 + cos t, y3 = sin t."""
    r = 2 + np.cos(ts)
    return np.column_stack([r * np.cos(ts), r * np.sin(ts), np.sin(ts)])


def _b5(t, x, u, p):
    return _vec(x[1] * x[2], -x[0] * x[2], -0.51 * x[0] * x[1])


def _b5_exact(ts):
    """Jacobi elliptic functions (sn, cn, dn)(t | m = 0.51)."""
    from scipy.special import ellipj
    sn, cn, dn, _ = ellipj(ts, 0.51)
    return np.column_stack([sn, cn, dn])


B = {
    "b1": dict(rhs=_b1, x0=(1.0, 3.0), exact=None,
               description="B1: growth of two conflicting populations (Lotka-Volterra)"),
    "b2": dict(rhs=_B2, x0=(2.0, 0.0, 1.0), exact=lambda ts: _b2_exact(ts, np.array([2.0, 0, 1])),
               description="B2: linear chemical reaction"),
    "b3": dict(rhs=_b3, x0=(1.0, 0.0, 0.0), exact=_b3_exact,
               description="B3: nonlinear chemical reaction"),
    "b4": dict(rhs=_b4, x0=(3.0, 0.0, 0.0), exact=_b4_exact,
               description="B4: integral surface of a torus"),
    "b5": dict(rhs=_b5, x0=(0.0, 1.0, 1.0), exact=_b5_exact,
               description="B5: Euler's equations of a rigid body without external forces"),
}


# -- class C ---------------------------------------------------------------------------------
_E1 = np.zeros(10)
_E1[0] = 1.0
_C1, _c1_exact = _linear(_chain(np.r_[-np.ones(9), 0.0], 1.0))
_C2, _c2_exact = _linear(_chain(-np.r_[np.arange(1.0, 10.0), 0.0], np.arange(1.0, 10.0)))
_C3, _c3_exact = _linear(_chain(-2.0, 1.0, 1.0))
_C4, _c4_exact = _linear(_chain(-2.0, 1.0, 1.0, n=51))

# C5: the five outer planets about the sun (heliocentric, astronomical units and days).
_K2 = 2.95912208286
_M0 = 1.00000597682
_M = np.array([0.000954786104043, 0.000285583733151, 0.0000437273164546, 0.0000517759138449,
               0.00000277777777778])
_C5_Q0 = [[3.42947415189, 3.35386959711, 1.35494901715],
          [6.64145542550, 5.97156957878, 2.18231499728],
          [11.2630437207, 14.6952576794, 6.27960525067],
          [-30.1552268759, 1.65699966404, 1.43785752721],
          [-21.1238353380, 28.4465098142, 15.3882659679]]
_C5_V0 = [[-0.557160570446, 0.505696783289, 0.230578543901],
          [-0.415570776342, 0.365682722812, 0.169143213293],
          [-0.325325669158, 0.189706021964, 0.0877265322780],
          [-0.0240476254170, -0.287659532608, -0.117219543175],
          [-0.176860753121, -0.216393453025, -0.0148647893090]]


def _c5(t, x, u, p):
    """x = [q (5 bodies x 3), v (5 x 3)]; the sun's pull plus the planets' mutual pulls,
    each planet's indirect term (the sun's acceleration towards it) included."""
    q, v = x[:15].reshape(5, 3), x[15:].reshape(5, 3)
    m = jnp.asarray(_M, x.dtype)
    r3 = jnp.sum(q**2, axis=1) ** 1.5
    diff = q[None, :, :] - q[:, None, :]                       # diff[j, k] = q_k - q_j
    d2 = jnp.sum(diff**2, axis=2) + jnp.eye(5, dtype=x.dtype)  # 1 on the diagonal: no 0/0
    d3 = d2**1.5
    off = 1.0 - jnp.eye(5, dtype=x.dtype)
    mutual = jnp.sum((off * m[None, :] / d3)[:, :, None] * diff, axis=1)
    indirect = jnp.sum((off * m[None, :])[:, :, None] * (q / r3[:, None])[None, :, :], axis=1)
    a = _K2 * (-(_M0 + m)[:, None] * q / r3[:, None] + mutual - indirect)
    return jnp.concatenate([v.reshape(-1), a.reshape(-1)])


C = {
    "c1": dict(rhs=_C1, x0=tuple(_E1), exact=lambda ts: _c1_exact(ts, _E1),
               description="C1: radioactive decay chain"),
    "c2": dict(rhs=_C2, x0=tuple(_E1), exact=lambda ts: _c2_exact(ts, _E1),
               description="C2: radioactive decay chain with rates 1..9"),
    "c3": dict(rhs=_C3, x0=tuple(_E1), exact=lambda ts: _c3_exact(ts, _E1),
               description="C3: parabolic PDE by lines, 10 equations"),
    "c4": dict(rhs=_C4, x0=tuple(np.r_[1.0, np.zeros(50)]),
               exact=lambda ts: _c4_exact(ts, np.r_[1.0, np.zeros(50)]),
               description="C4: parabolic PDE by lines, 51 equations"),
    "c5": dict(rhs=_c5, x0=tuple(np.r_[np.ravel(_C5_Q0), np.ravel(_C5_V0)]), exact=None,
               description="C5: five outer planets about the sun"),
}


# -- class D ---------------------------------------------------------------------------------
def _kepler(t, x, u, p):
    r3 = (x[0] ** 2 + x[1] ** 2) ** 1.5
    return _vec(x[2], x[3], -x[0] / r3, -x[1] / r3)


def kepler_exact(ts, e):
    """Orbit of eccentricity e from pericentre (1 - e, 0) with unit semi-major axis and mean
    motion: the eccentric anomaly E solves Kepler's equation E - e sin E = t (Newton)."""
    ts = np.asarray(ts, float)
    E = ts + 0.85 * e * np.sign(np.sin(ts))
    for _ in range(50):
        E = E - (E - e * np.sin(E) - ts) / (1 - e * np.cos(E))
    s, c, w = np.sin(E), np.cos(E), np.sqrt(1 - e**2)
    return np.column_stack([c - e, w * s, -s / (1 - e * c), w * c / (1 - e * c)])


D = {f"d{i}": dict(rhs=_kepler, x0=(1 - e, 0.0, 0.0, float(np.sqrt((1 + e) / (1 - e)))),
                   exact=(lambda ts, e=e: kepler_exact(ts, e)),
                   description=f"D{i}: Kepler orbit, eccentricity {e}")
     for i, e in enumerate((0.1, 0.3, 0.5, 0.7, 0.9), start=1)}


# -- class E ---------------------------------------------------------------------------------
def _e1(t, x, u, p):
    s = t + 1
    return _vec(x[1], -(x[1] / s + (1 - 0.25 / s**2) * x[0]))


def _e1_exact(ts):
    """J_1/2(t + 1) = sqrt(2 / (pi s)) sin s, s = t + 1, and its derivative."""
    s = ts + 1
    c = np.sqrt(2 / np.pi)
    return np.column_stack([c * np.sin(s) / np.sqrt(s),
                            c * (np.cos(s) / np.sqrt(s) - np.sin(s) / (2 * s**1.5))])


def _e4_exact(ts):
    """v' = 0.032 - 0.4 v^2, v(0) = 0: v = a tanh(k t), a = sqrt(0.08), k = sqrt(0.0128);
    y = 30 + (a / k) ln cosh(k t), a / k = 2.5."""
    k = np.sqrt(0.0128)
    return np.column_stack([30 + 2.5 * np.log(np.cosh(k * ts)), np.sqrt(0.08) * np.tanh(k * ts)])


def _e5_exact(ts):
    """v' = sqrt(1 + v^2) / (25 - t), v(0) = 0: asinh v = ln(25 / (25 - t))."""
    q = 25 / (25 - ts)
    return np.column_stack([0.5 * (25 * np.log(q) + ((25 - ts) ** 2 - 625) / 50),
                            0.5 * (q - 1 / q)])


E = {
    "e1": dict(rhs=_e1, x0=(0.6713967071418030, 0.09540051444747446), exact=_e1_exact,
               description="E1: Bessel's equation of order 1/2, origin shifted by -1"),
    "e2": dict(rhs=lambda t, x, u, p: _vec(x[1], (1 - x[0] ** 2) * x[1] - x[0]),
               x0=(2.0, 0.0), exact=None, description="E2: Van der Pol, mu = 1"),
    "e3": dict(rhs=lambda t, x, u, p: _vec(x[1], x[0] ** 3 / 6 - x[0] + 2 * jnp.sin(2.78535 * t)),
               x0=(0.0, 0.0), exact=None, description="E3: forced Duffing equation"),
    "e4": dict(rhs=lambda t, x, u, p: _vec(x[1], 0.032 - 0.4 * x[1] ** 2), x0=(30.0, 0.0),
               exact=_e4_exact, description="E4: falling body with quadratic drag"),
    "e5": dict(rhs=lambda t, x, u, p: _vec(x[1], jnp.sqrt(1 + x[1] ** 2) / (25 - t)),
               x0=(0.0, 0.0), exact=_e5_exact, description="E5: linear pursuit"),
}

PROBLEMS: dict[str, dict[str, Any]] = {f"detest_{k}": v for group in (A, B, C, D, E)
                                       for k, v in group.items()}
