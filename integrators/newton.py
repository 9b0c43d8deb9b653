"""Simplified Newton iteration for the stage equations of the implicit methods (Hairer &
Wanner, Solving ODEs II, IV.8, as in RADAU5): the caller factorises the iteration matrix once
per step and every iteration reuses it. A solve reports whether it converged: the rate of
convergence theta_k = |dz_k| / |dz_{k-1}| estimates the error left after an increment as
theta/(1 - theta) |dz_k|; the solve stops when that estimate and the residual are both within
tolerance, and gives up early when the iteration diverges (theta >= 1) or cannot reach the
tolerance within the iteration limit at its current rate.

The factorised iteration matrix may be an earlier step's (`Held`): a step keeps it while the
last solve contracted fast, and takes its own where a kept one fails. That choice is made per
chunk of a batch (`any_lane`): a new Jacobian costs the chunk's lanes the same whether one or
all of them need it, so all take it."""
from dataclasses import dataclass
from numbers import Real
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.custom_batching import custom_vmap


# Largest contraction rate of the simplified iteration with which the next step keeps the
# Jacobian (RADAU5's default). A looser rate (RADAU5 advises 0.1 where a Jacobian is costly)
# saved no evaluations on the bicycle, and its solves stop nearer the tolerance than fresh
# Jacobians' do: Radau IIA 5 then no longer showed its order on DETEST A2 at h = 1/8, where
# the Newton tolerance is near its error (see the implicit-speed study of 2026-11-28).
THETA_KEEP = 1e-3
# The same for systems of more than SMALL states, whose Jacobian costs d evaluations and whose
# iteration matrices the looped elimination inverts (RADAU5's advice where Jacobians are
# costly): with THETA_KEEP the CommonRoad 29-state model, whose fresh Jacobian's iteration
# contracts more slowly than that, renewed both at every step
# (docs/studies/radau-d29-2026-11-29.md).
THETA_KEEP_LARGE = 0.1


@dataclass(frozen=True)
class NewtonOptions:
    """Tolerances of one nonlinear solve, on the components weighted by atol + rtol |y|:
    the estimated error of the stage values must be at most 1, and the residual at most
    `res_tol` times 1 + |h A (x) J| (the residual of an iterate is the iteration matrix times
    its error: with res_tol = 1 it is no larger than an error within tolerance makes it).
    At most `max_iter` simplified iterations, then, where they fail, at most `max_iter_full`
    of the full-Newton retry (0: none). A step whose simplified iteration contracted at a
    rate of at most `keep` keeps its Jacobian's factors for the next step (RADAU5's WORK(3);
    below 0: never kept), `keep_large` in place of `keep` for systems of more than SMALL
    states. The driver passes them at run time (Method.run_options): other
    options need no other compiled program."""
    rtol: float = 1e-10
    atol: float = 1e-10
    res_tol: float = 1.0
    max_iter: int = 10
    max_iter_full: int = 40
    keep: float = THETA_KEEP
    keep_large: float = THETA_KEEP_LARGE

    def __post_init__(self):
        for name in ("rtol", "atol", "res_tol", "max_iter", "max_iter_full", "keep",
                     "keep_large"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, Real):
                raise TypeError(f"NewtonOptions.{name} must be a number, got {value!r}")
        if not (self.rtol >= 0 and self.atol >= 0 and self.rtol + self.atol > 0):
            raise ValueError(f"Newton tolerances must be >= 0, not both 0: rtol={self.rtol!r}, "
                             f"atol={self.atol!r}")
        if not (self.res_tol > 0 and int(self.max_iter) == self.max_iter >= 1
                and int(self.max_iter_full) == self.max_iter_full >= 0):
            raise ValueError(f"need res_tol > 0 and integers max_iter >= 1, max_iter_full >= 0:"
                             f" res_tol={self.res_tol!r}, max_iter={self.max_iter!r}, "
                             f"max_iter_full={self.max_iter_full!r}")


class RunOptions(NamedTuple):
    """NewtonOptions' fields as a compiled step reads them: run-time values (tracers inside
    the driver's program), unchecked; see Method.run_options."""
    rtol: object
    atol: object
    res_tol: object
    max_iter: object
    max_iter_full: object
    keep: object
    keep_large: object


