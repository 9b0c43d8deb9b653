"""The driver's baselines: each integrates `workload.problem` with RK4 at a constant step in
float64, in one of two regimes doing the same work as the driver does in it: "stored" keeps
every state, (B, N+1, 5); "final" keeps only the last one, (B, 5), as a sweep that
accumulates its error on the fly needs. A NumPy loop vectorised over the batch (SciPy has
no fixed-step RK4), Numba (serial, and `prange` with `fastmath`), a plain JAX `lax.scan`,
and diffrax with a constant step (its Tsit5 and an RK4 tableau; Kvaerno5, implicit, for the
implicit methods). The right-hand side is written out for NumPy and Numba, since only JAX
runs the model's own function. Every factory returns f(x0, u, p) -> states."""
from typing import ClassVar

import numpy as np

from stepzoo.bench.perf.workloads.bicycle import MODEL

REGIMES = ("stored", "final")
# The contenders that integrate with RK4 (stepzoo's rk4 first in `contenders`): their final
# states equal rk4's to round-off. diffrax's Tsit5 is another method.
SAME_AS_RK4 = ("rk4_fast_trig", "jax_scan", "diffrax_rk4", "numpy_loop", "numba_serial",
               "numba_fastmath")


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


def numpy_rk4(h, n, regime):
    """The batch as the last axis of each NumPy operation."""
    def run(x0, u, p):
        y, delta = x0.T.copy(), u[:, 0]
        out = np.empty((n + 1,) + y.shape) if regime == "stored" else None
        if out is not None:
            out[0] = y
        for k in range(n):
            k1 = numpy_rhs(y, delta, p)
            k2 = numpy_rhs(y + 0.5 * h * k1, delta, p)
            k3 = numpy_rhs(y + 0.5 * h * k2, delta, p)
            k4 = numpy_rhs(y + h * k3, delta, p)
            y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            if out is not None:
                out[k + 1] = y
        return out.transpose(2, 0, 1) if out is not None else y.T
    return run


NUMBA_PARAMS = ("vx", "m", "Iz", "Lf", "Lr", "Caf", "Car", "Fxf")


def numba_rk4(h, n, regime, parallel: bool):
    """One trajectory per loop iteration, `prange` with `fastmath` when parallel, plain
    serial loops otherwise; compiled on the first call."""
    import numba
    from math import cos, sin
    store = regime == "stored"      # a compile-time constant of the kernel

    @numba.njit(fastmath=parallel, parallel=parallel, cache=False)
    def kernel(x0, delta, vx, m, Iz, Lf, Lr, Caf, Car, Fxf, h, n, out):
        for b in numba.prange(x0.shape[0]):
            y = x0[b].copy()
            cd, sd = cos(delta[b]), sin(delta[b])   # the steer is constant: once per run
            ks = np.empty((4, 5))
            if store:
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
                if store:
                    out[b, step + 1] = y
            if not store:
                out[b] = y
        return out

    def run(x0, u, p):
        out = np.empty((x0.shape[0], n + 1, 5) if store else x0.shape)
        return kernel(x0, u[:, 0], *(p[k] for k in NUMBA_PARAMS), h, n, out)
    return run


def numba_layer() -> dict:
    """Numba's threading layer (as chosen by its first parallel run) and thread count."""
    import numba
    return {"numba_threading_layer": numba.threading_layer(),
            "numba_threads": numba.get_num_threads()}


def jax_rk4(h, n, regime):
    """A plain `lax.scan` of RK4 over the model's own right-hand side, vmapped: what a JAX
    user writes without the driver."""
    import jax
    import jax.numpy as jnp
    from jax import lax

    def one(y0, uu, pp):
        f = lambda y: MODEL.rhs(0.0, y, uu, pp)

        def step(y, _):
            k1 = f(y)
            k2 = f(y + 0.5 * h * k1)
            k3 = f(y + 0.5 * h * k2)
            k4 = f(y + h * k3)
            y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            return y, (y if regime == "stored" else None)

        y, ys = lax.scan(step, y0, None, length=n)
        return jnp.concatenate([y0[None], ys]) if regime == "stored" else y
    return jax.jit(jax.vmap(one))


