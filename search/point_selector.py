"""Where the planner shoots (paper Algorithm 2): `n` equally spaced points on an arc ahead of a
node, between psi - delta_max and psi + delta_max, plus seeded random points biased around the
destination."""
import numpy as np


def point_selector(state, radius, n, delta_max) -> np.ndarray:
    """(n, 2) [m]: points on the arc of `radius` [m] around (X, Y) of `state` [X, Y, psi, ...],
    at headings psi - delta_max .. psi + delta_max [rad]; one point lies straight ahead."""
    x, y, psi = state[0], state[1], state[2]
    angles = psi + (np.linspace(-delta_max, delta_max, n) if n > 1 else np.zeros(1))
    return np.column_stack([x + radius * np.cos(angles), y + radius * np.sin(angles)])


def random_points(rng: np.random.Generator, destination, n, spread) -> np.ndarray:
    """(n, 2) [m]: uniform in the disc of radius `spread` [m] around `destination` [X, Y]."""
    r = spread * np.sqrt(rng.random(n))
    a = 2 * np.pi * rng.random(n)
    return np.asarray(destination[:2], float) + np.column_stack([r * np.cos(a), r * np.sin(a)])
