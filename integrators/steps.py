"""The one generic step of each family: explicit RK, implicit RK (simplified Newton with a
Jacobian and its factorisation kept across steps while the iteration contracts fast: see
newton.Held), Rosenbrock (one Jacobian, one factorisation and one
linear solve per stage, no Newton) and linear multistep (explicit or implicit).
`fun(t, y)` is the right-hand side with inputs and parameters already bound; every step
returns (y_next, state) and counts its evaluations in state["evals"] (implicit: the Jacobian
counts as d evaluations, one per column, in the steps that take one). An implicit step whose
solve fails returns NaN and clears state["converged"]; a step from a state that has already
blown up (the method's own instability) is no solver failure."""
import jax
import jax.numpy as jnp
import numpy as np

from stepzoo.integrators.multistep import LinearMultistep
from stepzoo.integrators.newton import (Held, Stages, factorised, factors, keep_next,
                                        newton_solve, solver)


def rk_slopes(a, c, fun, t, y, h, needed=None, k0=None) -> list:
    """Slopes k_i = fun(t + c_i h, y + h sum_j a_ij k_j) of an explicit tableau (a, c), in
    plain arithmetic with Python-float coefficients, so that JAX arrays of any float dtype
    and CasADi symbols alike go through. Stages not `needed` are None; `k0` is a known first
    slope (first same as last)."""
    k: list = []
    for i in range(len(c)):
        if needed is not None and not needed[i]:
            k.append(None)
        elif i == 0 and k0 is not None:
            k.append(k0)
        else:
            yi = y
            for j in range(i):
                if a[i][j] != 0.0:
                    yi = yi + (h * float(a[i][j])) * k[j]
            k.append(fun(t + float(c[i]) * h, yi))
    return k


def weighted(weights, k):
    """sum_i w_i k_i over the non-zero weights, in plain arithmetic like `rk_slopes`."""
    terms = [float(w) * ki for w, ki in zip(weights, k) if w != 0.0]
    return sum(terms[1:], terms[0])


def explicit_rk_step(tab, fun, t, y, h, state):
    """One step of an explicit tableau, evaluating only the stages it needs."""
    k = rk_slopes(tab.a, tab.c, fun, t, y, h, tab.needed)
    return y + h * weighted(tab.b, k), dict(state, evals=state["evals"] + tab.evals_per_step)


def jacobian(fun, t, y):
    """df/dy at (t, y) by forward mode: d evaluations' worth of work."""
    return jax.jacfwd(lambda v: fun(t, v))(y)


def iteration_matrices(scheme, h):
    """(factorise, solver_of) of an implicit step of `scheme` with step h: factorise(J) makes
    the factors of its iteration matrices, I - h beta_k J (multistep), I - h a_ii J per
    distinct diagonal entry (diagonally implicit, a dict by entry) or the stage system
    I - h A (x) J (transformed where A allows, newton.Stages); solver_of(factors) gives
    (solve, size) of the one a solve uses (a function of the entry a_ii where diagonally
    implicit)."""
    if isinstance(scheme, LinearMultistep):
        bk = float(scheme.beta[-1])
        return (lambda jac: factors(_eye(jac) - (h * bk) * jac)), solver
    if scheme.diagonally_implicit:
        diag = sorted({float(g) for g in np.diag(scheme.a) if g != 0.0})
        return ((lambda jac: {g: factors(_eye(jac) - (h * g) * jac) for g in diag}),
                lambda g: lambda fac: solver(fac[g]))
    stages = Stages.of(scheme.a)
    if stages is None:
        a = np.asarray(scheme.a)
        return ((lambda jac: factors(jnp.eye(a.shape[0] * jac.shape[0], dtype=jac.dtype)
                                     - h * jnp.kron(jnp.asarray(a, jac.dtype), jac))), solver)
    a_norm = float(np.max(np.sum(np.abs(scheme.a), axis=1)))
    return (lambda jac: stages.factors(h, jac, a_norm)), stages.solver


def _eye(jac):
    return jnp.eye(jac.shape[0], dtype=jac.dtype)


def held_state(scheme, y0):
    """The factors an implicit step of `scheme` carries to the next, before the first: of
    the identity, shaped as the steps' and not to be kept (the first step takes its own)."""
    jac = jnp.zeros_like(y0, shape=y0.shape * 2)
    no = jnp.zeros_like(y0, bool, shape=())
    return Held(iteration_matrices(scheme, 0.0)[0](jac), no, no)


def _held(scheme, fun, t, y, h, state):
    """(held, factorise) at a step's start: the factors the last step left, none of them the
    step's own yet; factorise() makes the step's own, from the Jacobian at (t, y)."""
    make = iteration_matrices(scheme, h)[0]
    held = state["held"]
    return held._replace(current=held.current & False), lambda: make(jacobian(fun, t, y))


