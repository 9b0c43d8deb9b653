"""The sweep's stability tests ([stability] rule). "blowup": a run from the initial state plus
a small perturbation along the modes that bound the step, against a run from the initial
state with the same method and step; the step blows up where their distance in the error
norm grows past `growth` times its start. "modes" (MODES_RULE): each eigenmode and each
state alone, in every state, against the reference's own growth, within the stability
horizon; with a diagnosis of the run (the state and time it departs)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, NamedTuple

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


# ---- the "modes" rule: every state, each direction alone, against the reference's growth --

MODES = 3          # the fastest constraining eigenmodes perturbed, each in runs of its own
SEED = 20261128    # of the random directions that stand in for missing modes
RETRY_ITERATIONS = 4   # a failed solve is retried with this many times the iterations
STATE_FLOOR = 1.0  # a state's scale where it and its error scale are absent or 0 [its unit]
MODES_RULE = (
    f"Each stability run starts from the initial state plus one of {MODES} + d directions "
    f"(d states): the real part of each of the {MODES} fastest eigenmodes of df/dx there "
    f"that bound a step (by |lambda|; random directions where it has fewer, NumPy's "
    f"default_rng seeded {SEED} and the point's index), then each state alone; each "
    "direction in runs of its own, so that modes cannot cancel, sized "
    "`perturbation` in the state norm: the largest |dx_i| / scale_i over every state, "
    "scale_i the state's largest |x_i| along the reference (at least its error scale; "
    f"{STATE_FLOOR:g} where both are 0). It is compared with the same method's run from the "
    "initial state, step by step up to the stability horizon (ceil(horizon / h) steps), and "
    "is unstable at the first step where their distance in the state norm is not finite or "
    "exceeds `growth` times its start times the reference's own growth of that direction "
    "so far (at least 1: the reference solved from both states). A run whose nonlinear "
    f"solve failed inside the horizon (also when retried with {RETRY_ITERATIONS}x the Newton "
    "iterations; a solve that converges then needed more iterations and the retry is "
    "judged) is never stable; failures past the horizon are not counted. "
    "Where the reference's own growth exceeds `growth`, the model itself diverges there.")


class Diagnosis(NamedTuple):
    """Per candidate (N,): the state whose deviation was largest where the run failed (its
    index, -1 where none), that time [s] (NaN where none), the method's growth over the
    reference's (the largest over the run and the directions), the reference's own
    largest growth over the horizon, and whether its solves converged only when retried
    with RETRY_ITERATIONS times the Newton iterations."""
    state: np.ndarray
    t: np.ndarray
    growth_ratio: np.ndarray
    ref_growth: np.ndarray
    retried: np.ndarray


def more_iterations(meth):
    """The method with RETRY_ITERATIONS times its Newton iterations: the driver runs it with
    the method's own compiled program (the options are run-time values, Method.program)."""
    import dataclasses

    from stepzoo.integrators import method
    opts = meth.newton
    return method(meth.name, dataclasses.replace(
        opts, max_iter=RETRY_ITERATIONS * opts.max_iter,
        max_iter_full=RETRY_ITERATIONS * max(opts.max_iter_full, opts.max_iter)))


def state_scales(spec, xs: np.ndarray) -> np.ndarray:
    """(B, d) each state's scale: its largest |x_i| over the reference xs (B, T, d), at least
    its error scale for an error state, STATE_FLOOR where both are 0 (or not finite)."""
    with np.errstate(invalid="ignore"):
        s = np.nanmax(np.abs(xs), axis=1)
    floor = np.zeros(xs.shape[-1])
    floor[spec.error_index] = spec.error_scales
    s = np.fmax(np.nan_to_num(s, nan=0.0, posinf=0.0), floor)
    return np.where(s > 0, s, STATE_FLOOR)