# The first iteration whose rate (theta_k, k >= 1) forecasts a solve's failure. The first
# rate, of the increment after the one from the start, measures how far off the start was as
# much as how fast the iteration contracts, and can be far slower than the rates after it;
# forecast from it (RADAU5's rule) over the many orders of magnitude between a start of
# zeros and a tolerance near round-off, it gave up solves that converge well within the
# limit (docs/studies/radau-d29-2026-11-29.md). A diverging iteration (theta >= 1) still
# ends at k = 1.
FORECAST_FROM = 2

# Increments this many ulps of the iterate are round-off: the iteration has converged as far
# as the arithmetic allows, whatever the rate estimate says (it is noise at that level).
ROUND_OFF_ULPS = 8


# Matrices up to this order are factorised by the unrolled elimination below; larger ones
# (Radau IIA 5's 3d stage system) by the same elimination in a loop over the columns: an
# unrolled n^3 of operations at order 15 did not finish compiling in minutes. Neither calls
# LAPACK, whose batched getrf hung when two host devices ran it at once (XLA CPU, jax 0.10.2:
# both waited in its batch map), so a batch of any implicit method can be shared among them.
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
        return _lu_factor_loop(mat)
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


def _lu_factor_loop(mat):
    """lu_factor's elimination as a loop over the columns, each a step on whole rows (as
    arrays): (lu, pivots) with the pivots an integer array."""
    n = mat.shape[0]
    rows = jnp.arange(n)

    def column(k, carry):
        a, pivots = carry
        p = jnp.argmax(jnp.where(rows >= k, jnp.abs(a[:, k]), -1))
        a = _swap_rows(a, rows, k, p)
        below = rows > k
        lower = jnp.where(below, a[:, k] / a[k, k], 0)
        a = a - jnp.outer(lower, jnp.where(below, a[k], 0))
        a = jnp.where(rows == k, jnp.where(below, lower, a[:, k])[:, None], a)
        return a, jnp.where(rows == k, p, pivots)

    # Pivots like mat's rows, so that under shard_map the loop's carry varies as mat does.
    return lax.fori_loop(0, n - 1, column, (mat, jnp.zeros_like(mat, int, shape=(n,))))


def _lu_solve_loop(factors, r):
    """mat^-1 r from `_lu_factor_loop(mat)`, a loop over the rows. Each row's product with
    x is a sum by `halved`, not a dot: XLA:CPU makes a float32 dot over a batch a library
    call (YNNPACK), and then the full-Newton retry's loop, and the step loop around it, are
    not compiled as one native function."""
    lu, pivots = factors
    n = lu.shape[0]
    rows = jnp.arange(n)

    def swap(k, x):
        return _swap_rows(x, rows, k, pivots[k])

    def forward(i, x):
        return jnp.where(rows == i, x - _row_times(jnp.where(rows < i, lu[i], 0), x), x)

    def back(j, x):
        i = n - 1 - j
        xi = (x[i] - _row_times(jnp.where(rows > i, lu[i], 0), x)) / lu[i, i]
        return jnp.where(rows == i, xi, x)

    x = lax.fori_loop(0, n - 1, swap, r)
    return lax.fori_loop(0, n, back, lax.fori_loop(0, n, forward, x))


def _row_times(row, x):
    """row @ x (x a vector, or a matrix whose rows row weighs) as `halved` sums."""
    return halved(row.reshape((-1,) + (1,) * (x.ndim - 1)) * x, jnp.add)


def _swap_rows(a, rows, k, p):
    """a (a matrix or vector) with rows k and p exchanged, by selection: `.at[].set` with an
    index that varies across a vmapped batch is a scatter, and a loop holding a scatter is
    not compiled into one native function by XLA:CPU."""
    mask = lambda i: (rows == i).reshape((-1,) + (1,) * (a.ndim - 1))
    return jnp.where(mask(k), a[p], jnp.where(mask(p), a[k], a))


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
        return _lu_solve_loop(factors, r)
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


def _size(mat):
    """1 + |mat - I|_inf: the size against which a residual is judged."""
    return 1.0 + inf_norm(mat - jnp.eye(mat.shape[0], dtype=mat.dtype))


def inf_norm(mat):
    """max_i sum_j |mat_ij|, the sum over the columns taken by halving (`halved`): XLA:CPU
    makes a reduction over a batch of matrices a library call, and a loop holding one is
    not compiled as one native function."""
    return largest(halved(jnp.abs(mat).T, jnp.add))


