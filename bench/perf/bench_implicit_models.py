"""Implicit steps on vehicle models of 5, 9 and 29 states (the benchmark's bicycle, and
dynamics.commonroad's single-track drift model and multi-body model, BMW 320i, stiff through
their wheel speeds): stepzoo's implicit methods against diffrax's Kvaerno5 at the same
constant step H_S and step count, final state only, in interleaved rounds
(bench_baselines._rounds); and SciPy's Radau on one trajectory with its step capped at H_S
(its own error control, the model's f and Jacobian jitted by JAX, as a user would pass them)
as a per-step baseline. Each contender's compile time is recorded beside its throughput:
stepzoo's as a user calling `integrate_batch` meets it (its first call less its best round),
diffrax's as its jitted function's compile."""
from functools import partial
from time import perf_counter, process_time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stepzoo.bench.perf.workloads import baselines
from stepzoo.bench.perf.bench_baselines import _compiled, _rounds
from stepzoo.bench.perf.workloads.implicit import IMPLICIT
from stepzoo.bench.perf.workloads import bicycle
from stepzoo.bench.perf.workloads.bicycle import H_S
from stepzoo.dynamics import commonroad
from stepzoo.integrators import integrate_batch

BATCH = 1_000
STEPS = 20
ROUNDS = 3
MODELS = {9: (commonroad.std_rhs, commonroad.std_state),
          29: (commonroad.mb_rhs, commonroad.mb_state)}
STATES = (5, *MODELS)


def _rhs(d):
    """f(t, x, u, p) of the d-state model: the bicycle's, or a CommonRoad model's with the
    BMW 320i bound (p unused, so that every contender takes the same batched arguments)."""
    return bicycle.MODEL.rhs if d == 5 else partial(_bound_rhs, MODELS[d][0])


def _bound_rhs(rhs, t, x, u, p):
    return rhs(t, x, u, commonroad.BMW_320I)


def vehicle_problem(d: int, batch: int, seed: int = 0):
    """(x0 (B, d), u (B, 2), p (B,) unused) as NumPy: speeds 10-25 m/s, seeded steering
    angles, yaw rates and slip angles, wheels rolling; steering still, mild acceleration.
    At d = 5 the bicycle's problem (bicycle.problem)."""
    if d == 5:
        return bicycle.problem(batch, seed)
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
    u0, p0 = u[0], jax.tree.map(lambda a: a[0], p)
    f = jax.jit(lambda t, x: _rhs(d)(t, x, u0, p0))
    jac = jax.jit(jax.jacfwd(lambda t, x: _rhs(d)(t, x, u0, p0), argnums=1))
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


def _stepzoo(name, rhs, steps):
    """stepzoo's final states as a user gets them: `integrate_batch` called as it is (it
    compiles itself), not inside a jit of the caller's, which would compile its libm
    fallback too (see integrate_batch)."""
    def run(x0, u, p):
        return integrate_batch(name, rhs, x0, u, p, H_S, steps).x[:, -1]
    return run


def _first_call(fn, args) -> tuple[float, float]:
    """(wall [s], processor time of this process [s]) of fn's first call, compile included."""
    t0, c0 = perf_counter(), process_time()
    jax.block_until_ready(fn(*args))
    return perf_counter() - t0, process_time() - c0


def model_figures(d: int, names=IMPLICIT, batch=BATCH, steps=STEPS) -> dict:
    """{name}_d{d}_final_b1e3_steps_per_s [trajectory-steps/s] for stepzoo's implicit methods
    and diffrax_kvaerno5, scipy_radau_d{d}_steps_per_s; and {name}_d{d}_compile_s and
    _compile_cpu_s [s], wall and processor time (the machine is shared: the processor time
    is the work)."""
    rhs = _rhs(d)
    args = vehicle_problem(d, batch)
    fns, first = {}, {}
    for name in names:
        fns[name] = _stepzoo(name, rhs, steps)
        first[name] = _first_call(fns[name], args)
    kvaerno = baselines.diffrax_run(H_S, steps, "final", "kvaerno5", rhs)
    t0, c0 = perf_counter(), process_time()
    fns["diffrax_kvaerno5"] = _compiled(kvaerno, args)
    compiled = {"diffrax_kvaerno5": (perf_counter() - t0, process_time() - c0)}
    best = _rounds(fns, args, ROUNDS)[0]
    fig = {f"{name}_d{d}_final_b1e3_steps_per_s": batch * steps / s for name, s in best.items()}
    for name, (wall, cpu) in first.items():
        # The first call ran the steps once too: less its best round's time.
        compiled[name] = (wall - best[name], cpu - best[name])
    for name, (wall, cpu) in compiled.items():
        fig[f"{name}_d{d}_compile_s"] = max(wall, 0.0)
        fig[f"{name}_d{d}_compile_cpu_s"] = max(cpu, 0.0)
    fig[f"scipy_radau_d{d}_steps_per_s"] = scipy_radau_steps_per_s(d)
    return fig


@pytest.mark.parametrize("d", STATES)
def test_implicit_vehicle_models(benchmark, d):
    fig = benchmark.pedantic(model_figures, args=(d,), rounds=1)
    benchmark.extra_info.update(kind="regimes", figures=fig)
