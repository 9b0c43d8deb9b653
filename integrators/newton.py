"""Simplified Newton iteration for the stage equations of the implicit methods (Hairer &
Wanner, Solving ODEs II, IV.8, as in RADAU5): every iteration reuses one factorised iteration
matrix, whose Jacobian a step keeps from the last while the iteration contracts fast, and a
fully implicit method's stage system is solved through A's eigenvalues. A solve reports
whether it converged: the rate of convergence theta_k = |dz_k| / |dz_{k-1}| estimates the
error left after an increment as theta/(1 - theta) |dz_k|; the solve stops when that
estimate and the residual are both within tolerance, and gives up early when the iteration
diverges (theta >= 1) or cannot reach the tolerance within the iteration limit at its
current rate."""
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.scipy import linalg


@dataclass(frozen=True)
class NewtonOptions:
    """Tolerances of one nonlinear solve, on the components weighted by atol + rtol |y|:
    the estimated error of the stage values must be at most 1, and the residual at most
    `res_tol` times 1 + |h A (x) J| (the residual of an iterate is the iteration matrix times
    its error: with res_tol = 1 it is no larger than an error within tolerance makes it).
    At most `max_iter` simplified iterations, then, where they fail, at most `max_iter_full`
    of the full-Newton retry (0: none)."""
    rtol: float = 1e-10
    atol: float = 1e-10
    res_tol: float = 1.0
    max_iter: int = 10
    max_iter_full: int = 40

    def __post_init__(self):
        if not (self.rtol >= 0 and self.atol >= 0 and self.rtol + self.atol > 0):
            raise ValueError(f"Newton tolerances must be >= 0, not both 0: rtol={self.rtol!r}, "
                             f"atol={self.atol!r}")
        if not (self.res_tol > 0 and int(self.max_iter) == self.max_iter >= 1
                and int(self.max_iter_full) == self.max_iter_full >= 0):
            raise ValueError(f"need res_tol > 0 and integers max_iter >= 1, max_iter_full >= 0:"
                             f" res_tol={self.res_tol!r}, max_iter={self.max_iter!r}, "
                             f"max_iter_full={self.max_iter_full!r}")


# Increments this many ulps of the iterate are round-off: the iteration has converged as far
# as the arithmetic allows, whatever the rate estimate says (it is noise at that level).
ROUND_OFF_ULPS = 8


# Matrices up to this order are factorised by the unrolled elimination below; larger ones
# (Radau IIA 5's 3d stage system) by LAPACK: an unrolled n^3 of operations at order 15 did
# not finish compiling in minutes.
SMALL = 8


def lu_factor(mat):
    """Gaussian elimination with partial pivoting of a square matrix: (lu, pivots), the unit
    lower factor below the diagonal and the upper one on and above it, `pivots[k]` the row
    swapped with row k at column k. Up to order SMALL it is unrolled over the entries, held
    as nested lists of scalars: under vmap every operation, pivot search and row swaps
    included, is then elementwise across the batch, where LAPACK's getrf (or updates of
    slices of an array) would take the tiny matrices one at a time."""
    n = mat.shape[0]
    if n > SMALL:
        return linalg.lu_factor(mat)
    a = [[mat[i, j] for j in range(n)] for i in range(n)]
    pivots = []
    for k in range(n - 1):
        p, largest = jnp.asarray(k), jnp.abs(a[k][k])
        for i in range(k + 1, n):
            larger = jnp.abs(a[i][k]) > largest
            p, largest = jnp.where(larger, i, p), jnp.where(larger, jnp.abs(a[i][k]), largest)
        a[k:] = _swap(a[k:], k, p)
        for i in range(k + 1, n):
            a[i][k] = a[i][k] / a[k][k]
            for j in range(k + 1, n):
                a[i][j] = a[i][j] - a[i][k] * a[k][j]
        pivots.append(p)
    return a, pivots


def _swap(rows, k, p):
    """rows (rows k, k+1, ... of a matrix or vector) with the first, row k, exchanged with
    row p >= k (a traced index), by selection rather than indexing, so that a batch of swaps
    stays elementwise."""
    first = rows[0]
    for i in range(1, len(rows)):
        first = jax.tree.map(lambda f, r, i=i: jnp.where(p == k + i, r, f), first, rows[i])
    return [first] + [jax.tree.map(lambda r, f, i=i: jnp.where(p == k + i, f, r),
                                   rows[i], rows[0]) for i in range(1, len(rows))]


def lu_solve(factors, r):
    """mat^-1 r from `lu_factor(mat)`: the row swaps, then forward and back substitution."""
    lu, pivots = factors
    if not isinstance(lu, list):
        return linalg.lu_solve(factors, r)
    n = len(lu)
    x = [r[i] for i in range(n)]
    for k in range(n - 1):
        x[k:] = _swap(x[k:], k, pivots[k])
    for i in range(n):
        for j in range(i):
            x[i] = x[i] - lu[i][j] * x[j]
    for i in range(n - 1, -1, -1):
        for j in range(i + 1, n):
            x[i] = x[i] - lu[i][j] * x[j]
        x[i] = x[i] / lu[i][i]
    return jnp.stack(x)


