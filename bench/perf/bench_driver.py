"""Driver throughput (trajectory-steps per second) per method and batch size, on the generic
model and, for rk4, with `fast_trig`; compile time per method apart from run time. Each driver
benchmark also records the right-hand-side evaluations per step its run counted (Newton
iterations and Jacobians included), so that implicit methods compare with rk4 per evaluation."""
from time import perf_counter

import jax
import numpy as np
import pytest

from stepzoo.bench.perf.workloads.implicit import IMPLICIT, IMPLICIT_BATCHES
from stepzoo.bench.perf.workloads.bicycle import H_S, MODEL, N_STEPS, problem
from stepzoo.integrators import integrate_batch, method
from stepzoo.integrators.fast_trig import fast_trig

BATCHES = (1, 100, 10_000, 100_000)
ROUNDS = {1: 30, 100: 10, 10_000: 3, 100_000: 1}   # plus a warm-up round each
METHODS = ("rk4", "dopri5", "ab4", "trapezoidal")
INTERLEAVED = 3     # rounds of each in test_generic_vs_fast_trig


def n_steps(name, batch):
    """Newton makes implicit steps ~30x slower: fewer steps keep their big batches to
    seconds; throughput per trajectory-step is still comparable."""
    return N_STEPS if not method(name).implicit else max(10, min(N_STEPS, 2_000_000 // batch))


def _run(meth, f, args, n):
    """A timed call; it returns the trajectories' mean evaluations per step."""
    def call():
        tr = jax.block_until_ready(integrate_batch(meth, f, *args, H_S, n))
        return float(np.mean(tr.evals)) / n
    return call


def _driver(benchmark, name, batch):
    n = n_steps(name, batch)
    rounds = max(ROUNDS[batch], 2) if name == "rk4" else ROUNDS[batch]
    evals = benchmark.pedantic(_run(method(name), MODEL.rhs, problem(batch), n),
                               rounds=rounds, warmup_rounds=1)
    benchmark.extra_info.update(kind="driver", method=name, batch=batch, n_steps=n,
                                work=batch * n, rhs="model", evals_per_step=evals)


@pytest.mark.parametrize("batch", BATCHES)
@pytest.mark.parametrize("name", METHODS)
def test_driver(benchmark, name, batch):
    _driver(benchmark, name, batch)


# The other implicit methods of run.py's ratios to rk4, at the batches of those ratios.
@pytest.mark.parametrize("batch", IMPLICIT_BATCHES)
@pytest.mark.parametrize("name", [n for n in IMPLICIT if n not in METHODS])
def test_driver_implicit(benchmark, name, batch):
    _driver(benchmark, name, batch)


@pytest.mark.parametrize("batch", BATCHES)
def test_driver_fast_trig(benchmark, batch):
    benchmark.extra_info.update(kind="driver", method="rk4", batch=batch, n_steps=N_STEPS,
                                work=batch * N_STEPS, rhs="fast_trig")
    # rk4 at batch 1e5 is the headline ratio: a second round against load spikes.
    benchmark.pedantic(_run(method("rk4"), fast_trig(MODEL.rhs), problem(batch), N_STEPS),
                       rounds=max(ROUNDS[batch], 2), warmup_rounds=1)


def test_generic_vs_fast_trig(benchmark):
    """rk4 at batch 1e5: the generic model (the driver's default path) against fast_trig, in
    interleaved rounds so that load spikes hit both; the best round of each [s]."""
    meth, args = method("rk4"), problem(100_000)
    runs = {"generic": _run(meth, MODEL.rhs, args, N_STEPS),
            "fast_trig": _run(meth, fast_trig(MODEL.rhs), args, N_STEPS)}
    best = {}

    def rounds():
        for _ in range(INTERLEAVED):
            for name, fn in runs.items():
                best[name] = min(best.get(name, float("inf")), _min_time(fn, reps=1))

    for fn in runs.values():
        fn()
    benchmark.pedantic(rounds, rounds=1)
    benchmark.extra_info.update(kind="interleaved", method="rk4", batch=100_000, best_s=best)


@pytest.mark.parametrize("name", METHODS)
def test_compile(benchmark, name):
    """First call at batch 100 with a step count not compiled before (so each round compiles
    afresh), less the run time of a compiled call: the compile time [s]."""
    meth, args = method(name), problem(100)
    counts = iter(range(N_STEPS + 1, N_STEPS + 100))
    first = lambda n: jax.block_until_ready(integrate_batch(meth, MODEL.rhs, *args, H_S, n).x)
    benchmark.pedantic(first, setup=lambda: ((next(counts),), {}), rounds=3)
    benchmark.extra_info.update(kind="compile", method=name,
                                run_s=_min_time(_run(meth, MODEL.rhs, args, N_STEPS + 1)))


def _min_time(fn, reps=5):
    """Best of `reps` calls [s]."""
    best = float("inf")
    for _ in range(reps):
        t0 = perf_counter()
        fn()
        best = min(best, perf_counter() - t0)
    return best
