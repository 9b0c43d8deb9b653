"""One block of a sweep config's operating points and what its chunks share: the lanes, the
references along them (kept in a cache for the next method's chunk), the frozen Jacobians
that predict each method's stable step, and the stability test and limit search at them."""
from __future__ import annotations

import threading
from typing import NamedTuple

import numpy as np

from stepzoo.bench.model import frozen_jacobian as frozen
from stepzoo.bench.sweep import limit_search
from stepzoo.bench.model import nonsmooth
from stepzoo.bench.sweep import reference as reference_backend
from stepzoo.bench.sweep.limit_search import MeasuredLimit, Outcome
from stepzoo.bench.sweep.runs.method_runs import Runner
from stepzoo.bench.sweep.points import Points
from stepzoo.bench.sweep.runs.stability_runs import (Diagnosis, ModalRuns, StabilityRuns,
                                                     directions, perturbation, reference_growth,
                                                     state_scales)
from stepzoo.bench.timing.chunk_stopwatch import Stopwatch
from stepzoo.bench.sweep.config import run_steps

TRAJ_SAMPLES = 200     # reference samples of the figure trajectory
ALONG_SAMPLES = 50     # reference samples whose Jacobians predict the stable step (divides
                       # TRAJ_SAMPLES: the figure trajectory's prediction reuses the shape)


class Along(NamedTuple):
    """The reference over the horizon at ALONG_SAMPLES + 1 times ts (T,) [s]: states xs
    (B, T, d), eigenvalues lam (B, T, d) [1/s] and Jacobians jac (B, T, d, d) of f there."""
    ts: np.ndarray
    xs: np.ndarray
    lam: np.ndarray
    jac: np.ndarray


class Predicted(NamedTuple):
    """A lane's predicted largest stable step h [s] (frozen.predicted_limit), and the time
    index k and eigenvalue index j where it binds (-1 where nothing does)."""
    h: float
    k: int
    j: int


