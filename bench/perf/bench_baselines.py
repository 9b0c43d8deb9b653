"""stepzoo's rk4 against its baselines (baselines.py) in both regimes, every state stored and
the final state only, at batches BATCHES of STEPS steps of H_S; and stepzoo's implicit
methods against diffrax's Kvaerno5 at a constant step, final state only. Within a batch the
contenders run in interleaved rounds, so that a load spike on the shared machine hits all of
them; each figure is the best round. JAX's are compiled ahead of the rounds, Numba's by a
first call on one trajectory; NumPy has nothing to compile."""
from time import perf_counter

import jax
import numpy as np

from stepzoo.bench.perf.workloads import baselines
from stepzoo.bench.perf.workloads.implicit import IMPLICIT
from stepzoo.bench.perf.workloads.bicycle import H_S, problem

BATCHES = (1_000, 10_000, 100_000)
STEPS = 100                   # a stored run at batch 1e5 holds 0.4 GB
ROUNDS = {1_000: 7, 10_000: 5, 100_000: 3}
SLOW_S = 4.0                  # a contender whose call takes longer runs one round only
IMPLICIT_BATCHES = (10_000,)     # the batch of issue 26's implicit targets
IMPLICIT_STEPS = 20
LABEL = {1_000: "1e3", 10_000: "1e4", 100_000: "1e5"}


def _compiled(fn, args):
    """A JAX function compiled for `args` ahead of the rounds; any other (Numba's compiles
    on its first call) called once on the first trajectory."""
    if hasattr(fn, "lower"):
        return fn.lower(*args).compile()
    fn(*jax.tree.map(lambda a: a[:1], args))
    return fn


def _rounds(fns: dict, args, rounds: int, check: tuple = ()) -> tuple[dict, float]:
    """The best wall time [s] of each f(*args), in interleaved rounds; and the largest
    difference of the final states of the contenders named in `check` from the first
    contender's in the first round, relative to each trajectory's largest state."""
    best, slow, first, diff = {}, set(), None, 0.0
    for r in range(rounds):
        for name, fn in fns.items():
            if name in slow:
                continue
            t0 = perf_counter()
            out = jax.block_until_ready(fn(*args))
            took = perf_counter() - t0
            best[name] = min(best.get(name, np.inf), took)
            if took > SLOW_S:
                slow.add(name)
            if r == 0 and (first is None or name in check):
                end = np.asarray(out)[:, -1] if np.ndim(out) == 3 else np.asarray(out)
                if first is None:
                    first = end
                else:
                    scale = np.abs(first).max(axis=1)
                    diff = max(diff, float((np.abs(end - first).max(axis=1) / scale).max()))
            del out
    return best, diff


def regime_figures(batches=BATCHES, steps=STEPS) -> dict:
    """{contender}_{regime}_b{batch}_steps_per_s [trajectory-steps/s] for every contender,
    regime and batch; same_work_{regime}_max_rel_diff: the largest difference of an RK4
    baseline's final states from stepzoo's rk4 over the batches, relative to each
    trajectory's largest state (round-off when both do the same work)."""
    fig = {}
    for regime in baselines.REGIMES:
        made = baselines.contenders(H_S, steps, regime)
        for batch in batches:
            args = problem(batch)
            fns = {name: _compiled(fn, args) for name, fn in made.items()}
            best, diff = _rounds(fns, args, ROUNDS.get(batch, 3), baselines.SAME_AS_RK4)
            for name, s in best.items():
                fig[f"{name}_{regime}_b{LABEL[batch]}_steps_per_s"] = batch * steps / s
            key = f"same_work_{regime}_max_rel_diff"
            fig[key] = max(fig.get(key, 0.0), diff)
    return fig


def implicit_figures(batches=IMPLICIT_BATCHES, steps=IMPLICIT_STEPS) -> dict:
    """The same, final state only, for stepzoo's implicit methods and diffrax's Kvaerno5."""
    fig = {}
    made = {name: baselines.stepzoo_run(H_S, steps, "final", name) for name in IMPLICIT}
    made["diffrax_kvaerno5"] = baselines.diffrax_run(H_S, steps, "final", "kvaerno5")
    for batch in batches:
        args = problem(batch)
        fns = {name: _compiled(fn, args) for name, fn in made.items()}
        for name, s in _rounds(fns, args, ROUNDS.get(batch, 3))[0].items():
            fig[f"{name}_final_b{LABEL[batch]}_steps_per_s"] = batch * steps / s
    return fig


def test_regimes(benchmark):
    fig = benchmark.pedantic(regime_figures, rounds=1)
    found = baselines.numba_layer() if "numba_fastmath_final_b1e3_steps_per_s" in fig else {}
    benchmark.extra_info.update(kind="regimes", figures=fig, machine=dict(
        found, regime_steps=STEPS, xla_host_devices=len(jax.devices())))


def test_implicit_vs_kvaerno5(benchmark):
    fig = benchmark.pedantic(implicit_figures, rounds=1)
    benchmark.extra_info.update(kind="regimes", figures=fig)
