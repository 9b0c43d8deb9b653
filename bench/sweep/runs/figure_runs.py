"""The sweep's figure runs (Figures 1-2): at the trajectory point, each method at fractions of
its predicted limit and one past it, as rows of trajectories.parquet."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from stepzoo.bench.model import frozen_jacobian as frozen
from stepzoo.bench.sweep.block import ALONG_SAMPLES, TRAJ_SAMPLES

TRAJ_ROWS = 2000       # states kept of one figure run (evenly spread over it)


def figure_rows(n: int) -> np.ndarray:
    """Which of a figure run's n states the trajectories table keeps: all up to TRAJ_ROWS,
    else TRAJ_ROWS evenly spread from the first to the last (a figure shows no more, and
    an explicit method on a stiff problem takes millions of steps)."""
    return np.unique(np.linspace(0, n - 1, min(n, TRAJ_ROWS)).round().astype(int))


def trajectory_rows(spec, name, h, t, x, past_limit) -> pd.DataFrame:
    """Rows of trajectories.parquet: states x (T, d) at times t (T,) [s] of a run of step h."""
    df = pd.DataFrame(x, columns=list(spec.states))
    df.insert(0, "t", t)
    df.insert(0, "h", float(h))
    df.insert(0, "method", name)
    df["past_limit"] = past_limit
    return df


def reference_rows(block) -> pd.DataFrame:
    """The reference's rows at the trajectory point of a block (bench.sweep.block.Block)."""
    t, ref = block.trajectory_reference()
    return trajectory_rows(block.spec, "reference", t[1] - t[0], t, ref, False)


def method_rows(block, meth) -> pd.DataFrame:
    """The method's figure runs from the trajectory point: fractions of the predicted limit
    (of the largest grid step for A-stable methods) and one past it."""
    cfg, watch = block.cfg, block.watch
    t, ref = block.trajectory_reference()
    points = block.trajectory_points()
    every = TRAJ_SAMPLES // ALONG_SAMPLES
    with watch.clock("metrics_s"):
        jac = frozen.jacobians(block.spec.rhs, t[::every],
                               np.repeat(ref[None, ::every], len(points), 0), points.u,
                               points.p)
    limit = frozen.predicted_limit(meth, frozen.eigenvalues(jac[0]))[0]
    base = limit if math.isfinite(limit) else cfg.hs[-1]
    hs = [max(f * base, cfg.hs[0]) for f in cfg.trajectories.fractions]
    past = [False] * len(hs)
    if math.isfinite(limit) and limit > 0:
        hs.append(cfg.trajectories.past_limit * limit)
        past.append(True)
    frames, lanes = [], len(points)
    for start in range(0, len(hs), lanes):
        chunk = hs[start: start + lanes]
        h = np.array(chunk + [chunk[-1]] * (lanes - len(chunk)))
        n = min(block.run.max_steps, math.ceil(cfg.horizon / h.min() - 1e-9))
        run = block.run(meth, points.x0, points.u, points.p, h, n)
        watch.add("metrics_s", run.run_s)
        for k, hk in enumerate(chunk):
            rows = figure_rows(min(n, math.floor(cfg.horizon / hk + 1e-9)) + 1)
            frames.append(trajectory_rows(block.spec, meth.name, hk, hk * rows,
                                          run.x[k, rows], past[start + k]))
    return pd.concat(frames, ignore_index=True)