def directions(jac0: np.ndarray, scales: np.ndarray, size: float, ids) -> np.ndarray:
    """(B, MODES + d, d) initial deviations: per point (ids: the config's point indices)
    the real part of each of its MODES fastest constraining eigenmodes at the Jacobian jac0
    (B, d, d) (its imaginary part where that is 0; seeded random directions where it has
    fewer), then each state alone, each scaled to `size` in the state norm max_i |d_i| /
    scales_i."""
    B, d = jac0.shape[:2]
    out = np.zeros((B, MODES + d, d))
    for b in range(B):
        modes = []
        if np.isfinite(jac0[b]).all():
            w, V = np.linalg.eig(jac0[b])
            keep = np.where(frozen.constraining(w) & (w.imag >= 0))[0]
            for j in keep[np.argsort(-np.abs(w[keep]))][:MODES]:
                v = V[:, j].real if np.abs(V[:, j].real).max() > 0 else V[:, j].imag
                modes.append(v)
        rng = np.random.default_rng([SEED, int(ids[b])])
        while len(modes) < MODES:
            modes.append(rng.standard_normal(d) * scales[b])
        for k, v in enumerate([*modes, *np.eye(d)]):
            out[b, k] = size * v / np.max(np.abs(v) / scales[b])
    return out


def _state_norm(dx, scales):
    """max_i |dx_i| / scales_i over the last axis (inf where any is not finite)."""
    with np.errstate(invalid="ignore", over="ignore"):
        d = np.abs(dx) / scales
        return np.where(np.isfinite(d).all(axis=-1), d.max(axis=-1), np.inf)


