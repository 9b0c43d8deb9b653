"""The sweep's stability test: a run from the initial state plus a small perturbation along
the modes that bound the step, against a run from the initial state with the same method
and step; the step blows up where their scaled distance grows past `growth` times its start."""
from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from stepzoo.bench.model import frozen_jacobian as frozen
from stepzoo.bench.sweep.limit_search import Outcome, Probe

if TYPE_CHECKING:
    from stepzoo.bench.sweep.points import Points
    from stepzoo.bench.sweep.runs.method_runs import Runner


def perturbation(spec, jac0: np.ndarray, size: float) -> np.ndarray:
    """(B, d) initial deviation of the stability runs from the Jacobians jac0 (B, d, d) at the
    initial states: the same amount of each eigenmode that bounds a step (each mode scaled to
    size 1 in the error norm), the sum scaled to `size`; every error state alike when no mode
    bounds one."""
    out = np.zeros(jac0.shape[:2])
    for b in range(len(jac0)):
        # A model not finite at the start (model_nan) has no modes: every state alike.
        finite = np.isfinite(jac0[b]).all()
        w, V = np.linalg.eig(jac0[b] if finite else np.zeros_like(jac0[b]))
        d = np.zeros(len(w))
        for j in np.where(frozen.constraining(w))[0]:
            mode = spec.scaled(V[:, j].real) + spec.scaled(V[:, j].imag)
            if np.isfinite(mode) and mode > 0:
                d += V[:, j].real / mode
        total = spec.scaled(d)
        if not (np.isfinite(total) and total > 0):
            d = np.zeros(len(w))
            d[spec.error_index] = spec.error_scales
            total = 1.0
        out[b] = size * d / total
    return out


@dataclass(frozen=True)
class StabilityRuns:
    """The stability test of a block's lanes (bench.sweep.points.Points) with the perturbations
    delta (B, d), runs of `steps` steps by `runner` (bench.sweep.runs.method_runs.Runner)."""
    runner: Runner
    points: Points
    delta: np.ndarray
    steps: int
    growth: float

    def probe(self, meth) -> Probe:
        return partial(self.runs_at, meth)

    def runs_at(self, meth, lanes, h) -> Outcome:
        """Outcomes (N,) of candidate steps h (N,) [s] at lanes (N,). A run blows up at the
        first step where the scaled distance is not finite or exceeds `growth` times its start;
        a run whose nonlinear solves failed is never stable. The candidates go in calls of the
        block's own size (the last one filled with repeats): the accuracy runs' compiled
        program serves them."""
        B, N = len(self.points), len(h)
        ok, t_blow, conv = np.zeros(N, bool), np.full(N, np.nan), np.zeros(N, bool)
        for start in range(0, N, B):
            part = slice(start, min(start + B, N))
            m = part.stop - start
            idx, hh = np.resize(lanes[part], B), np.resize(h[part], B)
            x0, u, p = self.points.take(idx)
            a = self.runner(meth, x0 + self.delta[idx], u, p, hh, self.steps)
            b = self.runner(meth, x0, u, p, hh, self.steps)
            t0 = time.perf_counter()
            with np.errstate(invalid="ignore", over="ignore"):
                dev = self.runner.spec.scaled(a.x[:m] - b.x[:m])
                blown = ~(dev <= self.growth * dev[:, :1])
            k = np.where(blown.any(axis=1), np.argmax(blown, axis=1), -1)
            conv[part] = a.converged[:m] & b.converged[:m]
            ok[part] = (k < 0) & conv[part]
            t_blow[part] = np.where(k < 0, np.nan, k * hh[:m])
            self.runner.watch.add("stability_s", a.run_s + b.run_s + time.perf_counter() - t0)
        return Outcome(ok, t_blow, conv)
