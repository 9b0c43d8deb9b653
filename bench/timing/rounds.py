"""Repeated timing of one computation, summarised as pytest-benchmark summarises its rounds:
the minimum (the least-disturbed run; work-precision diagrams plot it, the DiffEqDevTools
convention), the median, the largest and the interquartile range, all per step [s]; and a
sweep's pricing of every run of a method by one calibrated run of it."""
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


# Steps of the run that prices a method's runs in a sweep (see `calibrated`): enough that the
# call's fixed cost is a small part of its time, few enough that its rounds cost little.
CALIBRATION_STEPS = 200
RULE = (f"a method's runs are priced by one of them, its grid run nearest {CALIBRATION_STEPS} "
        "steps, timed in timing_rounds calls after compilation: a run's time per step is that "
        "run's (the fastest round; the median, largest and IQR alike) times the run's "
        "right-hand-side evaluations per step over that run's, of the busiest lane (an "
        "implicit method's Newton iterations run in lockstep; 1 for an explicit method)")


def busiest_per_step(evals, steps: int) -> float:
    """Right-hand-side evaluations per step of the batch's busiest lane (evals (B,) over
    `steps` steps): an implicit method's Newton iterations run in lockstep over a batch, so
    its slowest lane sets the batch's time."""
    return float(np.nanmax(np.asarray(evals, float))) / steps if steps else float("nan")


def calibrated(walls, steps: int, work: float) -> dict:
    """The timing columns of a run priced by its method's calibration: `walls` [s] are the
    repeated calls of one run of the method that each take `steps` steps (all lanes
    together), and `work` the run's evaluations per step over that run's
    (`busiest_per_step`): 1 for an explicit method, the Newton iterations' ratio for an
    implicit one."""
    cols = per_step(walls, steps)
    for key in MEASURED:
        cols[key] *= work
    return cols
