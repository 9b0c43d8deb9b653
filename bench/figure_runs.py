"""The sweep's figure runs (Figures 1-2: each method at fractions of its predicted limit and
one past it, and the reference) at an operating point other than the one it ran them at, as
rows of trajectories.parquet, computed by the sweep's own code."""
from __future__ import annotations

import dataclasses

import pandas as pd

from stepzoo.bench import schema
from stepzoo.bench.sweep import _trajectory_rows, _Work


def trajectories_at(cfg, point) -> pd.DataFrame:
    """trajectories.parquet's rows of the sweep config `cfg` with its trajectory point
    replaced by `point` (one value per envelope variable, in their order)."""
    cfg = dataclasses.replace(cfg, traj_point=tuple(float(v) for v in point))
    work = _Work(cfg, 0, {})
    t, ref = work.trajectory_reference()
    frames = [_trajectory_rows(cfg.spec, "reference", t[1] - t[0], t, ref, False)]
    frames += [work._trajectories(cfg.method(name)) for name in cfg.methods]
    table = pd.concat(frames, ignore_index=True)
    return table.sort_values(schema.SORT["trajectories"], kind="stable", ignore_index=True)