@dataclass(frozen=True)
class ModalRuns:
    """The "modes" stability test (MODES_RULE) of a block's lanes: deviations delta (B, K,
    d), state scales (B, d), the reference's running-largest growth ref_growth (B, K, T) of
    each direction at the times ts (T,) [s] up to the stability horizon [s]; runs by
    `runner` (bench.sweep.runs.method_runs.Runner)."""
    runner: Runner
    points: Points
    delta: np.ndarray
    scales: np.ndarray
    ts: np.ndarray
    ref_growth: np.ndarray
    horizon: float
    growth: float
    made: dict = field(default_factory=dict)

    def probe(self, meth, settle: bool = False) -> Probe:
        """The test of candidates as a Probe; with `settle`, a candidate the first runs show
        not stable is settled by them (`judge`)."""
        return partial(self.runs_at, meth, settle=settle)

    def runs_at(self, meth, lanes, h, settle: bool = False) -> Outcome:
        """Outcomes (N,) of candidate steps h (N,) [s] at lanes (N,)."""
        return self.judge(meth, lanes, h, settle)[0]

    def steps(self, h) -> np.ndarray:
        """Steps that reach the stability horizon at h [s] (at most the runner's)."""
        n = np.ceil(self.horizon / np.asarray(h, float) - 1e-9)
        return np.minimum(n, self.runner.max_steps).astype(int)

    def _runs(self, meth, lanes, h, n_own, runs) -> tuple[list, np.ndarray]:
        """The runs (i, k) (candidate i from its initial state, k = -1, or plus direction k),
        as lanes of their own in calls of the block's size: their states up to the
        candidate's own horizon (n_own (N,) steps), and whether their solves converged
        there. An unperturbed run `made` already as long (a grid step's accuracy run, by
        the same method and program) is taken, not run again."""
        B = len(self.points)
        x: list = [None] * len(runs)
        conv = np.zeros(len(runs), bool)
        todo = []
        for r, (i, k) in enumerate(runs):
            got = self.made.get((meth, float(h[i]))) if self.made and k < 0 else None
            if got is not None and got[0].shape[1] == n_own[i] + 1:
                x[r] = got[0][lanes[i]]
                conv[r] = got[1][lanes[i]] or np.isfinite(x[r]).all()
            else:
                todo.append(r)
        for start in range(0, len(todo), B):
            part = todo[start: start + B]
            idx = np.resize([lanes[runs[r][0]] for r in part], B)
            hh = np.resize([h[runs[r][0]] for r in part], B)
            x0, u, p = self.points.take(idx)
            dx = np.zeros_like(x0)
            for j, r in enumerate(part):
                i, k = runs[r]
                if k >= 0:
                    dx[j] = self.delta[lanes[i], k]
            n = int(max(n_own[runs[r][0]] for r in part))
            run = self.runner(meth, x0 + dx, u, p, hh, n)
            self.runner.watch.add("stability_s", run.run_s)
            for j, r in enumerate(part):
                x[r] = run.x[j, : n_own[runs[r][0]] + 1]
                # A solve that failed leaves NaN from its step on (the driver's contract):
                # failures past this candidate's horizon are not its own.
                conv[r] = run.converged[j] or np.isfinite(x[r]).all()
        return x, conv

    def _retried(self, meth, lanes, h, n_own, xs: dict, cs: dict) -> np.ndarray:
        """Where a candidate's solve failed (cs, by run (i, k), False), all of its runs in xs
        run again with RETRY_ITERATIONS times the Newton iterations: where every one of
        those converges, they replace its runs in xs and cs (the solve needed more
        iterations). Returns which candidates (N,) were so replaced."""
        retried = np.zeros(len(h), bool)
        failed = sorted({i for (i, _), c in cs.items() if not c})
        if failed and meth.solves:
            again = [(i, k) for i, k in xs if i in failed]
            x2, conv2 = self._runs(more_iterations(meth), lanes, h, n_own, again)
            for i in failed:
                mine = [r for r, (j, _) in enumerate(again) if j == i]
                if conv2[mine].all():
                    for r in mine:
                        xs[again[r]], cs[again[r]] = x2[r], True
                    retried[i] = True
        return retried

    def _first_failures(self, lane, h, xs, ks) -> tuple[np.ndarray, float]:
        """Per direction of ks, the first step where the run from it departs past `growth`
        (its length where none), and the largest growth over the reference's among them."""
        base, sc = xs[-1], self.scales[lane]
        ts = h * np.arange(len(base))
        slot = np.minimum(np.searchsorted(self.ts, ts), len(self.ts) - 1)
        first, ratio = np.full(len(ks), len(base)), 0.0
        for j, k in enumerate(ks):
            allow = np.fmax(1.0, np.nan_to_num(self.ref_growth[lane, k, slot], nan=1.0))
            # A run that blew up is a result (it departed): its inf and NaN are no warning.
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                dev = _state_norm(xs[k] - base, sc)
                excess = dev / (dev[0] * allow)
            bad = ~(excess <= self.growth)
            ratio = max(ratio, float(np.nanmax(np.where(np.isfinite(excess), excess, np.inf))))
            if bad.any():
                first[j] = np.argmax(bad)
        return first, ratio

    def judge(self, meth, lanes, h, settle: bool = False) -> tuple[Outcome, Diagnosis]:
        """The outcomes (N,) of candidates h (N,) [s] at lanes (N,) and their diagnosis. A
        candidate whose solves failed inside its horizon runs again with RETRY_ITERATIONS
        times the Newton iterations: where that converges, the solve needed more iterations
        (it is judged by that run, `retried`); where not, the solver failed.

        With `settle` (the limit search's probes), the unperturbed run and the MODES mode
        directions run first, and a candidate they show not stable is settled by them: for
        a method that solves nothing, a run past `growth`; for any, a solve that failed
        also when retried. Its outcome (stable, converged) is then the whole test's; its
        failure time and diagnosis are of those runs alone."""
        lanes, h = np.asarray(lanes), np.asarray(h, float)
        N, K = len(h), self.delta.shape[1]
        n_own = self.steps(h)
        stable, t_fail, converged = np.zeros(N, bool), np.full(N, np.nan), np.zeros(N, bool)
        state, ratio = np.full(N, -1), np.zeros(N)
        todo = list(range(N))
        xs: dict = {}           # (candidate, direction) -> its run
        cs: dict = {}           # (candidate, direction) -> whether its solves converged
        if settle and K > MODES:
            todo, xs, cs = self._settle(meth, lanes, h, n_own, converged, t_fail)
        # The candidates not settled: every run (those already made stand), and the retry.
        rest = [(i, k) for i in todo for k in range(-1, K) if (i, k) not in xs]
        x, conv = self._runs(meth, lanes, h, n_own, rest)
        xs = {(i, k): xs.get((i, k)) for i in todo for k in range(-1, K)} | dict(zip(rest, x))
        cs = {(i, k): cs.get((i, k)) for i in todo for k in range(-1, K)} | dict(zip(rest, conv))
        retried = self._retried(meth, lanes, h, n_own, xs, cs)
        t0 = time.perf_counter()
        for i in todo:
            base = xs[i, -1]
            converged[i] = all(cs[i, k] for k in range(-1, K))
            first, ratio[i] = self._first_failures(lanes[i], h[i],
                                                   {k: xs[i, k] for k in range(-1, K)},
                                                   list(range(K)))
            k = int(np.argmin(first))
            if first[k] < len(base):
                j = first[k]
                t_fail[i] = j * h[i]
                with np.errstate(invalid="ignore"):
                    d = np.abs(xs[i, k][j] - base[j]) / self.scales[lanes[i]]
                # A failed solve's NaN names no state.
                state[i] = int(np.argmax(np.where(np.isfinite(d), d, np.inf))) \
                    if converged[i] else -1
            stable[i] = first[k] == len(base) and converged[i]
        self.runner.watch.add("stability_s", time.perf_counter() - t0)
        ref = np.nanmax(self.ref_growth[lanes], axis=(1, 2), initial=1.0)
        return (Outcome(stable, t_fail, converged),
                Diagnosis(state, t_fail, ratio, ref, retried))

    def _settle(self, meth, lanes, h, n_own, converged, t_fail) -> tuple[list[int], dict, dict]:
        """The unperturbed run and the MODES mode directions of every candidate, and the
        candidates they settle (judge's `settle`) marked in `converged` and `t_fail`: the
        candidates left, and those runs (before any retry) with their convergence."""
        early = [(i, k) for i in range(len(h)) for k in range(-1, MODES)]
        x, conv = self._runs(meth, lanes, h, n_own, early)
        xs, cs = dict(zip(early, x)), dict(zip(early, conv))
        first_xs, first_cs = dict(xs), dict(cs)
        self._retried(meth, lanes, h, n_own, first_xs, first_cs)
        left = []
        for i in range(len(h)):
            runs = {k: first_xs[i, k] for k in range(-1, MODES)}
            if not all(first_cs[i, k] for k in range(-1, MODES)):
                continue                    # a solve failed, also retried: settled
            if not meth.solves:
                first, _ = self._first_failures(lanes[i], h[i], runs, list(range(MODES)))
                if first.min() < len(runs[-1]):
                    converged[i], t_fail[i] = True, first.min() * h[i]
                    continue                # a run grew past `growth`: settled
            left.append(i)
        return left, xs, cs


def reference_growth(solve, points, base: np.ndarray, delta: np.ndarray,
                     scales: np.ndarray) -> np.ndarray:
    """(B, K, T) the reference's own growth of each deviation delta (B, K, d): the distance in
    the state norm of its solution from points' initial states plus delta[:, k] to `base`
    (B, T, d, the reference from the initial states), over its start, the largest so far at
    each of the T times; NaN where that reference failed. solve(points) -> Solution."""
    import dataclasses
    B, K, _ = delta.shape
    out = np.full((B, K, base.shape[1]), np.nan)
    for k in range(K):
        ref = solve(dataclasses.replace(points, x0=points.x0 + delta[:, k]))
        dev = _state_norm(ref.x - base, scales[:, None, :])
        with np.errstate(invalid="ignore", divide="ignore"):
            grow = np.fmax.accumulate(dev / dev[:, :1], axis=1)
        out[:, k] = np.where(ref.ok[:, None], grow, np.nan)
    return out
