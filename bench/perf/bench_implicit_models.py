"""Implicit steps on vehicle models of 9 and 29 states (dynamics.commonroad: the single-track
drift model and the multi-body model, BMW 320i), stiff through their wheel speeds: stepzoo's
implicit methods against diffrax's Kvaerno5 at the same constant step H_S and step count,
final state only, in interleaved rounds (bench_baselines._rounds); and SciPy's Radau on one
trajectory with its step capped at H_S (its own error control, the model's f and Jacobian
jitted by JAX, as a user would pass them) as a per-step baseline."""
from functools import partial
from time import perf_counter

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stepzoo.bench.perf.workloads import baselines
from stepzoo.bench.perf.bench_baselines import _compiled, _rounds
from stepzoo.bench.perf.workloads.implicit import IMPLICIT
from stepzoo.bench.perf.workloads.bicycle import H_S
from stepzoo.dynamics import commonroad

BATCH = 1_000
STEPS = 20
ROUNDS = 3
MODELS = {9: (commonroad.std_rhs, commonroad.std_state),
          29: (commonroad.mb_rhs, commonroad.mb_state)}


def _rhs(d):
    """f(t, x, u, p) of the d-state model with the BMW 320i bound (p unused, so that every
    contender takes the same batched arguments)."""
    return partial(_bound_rhs, MODELS[d][0])


def _bound_rhs(rhs, t, x, u, p):
    return rhs(t, x, u, commonroad.BMW_320I)


def vehicle_problem(d: int, batch: int, seed: int = 0):
    """(x0 (B, d), u (B, 2), p (B,) unused) as NumPy: speeds 10-25 m/s, seeded steering
    angles, yaw rates and slip angles, wheels rolling; steering still, mild acceleration."""
    rng = np.random.default_rng(seed)
    v = rng.uniform(10.0, 25.0, batch)
    state = jax.vmap(MODELS[d][1])(jnp.zeros(batch), jnp.zeros(batch),
                                   rng.uniform(-0.05, 0.05, batch), v, jnp.zeros(batch),
                                   rng.uniform(-0.2, 0.2, batch),
                                   rng.uniform(-0.02, 0.02, batch))
    u = np.column_stack([np.zeros(batch), rng.uniform(-1.0, 1.0, batch)])
    return np.asarray(state), u, np.zeros(batch)


def scipy_radau_steps_per_s(d: int, horizon_s: float = 0.2) -> float:
    """Steps per second of SciPy's Radau on the first trajectory of the problem, its step
    capped at H_S (rtol 1e-6, atol 1e-8), the best of 3 solves."""
    x0, u, p = vehicle_problem(d, 1)
    f = jax.jit(lambda t, x: _rhs(d)(t, x, u[0], p[0]))
    jac = jax.jit(jax.jacfwd(lambda t, x: _rhs(d)(t, x, u[0], p[0]), argnums=1))
    fun = lambda t, x: np.asarray(f(t, x))
    jfun = lambda t, x: np.asarray(jac(t, x))
    fun(0.0, x0[0]), jfun(0.0, x0[0])
    best = np.inf
    for _ in range(3):
        t0 = perf_counter()
        sol = solve_ivp(fun, (0.0, horizon_s), x0[0], method="Radau", jac=jfun, rtol=1e-6,
                        atol=1e-8, first_step=H_S, max_step=H_S)
        took = perf_counter() - t0
        assert sol.success, sol.message
        best = min(best, took / (len(sol.t) - 1))
    return 1.0 / best


def model_figures(d: int, names=IMPLICIT, batch=BATCH, steps=STEPS) -> dict:
    """{name}_d{d}_final_b1e3_steps_per_s [trajectory-steps/s] for stepzoo's implicit methods
    and diffrax_kvaerno5, and scipy_radau_d{d}_steps_per_s."""
    rhs = _rhs(d)
    made = {name: baselines.stepzoo_run(H_S, steps, "final", name, rhs) for name in names}
    made["diffrax_kvaerno5"] = baselines.diffrax_run(H_S, steps, "final", "kvaerno5", rhs)
    args = vehicle_problem(d, batch)
    fns = {name: _compiled(fn, args) for name, fn in made.items()}
    fig = {f"{name}_d{d}_final_b1e3_steps_per_s": batch * steps / s
           for name, s in _rounds(fns, args, ROUNDS)[0].items()}
    fig[f"scipy_radau_d{d}_steps_per_s"] = scipy_radau_steps_per_s(d)
    return fig


@pytest.mark.parametrize("d", sorted(MODELS))
def test_implicit_vehicle_models(benchmark, d):
    fig = benchmark.pedantic(model_figures, args=(d,), rounds=1)
    benchmark.extra_info.update(kind="regimes", figures=fig)