def _finish(y, y_next, ok, state, evals, held, keep):
    """NaN after a failed solve. The flag is cleared only by a failure from a state below
    finfo.max^(1/4) (1e77 in float64): beyond it the method has already blown up, and its
    right-hand side's arithmetic overflows whatever the solver does. A step that took its
    own Jacobian counts its d evaluations."""
    failed = ~ok & jnp.all(jnp.abs(y) < jnp.finfo(y.dtype).max ** 0.25)
    y_next = jnp.where(ok, y_next, jnp.nan)
    evals = evals + jnp.where(held.current, y.shape[0], 0).astype(evals.dtype)
    return y_next, dict(state, evals=evals, converged=state["converged"] & ~failed,
                        unsolved=state["unsolved"] | ~ok, held=held._replace(keep=keep))


def stage_system(tab, fun, t, y, h):
    """(stage_f, residual, residual_jacobian) of an implicit tableau's stage equations in
    z = (Y_i - y)_i, flat: stage_f(z) the slopes f(t + c_i h, Y_i) (s, d); residual(z) =
    z - h (A (x) I) F(z); residual_jacobian(z) its Jacobian, the blocks
    delta_ij I - h a_ij J(Y_j). Both take f and its Jacobian at the stages as one vmap over
    them, so that a compiled step holds f and its derivative once each, not once a stage."""
    d, s = y.shape[0], tab.stages
    a = jnp.asarray(tab.a, y.dtype)
    c = jnp.asarray(tab.c, y.dtype)

    def stage_f(z):
        return jax.vmap(lambda ci, zi: fun(t + ci * h, y + zi))(c, z.reshape(s, d))

    def residual(z):
        # Sums with the coefficients as constants, not a product with A: XLA:CPU makes that
        # product a library call, and a loop holding one is not compiled as one function.
        fz = stage_f(z)
        return z - h * jnp.concatenate([weighted(row, fz) if np.any(row) else 0.0 * fz[0]
                                        for row in tab.a])

    def residual_jacobian(z):
        jacs = jax.vmap(lambda ci, zi: jacobian(fun, t + ci * h, y + zi))(c, z.reshape(s, d))
        blocks = (-h * a)[:, :, None, None] * jacs[None]
        return jnp.eye(s * d, dtype=y.dtype) + blocks.transpose(0, 2, 1, 3).reshape(s * d, -1)

    return stage_f, residual, residual_jacobian


def implicit_rk_step(tab, opts, fun, t, y, h, state):
    """One step of an implicit tableau. A diagonally implicit one (a_ij = 0 for j > i) solves
    its stages one by one, each with I - h a_ii J (one factorisation per distinct a_ii);
    any other solves all stages at once with I - h A (x) J, through A's eigenvalues where A
    allows (newton.Stages). J is the step's own or an earlier step's (newton.Held)."""
    held, factorise = _held(tab, fun, t, y, h, state)
    if tab.diagonally_implicit:
        return _dirk_step(tab, opts, fun, t, y, h, state, held, factorise)
    d = y.shape[0]
    s = tab.stages
    stage_f, residual, residual_jacobian = stage_system(tab, fun, t, y, h)
    scale = jnp.tile(jnp.abs(y), s)
    # Starting from zeros like y's: see newton._iterate on carries under shard_map.
    z, k1, k2, ok, held, theta = newton_solve(residual, iteration_matrices(tab, h)[1],
                                              factorise, held, jnp.zeros_like(scale), scale,
                                              opts, residual_jacobian)
    zz = z.reshape(s, d)
    evals = state["evals"] + k1 * s + k2 * (s + s * d)
    if np.linalg.matrix_rank(tab.a) == s:
        # y + h b^T F = y + b^T A^-1 Z: no evaluation of f, whose h*lambda-sized values
        # would cancel badly on stiff problems.
        y_next = y + weighted(np.linalg.solve(tab.a.T, tab.b), zz)
    else:
        y_next = y + h * (jnp.asarray(tab.b, y.dtype) @ stage_f(z))
        evals = evals + s
    return _finish(y, y_next, ok, state, evals, held, keep_next(ok, theta, k2, opts, d))


