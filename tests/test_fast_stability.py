"""The chunked ray scan with its Schur-Cohn shortcut gives the very exits of one whole scan
by the eigenvalue route, for every method along rays of the left half-plane."""
import numpy as np
import pytest

from stepzoo.integrators import METHODS
from stepzoo.integrators import stability as S

ANGLES = (np.pi, 0.75 * np.pi, np.pi / 2, np.pi - 0.04)


def whole_scan_exit(m, theta):
    """The exit by one scan of every radius with the exact amplification (the old route)."""
    d = np.exp(1j * theta)
    rs = np.concatenate([np.linspace(0.0, S.R_FINE, S.N_FINE + 1)[1:],
                         np.geomspace(S.R_FINE, S.R_FAR, S.N_FAR)[1:]])
    amp = S.amplification_theory(m, rs * d)
    outside = ~(np.nan_to_num(amp, nan=np.inf) <= 1.0 + S.TOL)
    if not outside.any():
        return float("inf")
    i = int(np.argmax(outside))
    if not np.any(amp[:i] < 1.0 - S.MEASURABLE):
        return 0.0
    lo, hi = rs[i - 1], rs[i]
    for _ in range(S.BISECT):
        mid = 0.5 * (lo + hi)
        inside = np.nan_to_num(S.amplification_theory(m, np.array([mid * d])), nan=np.inf)
        lo, hi = (mid, hi) if inside[0] <= 1.0 + S.TOL else (lo, mid)
    return lo


@pytest.mark.parametrize("name", list(METHODS))
def test_fast_ray_exit_equals_the_whole_scan(name):
    m = METHODS[name]
    for theta in ANGLES:
        assert S.ray_exit(m, theta) == whole_scan_exit(m, theta), (name, theta)


def test_schur_cohn_agrees_with_the_roots_of_every_multistep_method():
    rng = np.random.default_rng(1)
    z = (rng.normal(size=4000) + 1j * rng.normal(size=4000)) * rng.choice([0.1, 1, 10], 4000)
    for m in (m for m in METHODS.values() if m.is_multistep):
        lmm = m.scheme
        big = S.multistep_roots_max(lmm, z)
        coeffs = lmm.alpha[None, :] - z[:, None] * lmm.beta[None, :]
        clear = np.isfinite(big) & (np.abs(big - 0.9) > 1e-9)
        np.testing.assert_array_equal(S.schur_inside(coeffs, 0.9)[clear], big[clear] < 0.9)
        # The bound is exact wherever the amplification can matter to a scan.
        bound = S.multistep_amplification_bound(lmm, z)
        near = big > 1.0 - S.CERTAIN
        np.testing.assert_array_equal(bound[near], big[near])
        assert np.all(bound[~near] < 1.0 - S.CERTAIN)
