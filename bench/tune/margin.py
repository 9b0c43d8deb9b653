"""The stability margin, one rule for `tune`, `verdict` and the report: a step h [s] is stable
with margin at an operating point when the sweep's stability test calls it stable there and
h <= (1 - margin) x the point's limit, the smaller of h_meas (the measured largest stable step
[s]) and h_pred (the frozen-Jacobian prediction along the trajectory [s]). A measurement can
miss a bounded instability (a saturating force turns it into chatter), a prediction cannot:
only the flag BEYOND_PREDICTED (its name states the risk) drops h_pred from the rule."""
from __future__ import annotations

import math

import numpy as np

BEYOND_PREDICTED = "--allow-beyond-predicted-limit"


def limit(h_meas, h_pred=None, beyond_predicted: bool = False):
    """The limit [s] the margin is kept below: min(h_meas, h_pred), or h_meas alone with
    `beyond_predicted` or no h_pred; a NaN of one of them (no prediction where the model
    returned NaN) leaves the other. Scalars or arrays alike."""
    h_meas = np.asarray(h_meas, float)
    if h_pred is None or beyond_predicted:
        return h_meas
    return np.fmin(h_meas, np.asarray(h_pred, float))


def stable_with_margin(stable, h, h_meas, margin: float, h_pred=None,
                       beyond_predicted: bool = False):
    """Where a stable step h [s] keeps `margin` (a fraction) below the limit (see `limit`);
    scalars or arrays alike."""
    with np.errstate(invalid="ignore"):
        return np.logical_and(stable, np.asarray(h) <= (1.0 - margin) * limit(
            h_meas, h_pred, beyond_predicted))


def beyond(h, h_pred):
    """Where h [s] is above the predicted limit h_pred [s] (NaN: no prediction, not beyond)."""
    with np.errstate(invalid="ignore"):
        return np.asarray(h) > np.asarray(h_pred, float)


def percent_below(h: float, h_limit: float) -> str:
    """How far h is below h_limit, as a percentage of h_limit ('18%')."""
    if not math.isfinite(h_limit) or h_limit <= 0:
        return "-"
    return f"{100.0 * (1.0 - h / h_limit):.2g}%"