class Block:
    """Block `block` of cfg's points (bench.sweep.points.Points). `cache` (any dict) keeps the
    references of a block for the next chunk in the same process; `watch` gets the time;
    max_steps (default: the grid's longest run or a stability run) sizes every call."""

    def __init__(self, cfg, block: int, cache: dict, watch: Stopwatch | None = None,
                 max_steps: int | None = None):
        self.cfg, self.block, self.cache = cfg, block, cache
        self.spec = cfg.spec
        self.points = Points.block(cfg, block)
        self.watch = Stopwatch() if watch is None else watch
        self.reference_backend = reference_backend.choose(cfg)
        steps = run_steps(cfg) if max_steps is None else max_steps
        self.run = Runner(cfg.spec, steps, self.watch)

    def cached(self, key, make):
        """make(), computed once per (key, block) in the cache: a chunk computed on another
        thread (bench.sweep.distributed.threaded) that needs it meanwhile waits for it."""
        key = (key, self.block)
        if key not in self.cache:
            with self.cache.setdefault(("lock", key), threading.Lock()):
                if key not in self.cache:
                    self.cache[key] = make()
        return self.cache[key]

    def reference(self, h: float, n: int, points: Points | None = None):
        """The reference (reference_backend.Solution) at t = k h [s], k = 0..n, of the block's
        lanes, or of `points`."""
        return self.reference_backend.solve(self.points if points is None else points, h, n,
                                            self.watch)

    def accuracy_reference(self, h: float):
        """The reference of the accuracy runs of step h [s] over the horizon, cached."""
        n = round(self.cfg.horizon / h)
        return self.cached(("accuracy", h), lambda: self.reference(h, n))

    # -- prediction ------------------------------------------------------------------------
    def along(self) -> Along:
        """The frozen Jacobians along each lane's reference that predict the step."""
        def make():
            dt = self.cfg.horizon / ALONG_SAMPLES
            ts = dt * np.arange(ALONG_SAMPLES + 1)
            xs = self.reference(dt, ALONG_SAMPLES).x
            with self.watch.clock("metrics_s"):
                jac = frozen.jacobians(self.spec.rhs, ts, xs, self.points.u, self.points.p)
            return Along(ts, xs, frozen.eigenvalues(jac), jac)
        return self.cached("along", make)

    def nonsmooth(self) -> list:
        """Per lane, where f is not smooth along its reference at the smallest grid step
        (bench.nonsmooth; none where that reference failed)."""
        def make():
            h = self.cfg.hs[0]
            ref = self.accuracy_reference(h)
            with self.watch.clock("metrics_s"):
                return nonsmooth.detect(self.spec.rhs, h * np.arange(ref.x.shape[1]),
                                        np.where(ref.ok[:, None, None], ref.x, np.nan),
                                        self.points.u, self.points.p, self.spec.states,
                                        self.spec.inputs, self.cfg.reference.rtol,
                                        self.cfg.reference.atol)
        return self.cached("nonsmooth", make)

    def predicted(self, meth) -> list[Predicted]:
        """Per lane, the method's predicted limit along the lane's reference."""
        lam = self.along().lam
        with self.watch.clock("metrics_s"):
            return [Predicted(*frozen.predicted_limit(meth, lam[b]))
                    for b in range(len(self.points))]

    # -- stability -------------------------------------------------------------------------
    @property
    def delta(self) -> np.ndarray:
        """(B, d) the stability runs' initial deviation (stability_runs.perturbation)."""
        return self.cached("perturbation", lambda: perturbation(
            self.spec, self.along().jac[:, 0], self.cfg.stability.perturbation))

    def modal(self) -> tuple:
        """The "modes" rule's (deviations (B, K, d), state scales (B, d), times ts (T,) [s],
        the reference's running-largest growth (B, K, T) of each deviation there), over the
        stability horizon (stability_runs.MODES_RULE)."""
        def make():
            cfg = self.cfg
            T = cfg.stability_horizon
            dt = T / ALONG_SAMPLES
            base = self.along().xs if T == cfg.horizon else \
                self.reference(dt, ALONG_SAMPLES).x
            scales = state_scales(self.spec, base)
            delta = directions(self.along().jac[:, 0], scales, cfg.stability.perturbation,
                               self.points.lanes)
            grow = reference_growth(lambda pts: self.reference(dt, ALONG_SAMPLES, pts),
                                    self.points, base, delta, scales)
            return delta, scales, dt * np.arange(ALONG_SAMPLES + 1), grow
        return self.cached("modal", make)

    def stability_runs(self, made: dict | None = None):
        """The stability test of the config's [stability] rule; under the "modes" rule with
        the runs `made` from the initial states ({(method, h [s]): (states (B, n+1, d),
        converged (B,))}), which stand in for its unperturbed runs as long."""
        cfg = self.cfg
        if cfg.stability.rule == "blowup":
            return StabilityRuns(self.run, self.points, self.delta, cfg.stability.steps,
                                 cfg.stability.growth)
        delta, scales, ts, grow = self.modal()
        return ModalRuns(self.run, self.points, delta, scales, ts, grow, cfg.stability_horizon,
                         cfg.stability.growth, made or {})

    def diagnose(self, meth, h_meas) -> Diagnosis:
        """Per lane, what fails just above its measured limit h_meas (B,) [s] (at the grid's
        smallest step where nothing was stable; nothing where nothing failed): the "modes"
        rule's diagnosis, NaN/-1 under the "blowup" rule. The padding lanes copy the last
        real one's."""
        B = len(self.points)
        none = Diagnosis(np.full(B, -1), np.full(B, np.nan), np.full(B, np.nan),
                         np.full(B, np.nan), np.zeros(B, bool))
        runs = self.stability_runs()
        if not isinstance(runs, ModalRuns):
            return none
        h = np.where(h_meas > 0, h_meas * (1 + self.cfg.stability.rel_tol), self.cfg.hs[0])
        lanes = np.where(np.isfinite(h[: self.points.n_real]))[0]
        out = Diagnosis(*(a.copy() for a in none))
        if len(lanes):
            found = runs.judge(meth, lanes, h[lanes])[1]
            for name, col in zip(Diagnosis._fields, found):
                getattr(out, name)[lanes] = col
        out.ref_growth[:] = np.nanmax(runs.ref_growth, axis=(1, 2))
        return Diagnosis(*(self.padded(a) for a in out))

    def padded(self, a: np.ndarray) -> np.ndarray:
        """Rows per lane (B, ...) from a's rows of the real lanes (its first n_real): the
        padding lanes repeat the last point, so their answers are a copy of its."""
        n = self.points.n_real
        return np.concatenate([a[:n], np.repeat(a[n - 1: n], len(self.points) - n, 0)])

    @property
    def h_top(self) -> float:
        """The largest step worth a stability probe [s]: stability.h_probe_max, and under the
        "modes" rule at most the stability horizon (a longer step is one step of a run: no
        growth can show), but never below the grid's largest step."""
        cfg = self.cfg
        if cfg.stability.rule == "blowup":
            return cfg.stability.h_probe_max
        return max(min(cfg.stability.h_probe_max, cfg.stability_horizon), cfg.hs[-1])

    def stable(self, meth, H, made: dict | None = None) -> Outcome:
        """Outcomes (B, K) of the stability runs at steps H (B, K) [s], row b at lane b, with
        the runs already `made` from the initial states (`stability_runs`); the real lanes
        are probed, the padding lanes copy the last real one's."""
        n = self.points.n_real
        got = limit_search.at_steps(self.stability_runs(made).probe(meth), np.arange(n),
                                    np.asarray(H, float)[:n].T)
        return Outcome(*(self.padded(a) for a in got))

    def measured_limits(self, meth, grid: Outcome, pred) -> MeasuredLimit:
        """The largest stable step per lane [s] and its cause (limit_search.measured_limit)
        from the outcomes grid (B, K) at the config's steps, guided by the predicted limits
        pred (B,) [s]: searched on the real lanes, copied to the padding lanes."""
        cfg, n = self.cfg, self.points.n_real
        runs = self.stability_runs()
        # The search needs no more of a candidate than that it is not stable (ModalRuns.judge).
        probe = runs.probe(meth, settle=True) if isinstance(runs, ModalRuns) else \
            runs.probe(meth)
        found = limit_search.measured_limit(
            Outcome(*(a[:n] for a in grid)), probe, cfg.hs,
            np.asarray(pred, float)[:n], self.h_top, cfg.stability.rel_tol, len(self.points),
            ladder=cfg.stability.rule != "blowup")
        return MeasuredLimit(*(self.padded(a) for a in found))

    # -- the figure trajectory --------------------------------------------------------------
    def trajectory_points(self) -> Points:
        """The trajectory point in every lane (the batch keeps its compiled shape)."""
        return Points.repeated(self.spec, self.cfg.trajectories.point, len(self.points))

    def trajectory_reference(self):
        """(times (TRAJ_SAMPLES+1,) [s], reference states (TRAJ_SAMPLES+1, d)) at the
        trajectory point."""
        def make():
            dt = self.cfg.horizon / TRAJ_SAMPLES
            ref = self.reference(dt, TRAJ_SAMPLES, self.trajectory_points()).x
            return dt * np.arange(TRAJ_SAMPLES + 1), ref[0]
        return self.cached("trajectory", make)
