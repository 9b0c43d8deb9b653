"""A sweep's wall time, estimated before it starts from a short calibration on its first block
of points: the references, Jacobians and stability references that every method's chunk
shares (computed into the sweep's own cache, so the sweep reuses them), and per method its
compiling call (the sweep's program, which JAX then keeps) and timed calls that give a call's
fixed cost and its cost per step. The calls a chunk makes are counted as the sweep would make
them: the accuracy runs and timing rounds from the config, the stability probes by a dry run
of the limit search whose probe answers from the predicted limits (no run). The calibration
runs, and the sweep's chunks are scheduled, on the sweep's worker threads as the sweep runs
them (engine.jobs, distributed.threaded): the estimate is their schedule's length."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import partial

import numpy as np

from stepzoo.bench.sweep import distributed, limit_search
from stepzoo.bench.sweep.block import Block
from stepzoo.bench.timing import compile_clock
from stepzoo.bench.timing.rounds import CALIBRATION_STEPS

# The dry run's stand-in for a lane's measured limit: this fraction above its predicted one.
# Growth past `growth` takes steps to show, so a measured limit lies a little above the
# linear one even where the prediction holds; a stand-in at the prediction itself would end
# the narrowing at its first probe, which a real search never does.
STAND_IN = 0.01


@dataclass(frozen=True)
class Estimate:
    """total_s: the sweep's estimated wall time [s], calibration_s of it already spent;
    shared_s: per block past the first, the references and Jacobians (their compiling
    done); per method {compile_s, call_s, step_s, calls, steps, ...} of one chunk; workers:
    the threads the chunks are computed on."""
    total_s: float
    calibration_s: float
    shared_s: float
    methods: dict
    workers: int = 1

    def record(self) -> dict:
        """The manifest's "estimate"."""
        return {"total_s": round(self.total_s, 3), "calibration_s": round(self.calibration_s, 3),
                "shared_per_block_s": round(self.shared_s, 3), "workers": self.workers,
                "methods": {m: {k: round(v, 6) if isinstance(v, float) else v
                                for k, v in c.items()} for m, c in self.methods.items()}}

    def says(self) -> str:
        slow = max(self.methods.items(), key=lambda kv: kv[1]["chunk_s"], default=None)
        most = f"; slowest method {slow[0]} ({slow[1]['chunk_s']:.3g} s a chunk)" if slow else ""
        on = f" on {self.workers} threads" if self.workers > 1 else ""
        return (f"estimated wall time {self.total_s:.3g} s{on} (calibrated in "
                f"{self.calibration_s:.3g} s on the first block{most})")


def estimate(cfg, cache: dict, blocks: int, workers: int = 1) -> Estimate:
    """The wall time of a sweep of `cfg` in `blocks` blocks on `workers` threads, calibrated
    on block 0 into `cache` (the dict the sweep's chunks then read), on those threads."""
    started = time.perf_counter()

    def shared():
        block = Block(cfg, 0, cache)
        with compile_clock.split() as took:
            block.along()
            for h in cfg.hs:
                block.accuracy_reference(h)
            block.nonsmooth()
            if cfg.stability.rule != "blowup":
                block.modal()
        yield "", took["wall"] - took["compile"]

    # Each method with its own block (its own stopwatch), sharing the cache: every program
    # compiled first, then the calls timed, so that no timed call waits on another thread's
    # tracing or compiling (which held a one-step call up to 0.7 s).
    own = {name: Block(cfg, 0, cache) for name in cfg.methods}
    compiled = dict(distributed.threaded(
        [shared, *(lambda name=name: _compile(own[name], cfg.method(name), name)
                   for name in cfg.methods)], workers))
    shared_s = compiled.pop("")

    def timing(name: str):
        yield name, _method(own[name], cfg.method(name), compiled[name])

    got = dict(distributed.threaded([partial(timing, name) for name in cfg.methods], workers))
    methods = {name: got[name] for name in cfg.methods}
    calibration = time.perf_counter() - started
    # Block 0's shared work and compiling are done; the rest is the chunks' runs, and the
    # other blocks' shared work (their references cost what block 0's did, compiling aside),
    # in the jobs the sweep gives its threads (engine.jobs: the references first, then the
    # methods, the longest first), each thread taking the next job as it finishes its own.
    # The last block's padding lanes are not probed: its stability work is its real lanes'.
    padding = 1.0 - (len(cfg.points) - (blocks - 1) * cfg.chunks.points) / cfg.chunks.points
    per_method = {name: blocks * m["chunk_s"] - (padding if blocks > 1 else 0.0)
                  * m["stability_s"] for name, m in methods.items()}
    order = sorted(per_method, key=lambda name: -methods[name]["chunk_s"])
    total = calibration + schedule([(blocks - 1) * shared_s, *(per_method[n] for n in order)],
                                   workers)
    return Estimate(total, calibration, shared_s, methods, workers)