def _diffrax_rk4():
    """Classical RK4 as a diffrax tableau (diffrax ships none)."""
    import diffrax

    class RK4(diffrax.AbstractERK):
        tableau: ClassVar[diffrax.ButcherTableau] = diffrax.ButcherTableau(
            c=np.array([0.5, 0.5, 1.0]), b_sol=np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6]),
            b_error=np.zeros(4),
            a_lower=(np.array([0.5]), np.array([0.0, 0.5]), np.array([0.0, 0.0, 1.0])))
        interpolation_cls: ClassVar = diffrax.ThirdOrderHermitePolynomialInterpolation.from_k

        def order(self, terms):
            return 4
    return RK4()


def diffrax_solver(name: str, newton_tol: float = 1e-10):
    """"rk4", "tsit5" or "kvaerno5": its stages solved by Newton's method (optimistix) to
    `newton_tol`, relative and absolute, as stepzoo's Newton defaults. diffrax's default
    for it, a chord iteration, diverged on most of the benchmark's trajectories at that
    tolerance."""
    import diffrax
    if name == "rk4":
        return _diffrax_rk4()
    if name == "tsit5":
        return diffrax.Tsit5()
    import optimistix
    return diffrax.Kvaerno5(root_finder=optimistix.Newton(rtol=newton_tol, atol=newton_tol))


def diffrax_run(h, n, regime, solver: str, rhs=None):
    """diffeqsolve with a constant step h, vmapped; saving every step, or the end only; of
    `rhs` (default the workload's model)."""
    import diffrax
    import jax

    f = MODEL.rhs if rhs is None else rhs
    term = diffrax.ODETerm(lambda t, y, args: f(t, y, *args))
    saveat = (diffrax.SaveAt(t0=True, steps=True) if regime == "stored"
              else diffrax.SaveAt(t1=True))
    method = diffrax_solver(solver)

    def one(y0, uu, pp):
        sol = diffrax.diffeqsolve(term, method, 0.0, n * h, h, y0, args=(uu, pp),
                                  saveat=saveat, stepsize_controller=diffrax.ConstantStepSize(),
                                  max_steps=n, throw=False)
        return sol.ys if regime == "stored" else sol.ys[0]
    return jax.jit(jax.vmap(one))


def stepzoo_run(h, n, regime, name="rk4", rhs=None):
    """stepzoo's driver (`integrate_batch`) under jit: every state, or the last row only."""
    import jax

    from stepzoo.integrators import integrate_batch
    f = MODEL.rhs if rhs is None else rhs

    def run(x0, u, p):
        xs = integrate_batch(name, f, x0, u, p, h, n).x
        return xs if regime == "stored" else xs[:, -1]
    return jax.jit(run)


def contenders(h, n, regime) -> dict:
    """name -> f(x0, u, p) of the explicit RK4 comparison in `regime`; Numba's only when it
    is installed. stepzoo's with the generic right-hand side and with fast_trig."""
    from stepzoo.integrators.fast_trig import fast_trig
    out = {"rk4": stepzoo_run(h, n, regime),
           "rk4_fast_trig": stepzoo_run(h, n, regime, rhs=fast_trig(MODEL.rhs)),
           "jax_scan": jax_rk4(h, n, regime),
           "diffrax_rk4": diffrax_run(h, n, regime, "rk4"),
           "diffrax_tsit5": diffrax_run(h, n, regime, "tsit5"),
           "numpy_loop": numpy_rk4(h, n, regime)}
    try:
        import numba  # noqa: F401
    except ImportError:
        return out
    out["numba_serial"] = numba_rk4(h, n, regime, parallel=False)
    out["numba_fastmath"] = numba_rk4(h, n, regime, parallel=True)
    return out