def factorised(mat):
    """(lu, 1 + |mat - I|_inf): the LU factors of an iteration matrix, applied by `solver`,
    and the size against which a residual is judged."""
    size = 1.0 + jnp.max(jnp.sum(jnp.abs(mat - jnp.eye(mat.shape[0], dtype=mat.dtype)), axis=1))
    return lu_factor(mat), size


def solver(factors):
    """(solve, size) of `factorised`'s factors: solve(r) = mat^-1 r."""
    lu, size = factors
    return (lambda r: lu_solve(lu, r)), size


class Stages(NamedTuple):
    """I - h A (x) J for a diagonalisable A = V diag(mu) V^-1, transformed as RADAU5 does
    (HW IV.8): one d x d system I - h mu J per real eigenvalue mu and one, in complex
    arithmetic, per complex pair, instead of the s d x s d system. `mu` are the
    eigenvalues solved for (of a pair, the one with Im mu > 0), `twice` says which stand
    for a pair; `v` their columns of V, `v_inv` their rows of V^-1 (NumPy constants)."""
    v: np.ndarray
    v_inv: np.ndarray
    mu: np.ndarray
    twice: tuple

    @staticmethod
    def of(a):
        """The transformation of A, or None where A is not diagonalisable with a
        well-conditioned V (then the s d x s d system is factorised whole)."""
        mu, v = np.linalg.eig(np.asarray(a, float))
        if not np.isfinite(np.linalg.cond(v)) or np.linalg.cond(v) > 1e6:
            return None
        pick = [i for i in range(len(mu)) if mu[i].imag >= 0]
        twice = tuple(bool(mu[i].imag > 0) for i in pick)
        return Stages(v[:, pick], np.linalg.inv(v)[pick], mu[pick], twice)

    def factorise(self, h, jac, a_norm):
        """Factors of every block, and 1 + |h A (x) J|_inf (= h |A|_inf |J|_inf)."""
        d = jac.shape[0]
        eye = jnp.eye(d, dtype=jac.dtype)
        blocks = []
        for mu, pair in zip(self.mu, self.twice):
            if pair:
                m = eye.astype(_complex(jac.dtype)) - (h * complex(mu)) * jac
            else:
                m = eye - (h * float(mu.real)) * jac
            blocks.append(lu_factor(m))
        size = 1.0 + h * a_norm * jnp.max(jnp.sum(jnp.abs(jac), axis=1))
        return blocks, size

    def solver(self, factors):
        """(solve, size): solve(r) = (I - h A (x) J)^-1 r for r flat (s d), as V's blocks."""
        blocks, size = factors

        def solve(r):
            s = self.v.shape[0]
            rr = r.reshape(s, -1)
            out = None
            for i, (lu, pair) in enumerate(zip(blocks, self.twice)):
                w = _combine(self.v_inv[i], rr, pair)
                x = lu_solve(lu, w)
                # V's column i times x, and its conjugate's for a pair: twice the real part.
                part = jnp.stack([_times(self.v[j, i], x, pair) for j in range(s)])
                out = part if out is None else out + part
            return out.reshape(-1)
        return solve, size


def _complex(dtype):
    return jnp.result_type(dtype, jnp.complex64)


def _combine(coeffs, rows, pair):
    """sum_j coeffs[j] rows[j], in complex arithmetic for a pair's block."""
    if pair:
        return sum(complex(c) * rows[j] for j, c in enumerate(coeffs))
    return sum(float(c.real) * rows[j] for j, c in enumerate(coeffs))


def _times(c, x, pair):
    """c x, real; for a pair 2 Re(c x), its sum with the conjugate's."""
    if pair:
        return 2.0 * (c.real * x.real - c.imag * x.imag)
    return float(c.real) * x


class Held(NamedTuple):
    """The Jacobian [df/dy] a step's solves use, the factors of its iteration matrices
    (whatever the step's `factorise` makes of it), and, per trajectory, whether it is this
    step's own (taken at its start) rather than one an earlier step kept."""
    jac: jax.Array
    factors: object
    current: jax.Array


def renew(held, jacobian, factorise, need):
    """`held`, with this step's Jacobian `jacobian()` and its factors where `need`: a loop
    that runs once if any trajectory of a batch needs it and not at all otherwise (under
    vmap, lax.cond would compute the Jacobian for every trajectory, every step)."""
    def body(carry):
        jac = jacobian()
        return jnp.asarray(True), Held(jac, factorise(jac), jnp.asarray(True))
    return lax.while_loop(lambda carry: ~carry[0], body, (~need, held))[1]


def keep_next(ok, theta, full):
    """Whether the next step may start from this step's Jacobian (RADAU5's rule): every
    solve converged in the simplified iteration, none by full Newton, at a contraction rate
    of at most THETA_KEEP."""
    return ok & (theta <= THETA_KEEP) & (full == 0)


# Largest contraction rate of the simplified iteration at which the next step keeps the
# Jacobian (RADAU5's default, 0.001): each iteration then gains three digits, so an older
# Jacobian costs at most an iteration, far less than a new one (d evaluations).
THETA_KEEP = 1e-3