def halved(v, op):
    """op's reduction over v's first axis as op of its two halves, repeated: about log2(n)
    elementwise operations, so that no reduction (a library call to XLA:CPU beyond some
    size) is compiled, and the traced program grows as log2(n), not n."""
    while v.shape[0] > 1:
        half = v.shape[0] // 2
        v = jnp.concatenate([op(v[:half], v[half:2 * half]), v[2 * half:]])
    return v[0]


def largest(v):
    """max(v) of a vector, as NaN-propagating as jnp.max, by `halved`."""
    return halved(v, jnp.maximum)


def factorised(mat):
    """(solve, 1 + |mat - I|_inf): the LU factors of an iteration matrix, applied by `solve`,
    and the size against which a residual is judged."""
    lu = lu_factor(mat)
    return (lambda r: lu_solve(lu, r)), _size(mat)


def factors(mat):
    """(factors, 1 + |mat - I|_inf) of an iteration matrix that steps may keep, as data:
    `lu_factor`'s up to order SMALL, above it the inverse. A kept matrix is applied far more
    often than it is made, and a product with the inverse is one vectorised operation where
    the looped substitution is a loop over the rows."""
    return (lu_factor(mat) if mat.shape[0] <= SMALL else inverse(mat)), _size(mat)


def solver(fac):
    """(solve, size) of `factors`' result: solve(r) = mat^-1 r."""
    f, size = fac
    return (lambda r: apply(f, r)), size


def inverse(mat):
    """mat^-1 by Gauss-Jordan elimination with partial pivoting, in place and looped over the
    columns: n^3 multiply-adds where the LU factors and a substitution of each column of I
    took about 3 n^3 (the same residual |mat X - I| on random matrices)."""
    n = mat.shape[0]
    rows = jnp.arange(n)

    def column(k, carry):
        a, perm = carry
        p = jnp.argmax(jnp.where(rows >= k, jnp.abs(a[:, k]), -1))
        a, perm = _swap_rows(a, rows, k, p), _swap_rows(perm, rows, k, p)
        pivot_row = jnp.where(rows == k, 1.0, a[k]) / a[k, k]
        factor = jnp.where(rows == k, 0.0, a[:, k])
        a = jnp.where(rows == k, 0.0, a) - jnp.outer(factor, pivot_row)
        return jnp.where((rows == k)[:, None], pivot_row, a), perm

    # The row order like mat, so that under shard_map the loop's carry varies as mat does.
    b, perm = lax.fori_loop(0, n, column, (mat, jnp.zeros_like(mat, int, shape=(n,)) + rows))
    # b inverts mat's rows in the order perm; mat^-1 is b with its columns put back in order.
    return b[:, jnp.argmax(perm[:, None] == rows, axis=0)]


def apply(f, r):
    """mat^-1 r from `lu_factor(mat)` (a tuple) or from mat's `inverse`."""
    return lu_solve(f, r) if isinstance(f, tuple) else f @ r


