"""A method's batched runs in a sweep: n steps of h from every lane in one compiled call, and
an accuracy run's errors against the reference."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from stepzoo.bench.sweep import metrics

if TYPE_CHECKING:
    from stepzoo.bench.model.spec import ModelSpec
    from stepzoo.bench.timing.chunk_stopwatch import Stopwatch


class Run(NamedTuple):
    """x (B, n+1, d) the states, evals (B,) right-hand-side evaluations, converged (B,)
    whether every nonlinear solve did, run_s [s] the call's time without JAX's compiling."""
    x: np.ndarray
    evals: np.ndarray
    converged: np.ndarray
    run_s: float


class Accuracy(NamedTuple):
    """An accuracy run: its error columns of the runs table (B,) each, evals, converged and
    run_s as Run's, and its states x (B, n+1, d)."""
    errors: dict
    evals: np.ndarray
    converged: np.ndarray
    run_s: float
    x: np.ndarray


@dataclass(frozen=True)
class Runner:
    """Runs a method on a model's lanes; every call of a block pads its runs to max_steps
    steps, so that one compiled program serves them all. Compiling goes to watch's
    compile_s; the caller charges the run. A sweep probes steps where solves fail, so its
    programs carry the full-Newton retry from the first run (driver.retry_at_once)."""
    spec: ModelSpec
    max_steps: int
    watch: Stopwatch

    def __call__(self, meth, x0, u, p, h, n: int) -> Run:
        """n steps of h [s] (one, or (B,) per lane) from x0 (B, d) with inputs u, params p."""
        import jax.numpy as jnp
        from stepzoo.integrators import integrate_batch
        from stepzoo.integrators.driver import retry_at_once
        retry_at_once(meth)
        hb = jnp.broadcast_to(jnp.asarray(h, float), (len(x0),))
        with self.watch.split() as took:
            tr = integrate_batch(meth, self.spec.rhs, jnp.asarray(x0), jnp.asarray(u),
                                 {k: jnp.asarray(v) for k, v in p.items()}, hb, jnp.asarray(n),
                                 max_steps=self.max_steps)
            x = np.asarray(tr.x.block_until_ready())[:, : n + 1]
        return Run(x, np.asarray(tr.evals), np.asarray(tr.converged, bool), took["run"])


def accuracy_run(runner: Runner, meth, points, h: float, n: int, ref: np.ndarray,
                 estimate: str) -> Accuracy:
    """n steps of h [s] from every lane of `points` and their errors against the reference
    ref (B, n+1, d) at the same times: the run goes to integration_s, the errors to
    metrics_s."""
    run = runner(meth, points.x0, points.u, points.p, h, n)
    runner.watch.add("integration_s", run.run_s)
    with runner.watch.clock("metrics_s"):
        errors = run_errors(runner.spec, run.x, ref, estimate)
    return Accuracy(errors, run.evals, run.converged, run.run_s, run.x)


def run_errors(spec, x, ref, estimate: str) -> dict:
    """The runs table's error columns of runs x (B, N+1, d) against ref: per state the largest
    distance (inf where a run left the finite range), for a vehicle the position's largest
    and final [m], and `err` (metrics.run_error by the config's estimate)."""
    with np.errstate(invalid="ignore", over="ignore"):
        d = np.abs(x - ref)
    d = np.where(np.isfinite(d), d, np.inf)
    col = {f"err_{state}": d[:, :, s].max(axis=1) for s, state in enumerate(spec.states)}
    if spec.vehicle:
        pos = np.hypot(d[:, :, spec.states.index("X")], d[:, :, spec.states.index("Y")])
        col["err_pos"], col["err_final"] = pos.max(axis=1), pos[:, -1]
    col["err"] = metrics.run_error(spec, x, ref, estimate)
    return col
