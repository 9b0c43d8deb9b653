"""Linear stability of the zoo on y' = lambda y, z = h*lambda, by two independent routes:
theory (R(z) by the determinant formula, for a Rosenbrock method that of its underlying DIRK;
the root condition of rho(zeta) - z sigma(zeta)) and experiment (the method's own JAX step
applied to y' = z y, vmapped over a grid of z).

Along a ray z = r e^{i theta} the interval is the first exit from the region, found by a
dense scan and refined by bisection; A-stable methods never exit and give inf. A ray that
is tangent to the region's boundary at z = 0 (|R| = 1 + C r^q, C > 0, e.g. Heun or RK6 on
the imaginary axis) looks stable to round-off for small r; its interval is 0, recognised
by the ray never being measurably inside (|R| < 1 - MEASURABLE) before its exit."""
from functools import cache

import jax
import jax.numpy as jnp
import numpy as np
from numpy.polynomial import polynomial as P

from stepzoo.integrators.methods import Method
from stepzoo.integrators.multistep import LinearMultistep
from stepzoo.integrators.rosenbrock import Rosenbrock
from stepzoo.integrators.tableau import ButcherTableau

TOL = 1e-12            # |amplification| <= 1 + TOL counts as stable (round-off of |R| = 1)
MEASURABLE = 1e-10     # |amplification| below 1 - MEASURABLE is inside beyond doubt
R_FINE = 40.0          # dense linear scan of the ray up to this |z|...
N_FINE = 8000
R_FAR = 1e8            # ...then a log scan out to here; no exit at all means unbounded
N_FAR = 2000
SCAN_CHUNK = 512       # radii evaluated at once by the scan
CERTAIN = 1e-6         # a Schur-Cohn margin far above the eigenvalue solver's round-off
BISECT = 60
SECTOR_SCAN = 5.0      # [deg] ray spacing of the sector scan of `a_alpha`...
SECTOR_TOL = 1e-4      # [deg] ...and the bisection's tolerance


def stability_function(tab, z):
    """R(z) = det(I - zA + z 1 b^T) / det(I - zA) of a tableau, for an array of complex z."""
    z = np.asarray(z, dtype=complex)[..., None, None]
    s = tab.stages
    eye, a = np.eye(s), tab.a
    num = np.linalg.det(eye - z * a + z * np.outer(np.ones(s), tab.b))
    with np.errstate(divide="ignore", invalid="ignore"):       # poles of implicit methods
        return num / np.linalg.det(eye - z * a)


def multistep_roots_max(lmm, z):
    """Largest |zeta| over the roots of rho(zeta) - z sigma(zeta), for an array of z; inf at
    z = 1/beta_k of an implicit method, where the leading coefficient vanishes (a root goes
    to infinity: the step divides by zero)."""
    z = np.asarray(z, dtype=complex).ravel()
    coeffs = lmm.alpha[None, :] - z[:, None] * lmm.beta[None, :]     # low to high degree
    lead = coeffs[:, -1:]
    pole = lead[:, 0] == 0
    # Companion matrices of the monic polynomials, eigenvalues all at once.
    k = lmm.steps
    comp = np.zeros((len(z), k, k), dtype=complex)
    comp[:, 1:, :-1] = np.eye(k - 1)
    comp[:, :, -1] = -coeffs[:, :-1] / np.where(pole[:, None], 1.0, lead)
    return np.where(pole, np.inf, np.abs(np.linalg.eigvals(comp)).max(axis=-1))


