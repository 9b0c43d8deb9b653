"""Calibration: each method's wall time per step [s] where the planner spends it, in one call
of the driver that integrates a batch of shootings of a fixed interval, as `Shooter` does.

The methods are timed interleaved, round by round in a rotating order, so that a machine
busy for a while slows every method alike; each keeps the minimum of its rounds (the least
disturbed) and the spread, median minus minimum, as the noise its comparison must allow."""
from __future__ import annotations

import time
from typing import Callable, Mapping, NamedTuple

import numpy as np

ROUNDS = 7          # timed rounds per method after its compiling call
# The planner's call with its default parameters (bench cannot read search's): batch_nodes x
# (n_arc + n_random) shootings of one horizon [s]. `stepzoo tune` passes the planner's own.
PLANNER_BATCH, PLANNER_INTERVAL_S = 40, 0.8
# Wall time [s] a round's sample of one method lasts at least, in back-to-back calls: a call
# of explicit methods at batch 40 takes a fraction of a millisecond, where a single
# preemption or timer tick is a large part of one call's time.
SAMPLE_S = 2e-3


class Calibration(NamedTuple):
    """One method's time per step: `per_step_s` the minimum over rounds [s], `spread_s`
    median minus minimum [s], at step `h` [s] and `n_steps` steps per call of `batch`."""
    h: float
    n_steps: int
    batch: int
    per_step_s: float
    spread_s: float
    rounds: int

    @property
    def spread(self) -> float:
        """The spread as a fraction of the minimum."""
        return self.spread_s / self.per_step_s

    def per_sim_s(self, h: float) -> float:
        """Seconds of wall time per simulated second at step h [s]: steps per second x time
        per step."""
        return self.per_step_s / h


def calibrate(methods: Mapping[str, float], model, batch: int, interval_s: float,
              rounds: int = ROUNDS, resolve: Callable | None = None,
              points: list | None = None) -> dict[str, Calibration]:
    """Time per step of each method of `methods` ({name: h [s]}) on `model` (a ModelSpec),
    integrating `batch` trajectories over `interval_s` [s] (round(interval_s / h) steps, at
    least one) per call, `rounds` rounds after one compiling call each. The lanes cycle
    through `points` (default: the model's envelope), so that an implicit method's Newton
    iterations are those of the operating range. `resolve(name)` gives the Method (default:
    the zoo's, with its default Newton options). Runs in the caller's JAX settings and XLA
    flags: the `stepzoo` command's, as the planner runs."""
    import jax.numpy as jnp

    from stepzoo.integrators import integrate_batch
    from stepzoo.integrators import method as zoo_method
    if rounds < 1 or batch < 1 or not interval_s > 0:
        raise ValueError(f"need rounds >= 1, batch >= 1 and interval_s > 0, got {rounds}, "
                         f"{batch}, {interval_s}")
    resolve = resolve or zoo_method
    pts = list(points if points is not None else model.points)
    lanes = [pts[i % len(pts)] for i in range(batch)]
    # States and inputs in NumPy, as the planner passes them: converting is part of a call.
    x0, u, p = model.arrays(lanes)
    p = {k: jnp.asarray(v) for k, v in p.items()}      # built once per shooter, as jnp
    calls = {}
    for name, h in methods.items():
        n = max(1, round(interval_s / h))
        meth = resolve(name)
        run = _call(integrate_batch, meth, model.rhs, x0, u, p, float(h), n)
        run()                                # compiles (or loads the compiled program)
        repeat = max(1, int(np.ceil(SAMPLE_S / _wall(run, 1))))
        calls[name] = (run, float(h), n, repeat)
    names = list(calls)
    walls: dict[str, list[float]] = {name: [] for name in names}
    for r in range(rounds):
        for name in names[r % len(names):] + names[:r % len(names)]:
            run, _, _, repeat = calls[name]
            walls[name].append(_wall(run, repeat) / repeat)
    out = {}
    for name in names:
        _, h, n, _ = calls[name]
        t = np.asarray(walls[name]) / n
        out[name] = Calibration(h, n, batch, float(t.min()), float(np.median(t) - t.min()),
                                rounds)
    return out


def _wall(run, repeat: int) -> float:
    t0 = time.perf_counter()
    for _ in range(repeat):
        run()
    return time.perf_counter() - t0


def _call(integrate_batch, meth, rhs, x0, u, p, h, n):
    # The planner reads the states back into NumPy: the copy is part of what a step costs.
    return lambda: np.asarray(integrate_batch(meth, rhs, x0, u, p, h, n).x)