def _dirk_step(tab, opts, fun, t, y, h, state, held, factorise):
    """Stages in order: Y_i = y + h sum_{j<i} a_ij k_j + z_i with z_i = h a_ii f(Y_i); the
    slope k_i = z_i / (h a_ii) costs no evaluation. Newton starts every stage from z_i = 0:
    a start from a slope lands stiff problems on another root."""
    ks, ok, evals = [], jnp.asarray(True), state["evals"]
    theta, full = jnp.zeros_like(y, shape=()), 0
    solver_of = iteration_matrices(tab, h)[1]
    for i in range(tab.stages):
        known = y
        for j in range(i):
            if tab.a[i, j] != 0.0:
                known = known + (h * float(tab.a[i, j])) * ks[j]
        ti, gii = t + float(tab.c[i]) * h, float(tab.a[i, i])
        if gii == 0.0:
            ks.append(fun(ti, known))
            evals = evals + 1
            continue
        # The residual is solved at once, inside this iteration: late binding is harmless.
        z, k1, k2, ok_i, held, theta_i = newton_solve(
            lambda z: z - (h * gii) * fun(ti, known + z), solver_of(gii), factorise, held,  # noqa: B023
            jnp.zeros_like(y), jnp.abs(y), opts)
        ks.append(z / (h * gii))
        ok, evals = ok & ok_i, evals + k1 + k2 * (1 + y.shape[0])
        theta, full = jnp.maximum(theta, theta_i), full + k2
    if tab.stiffly_accurate:
        y_next = known + z          # the last stage is the solution: no cancellation
    else:
        y_next = y + h * weighted(tab.b, ks)
    keep = keep_next(ok, theta, full, opts, y.shape[0])
    return _finish(y, y_next, ok, state, evals, held, keep)


def rosenbrock_step(ros, fun, t, y, h, state):
    """One step of a Rosenbrock method, in its form without products with J (HW (7.25)):
    (I - h gamma J) u_i = h gamma f(t + alpha_i h, y + sum_j a_ij u_j) + gamma sum_j c_ij u_j
    + gamma gamma_i h^2 f_t, y_1 = y + sum_i m_i u_i. The derivatives [f_t, J] count d + 1
    evaluations (one per column), each distinct stage argument one more. There is no
    nonlinear solve, so `converged` stays as it is: a non-finite state is the method's own
    result (its R(z) has a pole at z = 1/gamma, on the unstable side)."""
    d = y.shape[0]
    t = jnp.asarray(t, y.dtype)
    # f(t, y), the first stage's value, comes with the derivatives' forward pass.
    (f_t, jac), f0 = jax.jacfwd(lambda tt, yy: (fun(tt, yy),) * 2, argnums=(0, 1),
                                has_aux=True)(t, y)
    g = ros.gamma_diag
    solve, _ = factorised(jnp.eye(d, dtype=y.dtype) - (h * g) * jac)
    us, fs = [], []
    for i in range(ros.stages):
        if ros.same_as[i] < i:
            fs.append(fs[ros.same_as[i]])
        elif i == 0:
            fs.append(f0)
        else:
            yi = y
            for j in range(i):
                if ros.a_u[i, j] != 0.0:
                    yi = yi + float(ros.a_u[i, j]) * us[j]
            fs.append(fun(t + float(ros.nodes[i]) * h, yi))
        rhs = (h * g) * fs[i]
        if ros.gamma_sums[i] != 0.0:
            rhs = rhs + (g * float(ros.gamma_sums[i]) * h * h) * f_t
        for j in range(i):
            if ros.c_u[i, j] != 0.0:
                rhs = rhs + (g * float(ros.c_u[i, j])) * us[j]
        us.append(solve(rhs))
    evals = state["evals"] + d + 1 + ros.evals_per_step
    return y + weighted(ros.m_u, us), dict(state, evals=evals)


def multistep_step(lmm, opts, fun, t, y, h, state):
    """One step of sum_j alpha_j y_{n+j} = h sum_j beta_j f_{n+j}; state holds the last k
    values `ys` and slopes `fs`, oldest first; t is the time of the newest."""
    k = lmm.steps
    ys, fs = state["ys"], state["fs"]
    known = -jnp.tensordot(jnp.asarray(lmm.alpha[:k], y.dtype), ys, 1) \
        + h * jnp.tensordot(jnp.asarray(lmm.beta[:k], y.dtype), fs, 1)
    t_next = t + h
    # The new state's slope, which the next steps need (BDF's do not: it is not taken).
    evals = state["evals"] + (1.0 if lmm.uses_slopes else 0.0)
    if lmm.explicit:
        y_next, state = known, dict(state, evals=evals)
    else:
        bk = float(lmm.beta[k])
        d = y.shape[0]
        held, factorise = _held(lmm, fun, t, y, h, state)
        y_next, k1, k2, ok, held, theta = newton_solve(
            lambda v: v - (h * bk) * fun(t_next, v) - known, solver, factorise, held,
            jnp.tensordot(jnp.asarray(lmm.predictor, y.dtype), ys, 1), jnp.abs(y), opts)
        y_next, state = _finish(y, y_next, ok, state, evals + k1 + k2 * (1 + d), held,
                                keep_next(ok, theta, k2, opts, d))
    ys = jnp.concatenate([ys[1:], y_next[None]])
    if lmm.uses_slopes:
        fs = jnp.concatenate([fs[1:], fun(t_next, y_next)[None]])
    return y_next, dict(state, ys=ys, fs=fs)
