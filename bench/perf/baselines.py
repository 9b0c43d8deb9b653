"""The baselines of the driver, each integrating `workload.problem` with RK4 and storing the
whole trajectory (B, N+1, 5) like the driver does: a NumPy loop vectorised over the batch,
Numba (serial, and `prange` with `fastmath`), diffrax with a constant step, and SciPy's
adaptive DOP853 for one trajectory. The right-hand side is written out per baseline, since
only JAX can run the model's own function."""
import numpy as np


def numpy_rhs(x, delta, p):
    """Reduced bicycle (NOTES.md) on (5, B) rows; delta (B,) [rad]."""
    _, _, psi, vy, r = x
    vx = p["vx"]
    Fyf = -p["Caf"] * ((vy + p["Lf"] * r) / vx - delta)
    Fyr = -p["Car"] * (vy - p["Lr"] * r) / vx
    c, s = np.cos(psi), np.sin(psi)
    front = Fyf * np.cos(delta) - p["Fxf"] * np.sin(delta)
    return np.stack([vx * c - vy * s, vx * s + vy * c, r,
                     (front + Fyr) / p["m"] - vx * r,
                     (p["Lf"] * front - p["Lr"] * Fyr) / p["Iz"]])


def numpy_rk4(x0, u, p, h, n):
    """(B, n+1, 5): the batch as the last axis of each NumPy operation."""
    y, delta = x0.T.copy(), u[:, 0]
    out = np.empty((n + 1,) + y.shape)
    out[0] = y
    for k in range(n):
        k1 = numpy_rhs(y, delta, p)
        k2 = numpy_rhs(y + 0.5 * h * k1, delta, p)
        k3 = numpy_rhs(y + 0.5 * h * k2, delta, p)
        k4 = numpy_rhs(y + h * k3, delta, p)
        y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[k + 1] = y
    return out.transpose(2, 0, 1)


def numba_rk4(parallel: bool):
    """A compiled f(x0, u, p, h, n) -> (B, n+1, 5): one trajectory per loop iteration,
    `prange` with `fastmath` when parallel, plain serial loops otherwise."""
    import numba
    from math import cos, sin

    @numba.njit(fastmath=parallel, parallel=parallel, cache=False)
    def run(x0, delta, vx, m, Iz, Lf, Lr, Caf, Car, Fxf, h, n, out):
        for b in numba.prange(x0.shape[0]):
            y = x0[b].copy()
            cd, sd = cos(delta[b]), sin(delta[b])   # the steer is constant: once per run
            ks = np.empty((4, 5))
            out[b, 0] = y
            for step in range(n):
                for st in range(4):
                    a = 0.0 if st == 0 else (0.5 * h if st < 3 else h)
                    psi = y[2] + a * ks[st - 1, 2] if st else y[2]
                    vy = y[3] + a * ks[st - 1, 3] if st else y[3]
                    r = y[4] + a * ks[st - 1, 4] if st else y[4]
                    Fyf = -Caf[b] * ((vy + Lf[b] * r) / vx[b] - delta[b])
                    Fyr = -Car[b] * (vy - Lr[b] * r) / vx[b]
                    front = Fyf * cd - Fxf[b] * sd
                    c, s = cos(psi), sin(psi)
                    ks[st, 0] = vx[b] * c - vy * s
                    ks[st, 1] = vx[b] * s + vy * c
                    ks[st, 2] = r
                    ks[st, 3] = (front + Fyr) / m[b] - vx[b] * r
                    ks[st, 4] = (Lf[b] * front - Lr[b] * Fyr) / Iz[b]
                for i in range(5):
                    y[i] += h / 6 * (ks[0, i] + 2 * ks[1, i] + 2 * ks[2, i] + ks[3, i])
                out[b, step + 1] = y
        return out

    def call(x0, u, p, h, n):
        out = np.empty((x0.shape[0], n + 1, 5))
        return run(x0, u[:, 0], *(p[k] for k in ("vx", "m", "Iz", "Lf", "Lr", "Caf", "Car",
                                                 "Fxf")), h, n, out)
    return call


def diffrax_rk4(n, h):
    """A jitted f(x0, u, p) -> (B, n+1, 5): classical RK4 as a diffrax tableau (diffrax
    ships none) with a constant step, vmapped, saving every step like the driver."""
    from typing import ClassVar

    import diffrax
    import jax

    from stepzoo.bench.perf.workload import MODEL

    class RK4(diffrax.AbstractERK):
        tableau: ClassVar[diffrax.ButcherTableau] = diffrax.ButcherTableau(
            c=np.array([0.5, 0.5, 1.0]), b_sol=np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6]),
            b_error=np.zeros(4),
            a_lower=(np.array([0.5]), np.array([0.0, 0.5]), np.array([0.0, 0.0, 1.0])))
        interpolation_cls: ClassVar = diffrax.ThirdOrderHermitePolynomialInterpolation.from_k

        def order(self, terms):
            return 4

    term = diffrax.ODETerm(lambda t, y, args: MODEL.rhs(t, y, *args))

    def one(y0, uu, pp):
        sol = diffrax.diffeqsolve(term, RK4(), 0.0, n * h, h, y0, args=(uu, pp),
                                  saveat=diffrax.SaveAt(t0=True, steps=True),
                                  stepsize_controller=diffrax.ConstantStepSize(),
                                  max_steps=n)
        return sol.ys
    return jax.jit(jax.vmap(one))


def scipy_dop853(x0, u, p, h, n, rtol=1e-10, atol=1e-12):
    """(n+1, 5): one trajectory with SciPy's adaptive DOP853, dense output at the grid."""
    from scipy.integrate import solve_ivp
    pp = {k: float(v) for k, v in p.items()}
    delta = np.array([float(u[0])])
    fun = lambda t, y: numpy_rhs(y[:, None], delta, {k: np.array([v]) for k, v in pp.items()})[:, 0]
    sol = solve_ivp(fun, (0.0, n * h), x0, method="DOP853", t_eval=np.arange(n + 1) * h,
                    rtol=rtol, atol=atol)
    return sol.y.T
