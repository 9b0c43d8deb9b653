"""Paths of a car that ignore obstacles, for many start poses at once: the length of the
shortest path of bounded curvature forwards (Dubins 1957), and the words (segments) and
shortest length forwards and backwards (Reeds & Shepp 1990). Any path of the car between two
poses is at least this long, so the lengths order and prune the search's nodes; the words
guide the connection when the car may reverse."""
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


# --- Reeds-Shepp (1990): forwards and backwards, cusps free --------------------------------
# The words of Reeds & Shepp's section 8 (formulas 8.1-8.11) in the goal's coordinates
# relative to the start, unit turning radius, each for many poses at once.
# The other 40 of the 48 words follow by time-flip (x, y, phi) -> (-x, y, -phi), reflection
# (x, -y, -phi), both (-x, -y, phi), and, for CCC and CCSC, driving the word backwards
# (x cos phi + y sin phi, x sin phi - y cos phi, phi).
EPS = 1e-10


def _mod_pi(a):
    """Angle in (-pi, pi] [rad]."""
    b = np.mod(a, TWO_PI)
    return np.where(b > np.pi, b - TWO_PI, b)


def _polar(x, y):
    return np.hypot(x, y), np.arctan2(y, x)


def _tau_omega(u, v, xi, eta, phi):
    delta = _mod_pi(u - v)
    A, B = np.sin(u) - np.sin(delta), np.cos(u) - np.cos(delta) - 1
    t1 = np.arctan2(eta * A - xi * B, xi * A + eta * B)
    t2 = 2 * (np.cos(delta) - np.cos(v) - np.cos(u)) + 3
    tau = np.where(t2 < 0, _mod_pi(t1 + np.pi), _mod_pi(t1))
    return tau, _mod_pi(tau - u + v - phi)


# Each word gives (ok, segments): segments are (turn, signed length) with turn +1 (left),
# -1 (right) or 0 (straight) and the length in turning radii, negative backwards.
HALF_PI = 0.5 * np.pi


def _lsl(x, y, phi):                                                   # 8.1
    u, t = _polar(x - np.sin(phi), y - 1 + np.cos(phi))
    v = _mod_pi(phi - t)
    return (t >= -EPS) & (v >= -EPS), [(1, t), (0, u), (1, v)]


def _lsr(x, y, phi):                                                   # 8.2
    u1, t1 = _polar(x + np.sin(phi), y - 1 - np.cos(phi))
    u = np.sqrt(np.maximum(u1 * u1 - 4, 0.0))
    t = _mod_pi(t1 + np.arctan2(2, u))
    v = _mod_pi(t - phi)
    return (u1 * u1 >= 4) & (t >= -EPS) & (v >= -EPS), [(1, t), (0, u), (-1, v)]


def _lrl(x, y, phi):                                                   # 8.3
    u1, theta = _polar(x - np.sin(phi), y - 1 + np.cos(phi))
    u = -2 * np.arcsin(np.minimum(0.25 * u1, 1.0))
    t = _mod_pi(theta + 0.5 * u + np.pi)
    v = _mod_pi(phi - t + u)
    return (u1 <= 4) & (t >= -EPS) & (u <= EPS), [(1, t), (-1, u), (1, v)]


def _lrlr_a(x, y, phi):                                                # 8.7
    xi, eta = x + np.sin(phi), y - 1 - np.cos(phi)
    rho = 0.25 * (2 + np.hypot(xi, eta))
    u = np.arccos(np.minimum(rho, 1.0))
    t, v = _tau_omega(u, -u, xi, eta, phi)
    return (rho <= 1) & (t >= -EPS) & (v <= EPS), [(1, t), (-1, u), (1, -u), (-1, v)]


def _lrlr_b(x, y, phi):                                                # 8.8
    xi, eta = x + np.sin(phi), y - 1 - np.cos(phi)
    rho = (20 - xi * xi - eta * eta) / 16
    u = -np.arccos(np.clip(rho, -1.0, 1.0))
    t, v = _tau_omega(u, u, xi, eta, phi)
    ok = (rho >= 0) & (rho <= 1) & (u >= -0.5 * np.pi) & (t >= -EPS) & (v >= -EPS)
    return ok, [(1, t), (-1, u), (1, u), (-1, v)]


