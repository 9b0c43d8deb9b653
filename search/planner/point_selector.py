"""Where the planner shoots (paper Algorithm 2): `n` equally spaced points on an arc ahead of a
node, between psi - delta_max and psi + delta_max, plus seeded random points biased around the
destination."""
import functools

import numpy as np


def point_selector(state, radius, n, delta_max) -> np.ndarray:
    """(n, 2) [m]: points on the arc of `radius` [m] around (X, Y) of `state` [X, Y, psi, ...],
    at headings psi - delta_max .. psi + delta_max [rad]; one point lies straight ahead."""
    angles = state[2] + _fan(n, delta_max)
    points = np.empty((angles.size, 2))
    points[:, 0] = state[0] + radius * np.cos(angles)
    points[:, 1] = state[1] + radius * np.sin(angles)
    return points


@functools.lru_cache(maxsize=16)
def _fan(n, delta_max) -> np.ndarray:
    """(n,) [rad]: the arc's headings relative to psi; the same for every expansion of a plan."""
    fan = np.linspace(-delta_max, delta_max, n) if n > 1 else np.zeros(1)
    fan.setflags(write=False)
    return fan


def random_points(rng: np.random.Generator, destination, n, spread) -> np.ndarray:
    """(n, 2) [m]: uniform in the disc of radius `spread` [m] around `destination` [X, Y]."""
    r = spread * np.sqrt(rng.random(n))
    a = 2 * np.pi * rng.random(n)
    return np.asarray(destination[:2], float) + np.column_stack([r * np.cos(a), r * np.sin(a)])
