"""Lower bounds of the length of a car's path that ignore obstacles: the shortest forward path
of bounded curvature (Dubins 1957), for many start poses at once. Any forward path of the car
between two poses is at least this long, so it orders and prunes the search's nodes."""
from __future__ import annotations

import numpy as np

TWO_PI = 2 * np.pi
LOOP_TOL = 1e-9  # [rad] an arc this close to a full turn is a rounding of no turn


def dubins_length(starts, goal, radius) -> np.ndarray:
    """(K,) [m]: length of the shortest forward path of curvature <= 1/radius [1/m] from each
    pose of `starts` (K, 3+) [X, Y, psi] to the pose `goal` [X, Y, psi]; the six words
    (LSL, RSR, LSR, RSL, RLR, LRL) in closed form, each where it exists."""
    starts = np.atleast_2d(np.asarray(starts, float))
    dx, dy = goal[0] - starts[:, 0], goal[1] - starts[:, 1]
    d = np.hypot(dx, dy) / radius
    chord = np.arctan2(dy, dx)
    alpha, beta = _arc(starts[:, 2] - chord), _arc(goal[2] - chord)
    sa, sb, ca, cb = np.sin(alpha), np.sin(beta), np.cos(alpha), np.cos(beta)
    cab = np.cos(alpha - beta)
    words = []
    with np.errstate(invalid="ignore"):  # a word that does not exist gives NaN
        p2 = 2 + d * d - 2 * cab + 2 * d * (sa - sb)                      # LSL
        tmp = np.arctan2(cb - ca, d + sa - sb)
        words.append(_arc(tmp - alpha) + np.sqrt(p2) + _arc(beta - tmp))
        p2 = 2 + d * d - 2 * cab + 2 * d * (sb - sa)                      # RSR
        tmp = np.arctan2(ca - cb, d - sa + sb)
        words.append(_arc(alpha - tmp) + np.sqrt(p2) + _arc(tmp - beta))
        p = np.sqrt(-2 + d * d + 2 * cab + 2 * d * (sa + sb))             # LSR
        tmp = np.arctan2(-ca - cb, d + sa + sb) - np.arctan2(-2, p)
        words.append(_arc(tmp - alpha) + p + _arc(tmp - beta))
        p = np.sqrt(d * d - 2 + 2 * cab - 2 * d * (sa + sb))              # RSL
        tmp = np.arctan2(ca + cb, d - sa - sb) - np.arctan2(2, p)
        words.append(_arc(alpha - tmp) + p + _arc(beta - tmp))
        c = (6 - d * d + 2 * cab + 2 * d * (sa - sb)) / 8                 # RLR
        p = _arc(TWO_PI - np.arccos(c))
        t = _arc(alpha - np.arctan2(ca - cb, d - sa + sb) + p / 2)
        words.append(t + p + _arc(alpha - beta - t + p))
        c = (6 - d * d + 2 * cab + 2 * d * (sb - sa)) / 8                 # LRL
        p = _arc(TWO_PI - np.arccos(c))
        t = _arc(-alpha + np.arctan2(cb - ca, d + sa - sb) + p / 2)
        words.append(t + p + _arc(beta - alpha - t + p))
    return radius * np.nanmin(np.stack(words), axis=0)


def _arc(angle) -> np.ndarray:
    """[rad] a turn in [0, 2 pi), rounding near a full turn to none: a bound must never be
    too long (a word of zero turns would otherwise gain a loop)."""
    turn = np.mod(angle, TWO_PI)
    return np.where(turn > TWO_PI - LOOP_TOL, 0.0, turn)
