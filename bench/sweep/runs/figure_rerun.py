"""The sweep's figure runs (Figures 1-2: each method at fractions of its predicted limit and
one past it, and the reference) at an operating point other than the one it ran them at, as
rows of trajectories.parquet, computed by the sweep's own code."""
from __future__ import annotations

import pandas as pd

from stepzoo.bench.sweep import tables as schema
from stepzoo.bench.sweep.runs import figure_runs as trajectory_runs
from stepzoo.bench.sweep.block import Block


def trajectories_at(cfg, point) -> pd.DataFrame:
    """trajectories.parquet's rows of the sweep config `cfg` with its trajectory point
    replaced by `point` (one value per envelope variable, in their order)."""
    cfg = cfg.changed(trajectories=cfg.trajectories.at(dict(zip(cfg.spec.variables, point))))
    block = Block(cfg, 0, {})
    frames = [trajectory_runs.reference_rows(block)]
    frames += [trajectory_runs.method_rows(block, cfg.method(name)) for name in cfg.methods]
    table = pd.concat(frames, ignore_index=True)
    return table.sort_values(schema.SORT["trajectories"], kind="stable", ignore_index=True)
