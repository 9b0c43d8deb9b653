"""The baselines on the driver's problem (rk4, H_S, N_STEPS, float64, whole trajectory kept):
NumPy, Numba serial and `prange`+`fastmath`, diffrax, and SciPy DOP853 on one trajectory."""
import jax
import pytest

from stepzoo.bench.perf import baselines
from stepzoo.bench.perf.workload import H_S, N_STEPS, problem

ROUNDS = {1: 30, 100: 10, 10_000: 3, 100_000: 2}   # as the driver's rk4, the contender


def _info(benchmark, name, batch):
    benchmark.extra_info.update(kind="baseline", baseline=name, batch=batch, n_steps=N_STEPS,
                                work=batch * N_STEPS)


@pytest.mark.parametrize("batch", (100, 10_000, 100_000))
def test_numpy(benchmark, batch):
    _info(benchmark, "numpy", batch)
    args = problem(batch)
    # Nothing to compile, and ~30 s a round at batch 1e5: one round there, no warm-up.
    benchmark.pedantic(lambda: baselines.numpy_rk4(*args, H_S, N_STEPS),
                       rounds=1 if batch == 100_000 else ROUNDS[batch],
                       warmup_rounds=0 if batch == 100_000 else 1)


@pytest.mark.parametrize("batch", (1, 10_000, 100_000))
@pytest.mark.parametrize("parallel", (False, True), ids=("serial", "fastmath"))
def test_numba(benchmark, parallel, batch):
    pytest.importorskip("numba")
    if not parallel and batch == 100_000:
        pytest.skip("serial Numba is the batch-1 baseline; 1e4 already shows its rate")
    _info(benchmark, "numba_fastmath" if parallel else "numba_serial", batch)
    fn, args = baselines.numba_rk4(parallel), problem(batch)
    benchmark.pedantic(lambda: fn(*args, H_S, N_STEPS), rounds=ROUNDS[batch], warmup_rounds=1)


@pytest.mark.parametrize("batch", (1, 10_000, 100_000))
def test_diffrax(benchmark, batch):
    pytest.importorskip("diffrax")
    _info(benchmark, "diffrax", batch)
    fn, args = baselines.diffrax_rk4(N_STEPS, H_S), problem(batch)
    benchmark.pedantic(lambda: jax.block_until_ready(fn(*args)), rounds=ROUNDS[batch],
                       warmup_rounds=1)


def test_scipy_dop853(benchmark):
    _info(benchmark, "scipy_dop853", 1)
    x0, u, p = problem(1)
    one = {k: v[0] for k, v in p.items()}
    benchmark.pedantic(lambda: baselines.scipy_dop853(x0[0], u[0], one, H_S, N_STEPS),
                       rounds=5, warmup_rounds=1)