def schur_inside(coeffs, radius: float) -> np.ndarray:
    """Whether every root of each polynomial (rows of coeffs, low to high degree) lies in
    |zeta| < radius, by the Schur-Cohn recursion (no roots computed): p has all its roots
    in the unit disc iff |p(0)| < |p*(0)| and (p*(0) p - p(0) p*) / zeta has too, where p*
    is p reversed and conjugated."""
    c = np.asarray(coeffs, dtype=complex) * radius ** np.arange(np.shape(coeffs)[-1])
    ok = np.ones(c.shape[0], bool)
    with np.errstate(divide="ignore", invalid="ignore"):    # NaN rows: not shown inside
        while c.shape[1] > 1:
            # Scaled to a largest coefficient of 1 (roots unchanged): the products square
            # the coefficients' size at every degree and would overflow at large |z|.
            c = c / np.abs(c).max(axis=1, keepdims=True)
            a0, an = c[:, :1], c[:, -1:]
            ok &= np.abs(a0[:, 0]) < np.abs(an[:, 0])
            c = (np.conj(an) * c - a0 * np.conj(c[:, ::-1]))[:, 1:]
    return ok


def multistep_amplification_bound(lmm, z) -> np.ndarray:
    """multistep_roots_max where it exceeds 1 - CERTAIN, else a value below 1 - CERTAIN: the
    points that schur_inside places inside that radius skip the eigenvalue solve. For the
    ray scans, which only compare the amplification with 1 + TOL and 1 - MEASURABLE."""
    z = np.asarray(z, dtype=complex).ravel()
    out = np.zeros(len(z))
    inside = schur_inside(lmm.alpha[None, :] - z[:, None] * lmm.beta[None, :], 1.0 - CERTAIN)
    if not inside.all():
        out[~inside] = multistep_roots_max(lmm, z[~inside])
    return out


def tableau(m: Method) -> ButcherTableau:
    """The Butcher tableau whose R(z) is the one-step method's: its own, or a Rosenbrock
    method's underlying DIRK (alpha + Gamma, b)."""
    if isinstance(m.scheme, LinearMultistep):
        raise TypeError(f"{m.name} is a multistep method: it has no Butcher tableau")
    return m.scheme.tableau if isinstance(m.scheme, Rosenbrock) else m.scheme


def amplification_theory(m: Method, z):
    """|R(z)|, or the largest root modulus for a multistep method."""
    if m.is_multistep:
        return multistep_roots_max(m.scheme, z).reshape(np.shape(z))
    return np.abs(stability_function(tableau(m), z))


@cache
def _empirical(m: Method):
    """A jitted map z (complex array) -> amplification measured with the method's own step."""
    def fun_for(zr, zi):
        mat = jnp.array([[zr, -zi], [zi, zr]])
        return lambda t, y: mat @ y

    def one_step(zr, zi, y0):
        fun = fun_for(zr, zi)
        return m.step(fun, 0.0, y0, 1.0, m.init_state(y0))[0]

    def rk(zr, zi):
        y = one_step(zr, zi, jnp.array([1.0, 0.0]))
        return jnp.hypot(y[0], y[1])

    def lmm(zr, zi):
        # The step maps a history (y_0..y_{k-1}) to y_k linearly: stepping the k unit
        # histories gives the last row of the companion matrix; its spectral radius rules.
        k = m.steps
        fun = fun_for(zr, zi)
        rows = []
        for j in range(k):
            ys = jnp.zeros((k, 2)).at[j, 0].set(1.0)
            fs = jax.vmap(lambda y: fun(0.0, y))(ys)
            state = dict(m.init_state(ys[0]), ys=ys, fs=fs)
            y = m.step(fun, float(k - 1), ys[-1], 1.0, state)[0]
            rows.append(y[0] + 1j * y[1])
        comp = jnp.zeros((k, k), complex).at[:-1, 1:].set(jnp.eye(k - 1))
        comp = comp.at[-1].set(jnp.stack(rows))
        return jnp.max(jnp.abs(jnp.linalg.eigvals(comp)))

    return jax.jit(jax.vmap(lmm if m.is_multistep else rk))