class Stages(NamedTuple):
    """I - h A (x) J for a diagonalisable A = V diag(mu) V^-1, transformed as RADAU5 does
    (HW IV.8): one d x d system I - h mu J per real eigenvalue mu and one per complex pair,
    written as the real 2d x 2d system [[I - h Re mu J, h Im mu J], [-h Im mu J,
    I - h Re mu J]] on (Re x, Im x), instead of the s d x s d system. Each is inverted by a
    looped elimination (`inverse`; the unrolled elimination of the real block alone took
    longer to compile than the whole method had), and the inverses kept: see `factors`. `mu` are the
    eigenvalues solved for (of a pair, the one with Im mu > 0), `twice` says which stand for a
    pair; `v` their columns of V, `v_inv` their rows of V^-1 (NumPy constants)."""
    v: np.ndarray
    v_inv: np.ndarray
    mu: np.ndarray
    twice: tuple

    @staticmethod
    def of(a):
        """The transformation of A, or None where A is not diagonalisable with a
        well-conditioned V (then the s d x s d system is factorised whole)."""
        mu, v = np.linalg.eig(np.asarray(a, float))
        cond = np.linalg.cond(v)
        if not np.isfinite(cond) or cond > 1e6:
            return None
        pick = [i for i in range(len(mu)) if mu[i].imag >= 0]
        twice = tuple(bool(mu[i].imag > 0) for i in pick)
        return Stages(v[:, pick], np.linalg.inv(v)[pick], mu[pick], twice)

    def factors(self, h, jac, a_norm):
        """(factors of every block, 1 + |h A (x) J|_inf), |h A (x) J|_inf being
        h |A|_inf |J|_inf; a_norm is |A|_inf."""
        d = jac.shape[0]
        eye = jnp.eye(d, dtype=jac.dtype)
        blocks = []
        for mu, pair in zip(self.mu, self.twice):
            re = eye - (h * float(mu.real)) * jac
            if pair:
                im = (h * float(mu.imag)) * jac
                re = jnp.block([[re, im], [-im, re]])
            blocks.append(inverse(re))
        return blocks, 1.0 + h * a_norm * inf_norm(jac)

    def solver(self, fac):
        """(solve, size) of `factors`' result, solve(r) = (I - h A (x) J)^-1 r."""
        blocks, size = fac
        s = self.v.shape[0]

        def solve(r):
            rr = r.reshape(s, -1)
            d = rr.shape[1]
            out = 0.0
            for i, (inv, pair) in enumerate(zip(blocks, self.twice)):
                w = _combine(self.v_inv[i].real, rr)
                if pair:
                    x = apply(inv, jnp.concatenate([w, _combine(self.v_inv[i].imag, rr)]))
                    # V's column i times x plus its conjugate's: twice the real part.
                    part = [float(2 * c.real) * x[:d] - float(2 * c.imag) * x[d:]
                            for c in self.v[:, i]]
                else:
                    x = apply(inv, w)
                    part = [float(c.real) * x for c in self.v[:, i]]
                out = out + jnp.stack(part)
            return out.reshape(-1)
        return solve, size

    def factorised(self, h, jac, a_norm):
        """(solve, 1 + |h A (x) J|_inf) as `factorised` gives them for the whole system."""
        return self.solver(self.factors(h, jac, a_norm))


def _combine(coeffs, rows):
    """sum_j coeffs[j] rows[j] (real coefficients)."""
    return sum(float(c) * rows[j] for j, c in enumerate(coeffs))


def _iterate(residual, solver, z0, y_scale, opts, fresh, done0):
    """One Newton iteration loop from z0, skipped where `done0`: with `fresh`, `solver(z)`
    gives (solve, size) of the exact Jacobian's iteration matrix at each iterate (full
    Newton); otherwise `solver` is the fixed (solve, size). Returns (z, iterations,
    converged, the last contraction rate)."""
    w = opts.atol + opts.rtol * y_scale
    eps = jnp.finfo(z0.dtype).eps
    limit = opts.max_iter_full if fresh else opts.max_iter

    def cond(st):
        _, k, _, done, _, _ = st
        return (~done) & (k < limit)

    def body(st):
        z, k, prev, _, _, _ = st
        solve, size = solver(z) if fresh else solver
        r = residual(z)
        dz = solve(r)
        n = largest(jnp.abs(dz) / w)
        res = largest(jnp.abs(r) / w) / size
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
        # Iterations left after this one at the current rate cannot reach the tolerance,
        # forecast from the second rate on: the first (k = 1) holds the start's transient,
        # which can be slower than the iteration's own rate (FORECAST_FROM).
        # Full Newton converges faster than linearly once close: no such forecast for it.
        forecast = (k >= FORECAST_FROM) & (theta ** (limit - 1 - k) / (1 - theta) * n > 1)
        hopeless = later & ~small & ((theta >= 1) | forecast)
        hopeless = hopeless & (not fresh)
        done = ok | ~finite | hopeless
        return z - dz, k + 1, n, done, ok, jnp.where(later, theta, 0)

    # Every carry is derived from the data, so that under shard_map it varies across devices
    # as the body's values do (a constant would not, and the loop would be refused).
    init = (z0, jnp.zeros_like(y_scale, int, shape=()),
            jnp.full_like(y_scale, jnp.inf, shape=()), done0,
            jnp.zeros_like(y_scale, bool, shape=()), jnp.zeros_like(y_scale, shape=()))
    z, k, _, _, ok, theta = lax.while_loop(cond, body, init)
    return z, k, ok, theta


@custom_vmap
def any_lane(flag):
    """Whether `flag` holds for any trajectory of the batch being vmapped (of a driver's
    chunk), the same unbatched answer for all; a single trajectory's flag itself. A loop
    whose predicate it gives runs for all lanes or none, as one loop: a batched predicate
    would make every iteration select, lane by lane, what to keep."""
    return flag