# Simplified iterations of a step's first solve run in line before the loop (see _iterate).
IN_LINE = 2


def _iterate(residual, solve_size, z0, y_scale, opts, fresh, done0, lined=False):
    """One Newton iteration loop from z0, skipped where `done0`: with `fresh`,
    `solve_size(z)` gives (solve, size) of the exact Jacobian's iteration matrix at each
    iterate (full Newton); otherwise `solve_size` is the fixed (solve, size).
    `lined`: the first iterations in line (IN_LINE), for a solve every trajectory makes.
    Returns (z, iterations, converged, the last contraction rate)."""
    w = opts.atol + opts.rtol * y_scale
    eps = jnp.finfo(z0.dtype).eps
    limit = opts.max_iter_full if fresh else opts.max_iter

    def cond(st):
        _, k, _, done, _, _ = st
        return (~done) & (k < limit)

    def body(st):
        z, k, prev, _, _, _ = st
        solve, size = solve_size(z) if fresh else solve_size
        r = residual(z)
        dz = solve(r)
        n = jnp.max(jnp.abs(dz) / w)
        res = jnp.max(jnp.abs(r) / w) / size
        finite = jnp.isfinite(n) & jnp.isfinite(res)
        theta = n / prev
        later = k >= 1
        noise = jnp.all(jnp.abs(dz) <= ROUND_OFF_ULPS * eps * (jnp.abs(z) + y_scale))
        # An increment within tolerance that stopped shrinking has met the noise of f's own
        # arithmetic (met by the bicycle at a yaw of 2500 rad): as far as it can go.
        small = n <= 1
        settled = noise | (later & (((theta < 1) & (theta / (1 - theta) * n <= 1)) |
                                    (small & (theta >= 1))))
        ok = finite & settled & (noise | (res <= opts.res_tol))
        # Iterations left after this one at the current rate cannot reach the tolerance.
        # Full Newton converges faster than linearly once close: no such forecast for it.
        hopeless = later & ~small & ((theta >= 1) |
                                     (theta ** (limit - 1 - k) / (1 - theta) * n > 1))
        hopeless = hopeless & (not fresh)
        done = ok | ~finite | hopeless
        return z - dz, k + 1, n, done, ok, theta

    st = (z0, jnp.asarray(0), jnp.asarray(jnp.inf, z0.dtype), done0, jnp.asarray(False),
          jnp.zeros((), z0.dtype))
    if lined and not fresh and 2 <= IN_LINE <= opts.max_iter:
        # The first IN_LINE iterations in line, with no test until the last of them: most
        # solves need no more, and a loop costs more per iteration than its arithmetic.
        # A solve that diverges in them fails the test as it would in the loop.
        solve, _ = solve_size
        z, n = z0, None
        for _ in range(IN_LINE - 1):
            dz = solve(residual(z))
            z, n = z - dz, jnp.max(jnp.abs(dz) / w)
        st = body((z, jnp.asarray(IN_LINE - 1), n, done0, jnp.asarray(False), st[-1]))
    z, k, _, _, ok, theta = lax.while_loop(cond, body, st)
    return z, k, ok, theta


def newton_solve(residual, solve_with, held, refresh, z0, y_scale, opts: NewtonOptions):
    """Solve residual(z) = 0 (z flat) from z0 by the simplified iteration with the held
    Jacobian: `solve_with(held.factors)` gives (solve, size), `solve(r)` applying the factorised
    iteration matrix's inverse, `size` being 1 + |h A (x) J|. Where it fails with a Jacobian
    an earlier step kept, `refresh(held, need)` takes this step's and the iteration starts
    again from z0. Where it still fails (a Jacobian from the step's start can be too far from
    the solution's, as at Robertson's first step) the solve is retried from z0 with full
    Newton, the exact Jacobian of the residual refactorised at every iterate. A retry costs
    nothing when every trajectory of a batch converged. `y_scale` is |y| tiled like z.
    Returns (z, simplified iterations, full iterations, converged, held, contraction rate
    of the simplified iteration)."""
    z1, k1, ok1, theta = _iterate(residual, solve_with(held.factors), z0, y_scale, opts, False,
                                  jnp.asarray(False), lined=True)
    need = ~ok1 & ~held.current
    held = refresh(held, need)
    # Not lax.cond: under vmap it would run the retry for every trajectory; a loop that
    # starts done is skipped unless some trajectory of the batch needs it.
    z2, k2, ok2, theta2 = _iterate(residual, solve_with(held.factors), z0, y_scale, opts, False,
                                   ~need)
    z1, k1 = jnp.where(need, z2, z1), k1 + k2
    ok1, theta = jnp.where(need, ok2, ok1), jnp.where(need, theta2, theta)
    exact = lambda z: solver(factorised(jax.jacfwd(residual)(z)))
    z3, k3, ok3, _ = _iterate(residual, exact, jnp.where(ok1, z1, z0), y_scale, opts, True,
                              ok1)
    return jnp.where(ok1, z1, z3), k1, k3, ok1 | ok3, held, theta
