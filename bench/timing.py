"""Repeated timing of one computation, summarised as pytest-benchmark summarises its rounds:
the minimum (the least-disturbed run; work-precision diagrams plot it, the DiffEqDevTools
convention), the median, the largest and the interquartile range, all per step [s]."""
from __future__ import annotations

import numpy as np

# The `runs` table's timing columns (time_per_step_s, the minimum, is the original one).
COLUMNS = ("time_per_step_s", "time_per_step_median_s", "time_per_step_max_s",
           "time_per_step_iqr_s", "timing_rounds")
MEASURED = COLUMNS[:-1]    # wall-clock columns: two runs of one config never agree on them


def per_step(walls, steps: int) -> dict:
    """The timing columns of `walls`, the wall times [s] of repeated identical calls that
    each take `steps` steps (all lanes together)."""
    t = np.asarray(walls, dtype=float) / steps
    q1, median, q3 = np.percentile(t, [25, 50, 75])
    return {"time_per_step_s": float(t.min()), "time_per_step_median_s": float(median),
            "time_per_step_max_s": float(t.max()), "time_per_step_iqr_s": float(q3 - q1),
            "timing_rounds": len(t)}