@any_lane.def_vmap
def _any_lane_batched(axis_size, in_batched, flag):
    return (jnp.any(flag, axis=0) if in_batched[0] else flag), False


class Held(NamedTuple):
    """What an implicit step carries to the next: the factors of its iteration matrices (as
    the step's `factorise` makes them of a Jacobian, with their sizes), whether the next
    step may keep them (`keep`), and whether they are the current step's own (`current`,
    taken at its start)."""
    factors: object
    keep: jax.Array
    current: jax.Array


def renew(held, factorise, need):
    """`held` with the current step's factors `factorise()` where `need` (one flag for a
    whole chunk, `any_lane`'s): a loop that runs once or not at all, since sin and cos are
    made vectorisable inside loops and not inside lax.cond."""
    def body(carry):
        done, _ = carry
        fresh = factorise()
        return done | True, Held(fresh, held.keep | True, held.current | True)
    return lax.while_loop(lambda carry: ~carry[0], body, (~need, held))[1]


def newton_solve(residual, solver_of, factorise, held, z0, y_scale, opts: NewtonOptions,
                 residual_jacobian=None):
    """Solve residual(z) = 0 (z flat) from z0 by the simplified iteration with the factors
    `held` carries (`solver_of(factors)` gives (solve, size): `solve(r)` applies the
    iteration matrix's inverse, `size` is 1 + |h A (x) J|), or, where the step may not keep
    them, with its own (`factorise()`). Where the kept ones fail, the step's own are taken
    and the failed trajectories start again from z0. Where the step's own fail too (a
    Jacobian from the step's start can be too far from the solution's, as at Robertson's
    first step) the solve is retried from z0 with full Newton, the exact Jacobian of the
    residual (`residual_jacobian(z)`, by default forward mode through `residual`)
    refactorised at every iterate (left out of the program where `without_retry(opts)`).
    Each retry costs nothing when every trajectory of the chunk converged. `y_scale` is |y|
    tiled like z. Returns (z, simplified iterations, full iterations, converged, held, the
    simplified iteration's last contraction rate)."""
    def cond(st):
        held, _, tries, ok, _, _ = st
        return any_lane(tries == 0) | (any_lane(~ok) & ~any_lane(held.current))

    def body(st):
        held, z, tries, ok, k, theta = st
        # The step's own where it may not keep them, or after they failed (a retry only
        # runs while the held ones are not the step's own).
        need = any_lane(~held.keep | (tries > 0)) & ~any_lane(held.current)
        held = renew(held, factorise, need)
        z1, k1, ok1, theta1 = _iterate(residual, solver_of(held.factors), z0, y_scale, opts,
                                       False, ok)
        return (held, jnp.where(ok, z, z1), tries + 1, ok | ok1, k + k1,
                jnp.where(ok, theta, theta1))

    none = jnp.zeros_like(y_scale, bool, shape=())
    zero = jnp.zeros_like(y_scale, int, shape=())
    held, z1, _, ok1, k1, theta = lax.while_loop(
        cond, body, (held, z0, zero, none, zero, jnp.zeros_like(y_scale, shape=())))
    if without_retry(opts):
        return z1, k1, zero, ok1, held, theta
    jac = jax.jacfwd(residual) if residual_jacobian is None else residual_jacobian
    exact = lambda z: factorised(jac(z))
    z2, k2, ok2, _ = _iterate(residual, exact, jnp.where(ok1, z1, z0), y_scale, opts, True, ok1)
    return jnp.where(ok1, z1, z2), k1, k2, ok1 | ok2, held, theta


def without_retry(opts) -> bool:
    """Whether a step compiled with these options leaves the full-Newton retry out: its
    `max_iter_full` is the number 0 when the step is traced, not a run-time value. A failed
    solve ends the same either way (the step makes its result NaN), and the program is
    smaller to compile: the driver's first try (driver.integrate)."""
    return isinstance(opts.max_iter_full, int) and opts.max_iter_full == 0


def keep_next(ok, theta, full, opts, d: int):
    """Whether the next step of a d-state system may keep this step's factors: its solves
    converged by the simplified iteration alone, contracting at a rate of at most `keep`,
    or `keep_large` above SMALL states (NewtonOptions)."""
    return ok & (full == 0) & (theta <= (opts.keep if d <= SMALL else opts.keep_large))
