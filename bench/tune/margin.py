"""The stability margin, one rule for `tune` and `verdict`: a step h [s] is stable with margin
at an operating point when the sweep's blow-up test calls it stable there and h <= (1 -
margin) x h_meas, the measured largest stable step [s] at that point."""
from __future__ import annotations

import math

import numpy as np

def stable_with_margin(stable, h, h_meas, margin: float):
    """Where a stable step h [s] keeps `margin` (a fraction) below h_meas [s]; scalars or
    arrays alike."""
    with np.errstate(invalid="ignore"):
        return np.logical_and(stable, np.asarray(h) <= (1.0 - margin) * np.asarray(h_meas))


def percent_below(h: float, h_meas: float) -> str:
    """How far h is below h_meas, as a percentage of h_meas ('18%')."""
    if not math.isfinite(h_meas) or h_meas <= 0:
        return "-"
    return f"{100.0 * (1.0 - h / h_meas):.2g}%"