def _lrsl(x, y, phi):                                                  # 8.9
    rho, theta = _polar(x - np.sin(phi), y - 1 + np.cos(phi))
    r = np.sqrt(np.maximum(rho * rho - 4, 0.0))
    u = 2 - r
    t = _mod_pi(theta + np.arctan2(r, -2))
    v = _mod_pi(phi - 0.5 * np.pi - t)
    ok = (rho >= 2) & (t >= -EPS) & (u <= EPS) & (v <= EPS)
    return ok, [(1, t), (-1, -HALF_PI), (0, u), (1, v)]


def _lrsr(x, y, phi):                                                  # 8.10
    rho, theta = _polar(-(y - 1 - np.cos(phi)), x + np.sin(phi))
    t, u = theta, 2 - rho
    v = _mod_pi(t + 0.5 * np.pi - phi)
    ok = (rho >= 2) & (t >= -EPS) & (u <= EPS) & (v <= EPS)
    return ok, [(1, t), (-1, -HALF_PI), (0, u), (-1, v)]


def _lrslr(x, y, phi):                                                 # 8.11
    xi, eta = x + np.sin(phi), y - 1 - np.cos(phi)
    rho, _ = _polar(xi, eta)
    u = 4 - np.sqrt(np.maximum(rho * rho - 4, 0.0))
    t = _mod_pi(np.arctan2((4 - u) * xi - 2 * eta, -2 * xi + (u - 4) * eta))
    v = _mod_pi(t - phi)
    ok = (rho >= 2) & (u <= EPS) & (t >= -EPS) & (v >= -EPS)
    return ok, [(1, t), (-1, -HALF_PI), (0, u), (1, -HALF_PI), (-1, v)]


def reeds_shepp_words(starts, goal, radius) -> list:
    """The 48 words of Reeds & Shepp from each pose of `starts` (K, 3+) [X, Y, psi] to the
    pose `goal`, curvature <= 1/radius [1/m]: a list of (ok (K,) bool: the word exists,
    segments [(turn, (K,) signed length [m])]), turn +1 left, -1 right, 0 straight, lengths
    negative where the car drives backwards, in the order driven."""
    starts = np.atleast_2d(np.asarray(starts, float))
    dx, dy = goal[0] - starts[:, 0], goal[1] - starts[:, 1]
    c, s = np.cos(starts[:, 2]), np.sin(starts[:, 2])
    x, y = (c * dx + s * dy) / radius, (-s * dx + c * dy) / radius
    phi = goal[2] - starts[:, 2]
    backwards = (x * np.cos(phi) + y * np.sin(phi), x * np.sin(phi) - y * np.cos(phi), phi)
    out = []
    with np.errstate(invalid="ignore"):
        for word, reverse_too in ((_lsl, False), (_lsr, False), (_lrl, True), (_lrlr_a, False),
                                  (_lrlr_b, False), (_lrsl, True), (_lrsr, True),
                                  (_lrslr, False)):
            for back, (bx, by, bphi) in ((False, (x, y, phi)), (True, backwards))[
                    :2 if reverse_too else 1]:
                for sx, sy in ((1, 1), (-1, 1), (1, -1), (-1, -1)):
                    ok, segs = word(sx * bx, sy * by, sx * sy * bphi)
                    # Time-flip (sx = -1) drives every segment the other way, reflection
                    # (sy = -1) swaps left and right, backwards drives the word end first.
                    segs = [(sy * turn, sx * radius * np.broadcast_to(q, ok.shape))
                            for turn, q in segs]
                    out.append((ok, segs[::-1] if back else segs))
    return out


def reeds_shepp_length(starts, goal, radius) -> np.ndarray:
    """(K,) [m]: length of the shortest path of curvature <= 1/radius [1/m], forwards and
    backwards with any number of cusps (Reeds & Shepp 1990), from each pose of `starts`
    (K, 3+) [X, Y, psi] to the pose `goal`; a lower bound of any path of the car with reverse
    gear."""
    best = np.full(len(np.atleast_2d(starts)), np.inf)
    for ok, segs in reeds_shepp_words(starts, goal, radius):
        length = sum(np.abs(q) for _, q in segs)
        best = np.where(ok & (length < best), length, best)
    return best