def schedule(durations, workers: int) -> float:
    """The length [s] of jobs of these durations [s] taken in order by `workers` threads,
    each taking the next job as it finishes its own (distributed.threaded)."""
    ends = [0.0] * max(1, workers)
    for d in durations:
        ends[int(np.argmin(ends))] += d
    return max(ends)


def _compile(block: Block, meth, name: str):
    """(name, the wall time [s] of the method's compiling call), as the chunk makes it, and
    its stability probe's at the grid's middle step, once the shared work it needs (which
    another thread may be computing) is there."""
    cfg, pts = block.cfg, block.points
    t0 = time.perf_counter()
    block.run(meth, pts.x0, pts.u, pts.p, cfg.hs[0], 1)
    compile_s = time.perf_counter() - t0
    block.along()
    block.stability_runs()
    block.stable(meth, np.full((len(pts), 1), cfg.hs[len(cfg.hs) // 2]))
    yield name, compile_s


def _method(block: Block, meth, compile_s: float) -> dict:
    """A method's calibration, its programs compiled (`compile_s` [s] its compiling call),
    and its chunk's counted calls and steps."""
    cfg, pts = block.cfg, block.points
    # The cost per step from the sweep's longest call (the grid's smallest step, most of a
    # chunk's steps; long enough that one call of it is timed), past the fixed cost of a
    # call of one step.
    h = cfg.hs[0]
    n = max(2, block.run.max_steps)
    one = _timed(block, meth, h, 1)
    many = _timed(block, meth, h, n, rounds=1)
    step_s = max(0.0, (many - one) / (n - 1))
    call_s = max(0.0, one - step_s)
    calls, steps, run_steps, predict_s, stab_calls, stab_steps = _chunk_work(block, meth)
    # What a stability probe costs besides its calls (judging each run, step by step, in
    # Python), per step of a run, from one probe of the block's lanes at the grid's middle
    # step.
    B, h = len(pts), cfg.hs[len(cfg.hs) // 2]
    c, s, r = _probe_work(cfg, block.run.max_steps, B, np.full(B, h))
    t0, compiled = time.perf_counter(), block.watch.seconds["compile_s"]
    block.stable(meth, np.full((B, 1), h))
    # Less any compiling in it (the libm fallback's, should an argument reach the bound).
    compiled = block.watch.seconds["compile_s"] - compiled
    probe_s = time.perf_counter() - t0 - compiled
    judge_s = max(0.0, probe_s - c * call_s - s * step_s) / r
    stability_s = stab_calls * call_s + stab_steps * step_s + run_steps * judge_s
    return {"compile_s": compile_s, "call_s": call_s,
            "step_s": step_s, "calls": calls,
            "steps": steps, "run_steps": run_steps, "judge_s": judge_s,
            "predict_s": predict_s, "stability_s": stability_s,
            "chunk_s": (calls - stab_calls) * call_s + (steps - stab_steps) * step_s
            + stability_s + predict_s}


def _timed(block, meth, h: float, n: int, rounds: int = 3) -> float:
    """The median wall time [s] of `rounds` calls of n steps of h [s] on the block's lanes:
    the sweep's calls meet the machine as it is, not at its least busy."""
    pts = block.points
    walls = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        block.run(meth, pts.x0, pts.u, pts.p, h, n)
        walls.append(time.perf_counter() - t0)
    return float(np.median(walls))


def _chunk_work(block: Block, meth) -> tuple[int, int, int, float, int, int]:
    """(calls, steps per call summed, the stability runs' steps summed, the prediction's
    time [s], the stability probes' calls and their steps) of one chunk of `meth` on block
    0: its compiling call, the accuracy runs, the timing rounds, the figure runs, and the
    stability probes of a dry run of the limit search (stable up to STAND_IN above the
    predicted limit) in the calls the configured rule packs them in."""
    cfg = block.cfg
    n_acc = [round(cfg.horizon / h) for h in cfg.hs]
    j = int(np.argmin(np.abs(np.array(n_acc) - CALIBRATION_STEPS)))   # the timed run
    # The chunk's compiling call (one step), the accuracy runs and the timing rounds.
    calls = 1 + len(n_acc) + cfg.timing.rounds - 1
    steps = 1 + sum(n_acc) + (cfg.timing.rounds - 1) * n_acc[j]
    t0 = time.perf_counter()
    pred = np.array([p.h for p in block.predicted(meth)])      # the chunk computes it too
    predict_s = time.perf_counter() - t0
    # (candidates [s], which the search's probe settles early, whose unperturbed run the
    # accuracy runs made)
    asked = []
    modes = cfg.stability.rule != "blowup"
    settles = modes and not meth.solves
    made = {h for h, n in zip(cfg.hs, n_acc)
            if modes and n == _steps(cfg, h, block.run.max_steps)}

    def probe(lanes, hs, search=True):
        lanes, hs = np.asarray(lanes), np.asarray(hs, float)
        ok = hs <= pred[lanes] * (1 + STAND_IN)
        asked.append((hs, ~ok if search and settles else np.zeros(len(hs), bool),
                      np.array([not search and h in made for h in hs], bool)))
        return limit_search.Outcome(ok, np.where(ok, np.nan, hs), np.ones(len(hs), bool))

    n = block.points.n_real                   # the padding lanes are not probed
    grid = limit_search.at_steps(lambda lanes, hs: probe(lanes, hs, search=False),
                                 np.arange(n), np.tile(np.asarray(cfg.hs), (n, 1)).T)
    measured = limit_search.measured_limit(grid, probe, cfg.hs, pred[:n], block.h_top,
                                           cfg.stability.rel_tol, len(block.points),
                                           ladder=cfg.stability.rule != "blowup")
    if cfg.stability.rule != "blowup":         # the diagnosis probes just above each limit
        h = measured.h_meas * (1 + cfg.stability.rel_tol)
        h = h[np.isfinite(h) & (h > 0)]
        asked.append((h, np.zeros(len(h), bool), np.zeros(len(h), bool)))
    stab_calls, stab_steps, run_steps, B = 0, 0, 0, len(block.points)
    for hs, settled, known in asked:
        c, s, r = _probe_work(cfg, block.run.max_steps, B, hs, settled, known)
        stab_calls, stab_steps, run_steps = stab_calls + c, stab_steps + s, run_steps + r
    c, s = _figure_work(cfg, block.run.max_steps, B, pred[0])
    return (calls + c + stab_calls, steps + s + stab_steps, run_steps, predict_s, stab_calls,
            stab_steps)


def _figure_work(cfg, max_steps: int, B: int, limit: float) -> tuple[int, int]:
    """(calls, steps) of the figure runs (runs.figure_runs.method_rows), with the first
    lane's predicted limit standing in for the trajectory point's."""
    base = limit if math.isfinite(limit) else cfg.hs[-1]
    hs = [max(f * base, cfg.hs[0]) for f in cfg.trajectories.fractions]
    runs = len(hs) + (1 if math.isfinite(limit) and limit > 0 else 0)
    calls = -(-runs // B)
    return calls, calls * min(max_steps, math.ceil(cfg.horizon / min(hs) - 1e-9))


def _steps(cfg, h: float, max_steps: int) -> int:
    """The steps of a "modes" stability run at h [s] (ModalRuns.steps)."""
    return min(math.ceil(cfg.stability_horizon / h - 1e-9), max_steps)


def _probe_work(cfg, max_steps: int, B: int, hs: np.ndarray, settled=None, known=None
                ) -> tuple[int, int, int]:
    """(calls, steps of the calls, steps of the runs) of one probe of candidates hs [s]: the
    "blowup" rule runs each candidate twice for `stability.steps`, in calls of B; the
    "modes" rule runs each with its directions, to the stability horizon, in calls of B
    runs, each call as long as its longest run; a candidate `settled` (a search's probe that
    finds it not stable, ModalRuns.judge) runs the unperturbed state and the modes alone,
    one whose unperturbed run is `known` (a grid step's accuracy run) runs its directions."""
    from stepzoo.bench.sweep.runs.stability_runs import MODES
    if cfg.stability.rule == "blowup":
        calls = 2 * math.ceil(len(hs) / B)
        return calls, calls * cfg.stability.steps, 2 * len(hs) * cfg.stability.steps
    n = np.minimum(np.ceil(cfg.stability_horizon / hs - 1e-9), max_steps).astype(int)
    d = len(cfg.spec.states)
    # Each of the MODES modes and each state alone (stability_runs.directions), and the
    # unperturbed run: where the probe may settle, the modes' runs first, then the others'.
    settled = np.zeros(len(hs), bool) if settled is None else np.asarray(settled, bool)
    known = np.zeros(len(hs), bool) if known is None else np.asarray(known, bool)
    own = np.where(known, MODES + d, MODES + d + 1)
    groups = [np.repeat(n, own)] if not settled.any() else \
        [np.repeat(n, MODES + 1), np.repeat(n[~settled], d)]
    longest = [int(runs[i: i + B].max()) for runs in groups for i in range(0, len(runs), B)]
    return len(longest), sum(longest), int(sum(runs.sum() for runs in groups))