def amplification_empirical(m: Method, z):
    """The amplification at each z measured with the method's own step. Evaluated in blocks
    of SCAN_CHUNK points (the last one padded with z = 0), so that every call but one of a
    single point runs one of two compiled programs per method: a program is compiled per
    input length, and for an implicit method compiling is most of the cost."""
    z = np.asarray(z, dtype=complex)
    if z.size <= 1:
        blocks = [z.ravel()]
    else:
        flat = np.concatenate([z.ravel(), np.zeros(-z.size % SCAN_CHUNK, complex)])
        blocks = np.split(flat, flat.size // SCAN_CHUNK)
    amp = _empirical(m)
    out = [np.asarray(amp(jnp.asarray(b.real), jnp.asarray(b.imag))) for b in blocks]
    return np.concatenate(out)[:z.size].reshape(z.shape)


def _ray_exit(amp, theta: float, scan_amp=None) -> float:
    """Smallest r > 0 at which r e^{i theta} leaves the region; inf if it never does;
    `scan_amp` (default amp) for the scan, amp for the bisection. The scan runs in chunks of
    SCAN_CHUNK radii and stops at the first chunk with a point outside: the same points and
    the same first exit as one whole scan, at a fraction of its cost where the exit is near
    (amp of a point does not depend on its neighbours)."""
    d = np.exp(1j * theta)
    rs = np.concatenate([np.linspace(0.0, R_FINE, N_FINE + 1)[1:],
                         np.geomspace(R_FINE, R_FAR, N_FAR)[1:]])
    seen = []
    for lo in range(0, len(rs), SCAN_CHUNK):
        a = (scan_amp or amp)(rs[lo:lo + SCAN_CHUNK] * d)
        seen.append(a)
        outside = ~(np.nan_to_num(a, nan=np.inf) <= 1.0 + TOL)
        if outside.any():
            break
    else:
        return float("inf")
    i = lo + int(np.argmax(outside))
    if not np.any(np.concatenate(seen)[:i] < 1.0 - MEASURABLE):
        return 0.0                                  # tangent at the origin
    lo, hi = rs[i - 1], rs[i]
    for _ in range(BISECT):
        mid = 0.5 * (lo + hi)
        if mid == lo or mid == hi:      # adjacent floats: no later step would move lo
            break
        if np.nan_to_num(amp(np.array([mid * d])), nan=np.inf)[0] <= 1.0 + TOL:
            lo = mid
        else:
            hi = mid
    return lo


@cache
def ray_exit(m: Method, theta: float, route: str = "theory") -> float:
    """First exit |z| along the ray of angle theta [rad] by `route` ('theory' or 'empirical')."""
    if route == "theory" and not m.is_multistep and theta > np.pi / 2 and a_stable(m):
        return float("inf")          # the left half-plane, by the maximum principle
    amp = {"theory": amplification_theory, "empirical": amplification_empirical}[route]
    scan = None
    if route == "theory" and m.is_multistep:
        scan = lambda z: multistep_amplification_bound(m.scheme, z)
    return _ray_exit(lambda z: amp(m, z), theta, scan)


def stability_intervals(m: Method, route: str = "theory") -> tuple[float, float]:
    """(real, imaginary) stability intervals: [-real, 0] and [0, i*imag] lie in the region."""
    return ray_exit(m, np.pi, route), ray_exit(m, np.pi / 2, route)


def max_stable_step(m: Method, eigenvalues) -> float:
    """Largest h [s] with every h*lambda in the stability region (first exit along each
    eigenvalue's ray); inf when no ray ever leaves (A-stable methods on stable modes).
    Zero eigenvalues constrain nothing."""
    h = float("inf")
    for lam in np.atleast_1d(np.asarray(eigenvalues, dtype=complex)):
        if abs(lam) == 0.0:
            continue
        theta = float(np.round(abs(np.angle(lam)), 12))     # regions are symmetric in Im z
        h = min(h, ray_exit(m, theta) / abs(lam))
    return h


def stiff_decay(m: Method) -> float:
    """|R(-inf)|, the damping of infinitely stiff modes: 1 - b^T A^-1 1 for an implicit
    tableau with invertible A, the limit along the negative axis otherwise; for an implicit
    multistep method the largest root of sigma. inf for explicit methods."""
    if not m.implicit:
        return float("inf")
    if isinstance(m.scheme, LinearMultistep):
        roots = np.roots(m.scheme.beta[::-1])
        return float(np.abs(roots).max()) if roots.size else 0.0
    tab = tableau(m)
    if np.linalg.matrix_rank(tab.a) == tab.stages:
        return float(abs(1.0 - tab.b @ np.linalg.solve(tab.a, np.ones(tab.stages))))
    return float(amplification_theory(m, np.array([-1e12]))[0])


def a_stable(m: Method) -> bool:
    """Whether the whole left half-plane is stable. Tableau: its poles 1/eig(A) lie in the
    right half-plane (so R is analytic on the left) and |R(iy)| <= 1 along the imaginary
    axis, which by the maximum principle suffices. Multistep: no ray of the left half-plane
    ever leaves the root-condition region."""
    if not m.implicit:
        return False
    if m.is_multistep:
        rays = np.linspace(np.pi / 2, np.pi, 9)
        return all(bool(np.isinf(ray_exit(m, float(th)))) for th in rays)
    eig = np.linalg.eigvals(tableau(m).a)
    poles_right = bool(np.all(eig[np.abs(eig) > 1e-12].real > 0))
    return poles_right and bool(np.isinf(ray_exit(m, np.pi / 2)))


def l_stable(m: Method) -> bool:
    """A-stable with |R(-inf)| = 0 (to 1e-9)."""
    return a_stable(m) and stiff_decay(m) <= 1e-9


def root_locus(lmm, n: int = 200_001) -> np.ndarray:
    """The boundary locus z(theta) = rho(e^{i theta}) / sigma(e^{i theta}) of a multistep
    method for theta in [0, pi] (the other half is its mirror image): the z where a root of
    rho - z sigma has modulus 1, among them the whole boundary of the stability region."""
    zeta = np.exp(1j * np.linspace(0.0, np.pi, n))
    with np.errstate(divide="ignore", invalid="ignore"):     # sigma = 0: z at infinity
        return P.polyval(zeta, lmm.alpha) / P.polyval(zeta, lmm.beta)


def a_alpha(m: Method) -> float | None:
    """The A(alpha) angle [deg]: the largest alpha such that the sector |arg(-z)| < alpha
    lies in the stability region; 90 for A-stable methods, None where the negative real axis
    itself leaves the region (no sector at all). Multistep: the smallest angle to the
    negative real axis of the root locus in the left half-plane (every locus point has an
    unstable side, so none may lie in the sector). Tableau: rays of the sector every
    SECTOR_SCAN deg, the first that leaves bisected to SECTOR_TOL deg against the last that
    does not."""
    if not m.implicit or not np.isinf(ray_exit(m, np.pi)):
        return None
    if a_stable(m):
        return 90.0
    if m.is_multistep:
        z = root_locus(m.scheme)[1:]                        # theta = 0 is z = 0 itself
        left = np.isfinite(z) & (z.real < 0)
        return float(np.degrees(np.min(np.pi - np.abs(np.angle(z[left])))))
    stable = lambda deg: bool(np.isinf(ray_exit(m, float(np.pi - np.radians(deg)))))
    hi = next(deg for deg in np.arange(SECTOR_SCAN, 90.0 + SECTOR_SCAN / 2, SECTOR_SCAN)
              if not stable(deg))
    lo = hi - SECTOR_SCAN
    while hi - lo > SECTOR_TOL:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return float(lo)


def region_grid(m: Method, re: tuple[float, float] = (-6.0, 2.0),
                im: tuple[float, float] = (-4.0, 4.0), n: int = 401,
                route: str = "theory") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(re axis, im axis, amplification on the grid) for plots; stable where <= 1."""
    x, y = np.linspace(*re, n), np.linspace(*im, n)
    z = x[None, :] + 1j * y[:, None]
    amp = amplification_theory(m, z) if route == "theory" else amplification_empirical(m, z)
    return x, y, amp
