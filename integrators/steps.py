"""The one generic step of each family: explicit RK, implicit RK (simplified Newton: one
Jacobian and one factorisation per step), Rosenbrock (one Jacobian, one factorisation and one
linear solve per stage, no Newton) and linear multistep (explicit or implicit).
`fun(t, y)` is the right-hand side with inputs and parameters already bound; every step
returns (y_next, state) and counts its evaluations in state["evals"] (implicit: the Jacobian
counts as d evaluations, one per column). An implicit step whose solve fails returns NaN and
clears state["converged"]; a step from a state that has already blown up (the method's own
instability) is no solver failure."""
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from stepzoo.integrators.newton import factorised, newton_solve


def rk_slopes(a, c, fun, t, y, h, needed=None, k0=None) -> list:
    """Slopes k_i = fun(t + c_i h, y + h sum_j a_ij k_j) of an explicit tableau (a, c), in
    plain arithmetic with Python-float coefficients, so that JAX arrays of any float dtype
    and CasADi symbols alike go through. Stages not `needed` are None; `k0` is a known first
    slope (first same as last)."""
    k = []
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


def _finish(y, y_next, ok, state, evals):
    """NaN after a failed solve. The flag is cleared only by a failure from a state below
    finfo.max^(1/4) (1e77 in float64): beyond it the method has already blown up, and its
    right-hand side's arithmetic overflows whatever the solver does."""
    failed = ~ok & jnp.all(jnp.abs(y) < jnp.finfo(y.dtype).max ** 0.25)
    y_next = jnp.where(ok, y_next, jnp.nan)
    return y_next, dict(state, evals=evals, converged=state["converged"] & ~failed)


def _where_needed(need, make, default):
    """make() where `need`, else `default` (same structure). A loop of at most one pass
    rather than lax.cond, which under vmap would run `make` for every trajectory: the pass
    runs only when some trajectory of the batch needs it."""
    return lax.while_loop(lambda c: c[0], lambda c: (jnp.zeros_like(c[0]), make()),
                          (need, default))[1]


def _solve_reusing(attempt, opts, fun, t, y, state):
    """An implicit step's solve with RADAU5's Jacobian reuse. `attempt(jac, opts)` solves the
    step with iteration matrices built from `jac`: (y_next, converged, evaluations, rate of
    convergence). The Jacobian kept in the state (`jac`, valid where `reuse`) is tried first,
    without the full-Newton retry; where it is not valid or fails, a new one at (t, y) and
    today's solve with it (retry included), whose outcome is the step's. Returns (y_next,
    converged, evaluations, state with the Jacobian to keep). A state without `jac` (a
    single step outside the driver) takes a new Jacobian."""
    d = y.shape[0]
    if "jac" not in state:
        y_next, ok, evals, _ = attempt(jacobian(fun, t, y), opts)
        return y_next, ok, evals + d, state
    reuse, kept = state["reuse"], state["jac"]
    quick = dataclasses.replace(opts, max_iter_full=0)
    none = jax.tree.map(lambda v: jnp.zeros(v.shape, v.dtype),
                        jax.eval_shape(lambda j: attempt(j, opts), kept))
    y_a, ok_a, evals_a, theta_a = _where_needed(reuse, lambda: attempt(kept, quick), none)
    fresh = ~(reuse & ok_a)
    jac = _where_needed(fresh, lambda: jacobian(fun, t, y), kept)
    y_b, ok_b, evals_b, theta_b = _where_needed(fresh, lambda: attempt(jac, opts), none)
    pick = lambda b, a: jnp.where(fresh, b, a)
    ok, theta = pick(ok_b, ok_a), pick(theta_b, theta_a)
    evals = jnp.where(reuse, evals_a, 0) + jnp.where(fresh, evals_b + d, 0)
    state = dict(state, jac=jac, reuse=ok & (theta <= opts.reuse_theta))
    return pick(y_b, y_a), ok, evals, state


def implicit_rk_step(tab, opts, fun, t, y, h, state):
    """One step of an implicit tableau. A diagonally implicit one (a_ij = 0 for j > i) solves
    its stages one by one, each with I - h a_ii J (one factorisation per distinct a_ii);
    any other solves all stages at once with I - h A (x) J."""
    attempt = _dirk_attempt if tab.diagonally_implicit else _collocation_attempt
    y_next, ok, evals, state = _solve_reusing(
        lambda jac, o: attempt(tab, o, fun, t, y, h, jac), opts, fun, t, y, state)
    return _finish(y, y_next, ok, state, state["evals"] + evals)


def _collocation_attempt(tab, opts, fun, t, y, h, jac):
    """All s stages at once with I - h A (x) J: (y_next, converged, evaluations, rate)."""
    d = y.shape[0]
    s = tab.stages
    a = jnp.asarray(tab.a, y.dtype)

    def stage_f(z):
        zz = z.reshape(s, d)
        return jnp.stack([fun(t + float(tab.c[i]) * h, y + zz[i]) for i in range(s)])

    def residual(z):
        return z - h * (a @ stage_f(z)).reshape(-1)

    solver = lambda z: factorised(jnp.eye(s * d, dtype=y.dtype) - h * jnp.kron(a, jac))
    z, k1, k2, ok, theta = newton_solve(residual, solver, jnp.zeros(s * d, y.dtype),
                                        jnp.tile(jnp.abs(y), s), opts)
    zz = z.reshape(s, d)
    evals = k1 * s + k2 * (s + s * d)
    if np.linalg.matrix_rank(tab.a) == s:
        # y + h b^T F = y + b^T A^-1 Z: no evaluation of f, whose h*lambda-sized values
        # would cancel badly on stiff problems.
        y_next = y + jnp.asarray(np.linalg.solve(tab.a.T, tab.b), y.dtype) @ zz
    else:
        y_next = y + h * (jnp.asarray(tab.b, y.dtype) @ stage_f(z))
        evals = evals + s
    return y_next, ok, jnp.asarray(evals, y.dtype), theta


def _dirk_attempt(tab, opts, fun, t, y, h, jac):
    """Stages in order: Y_i = y + h sum_{j<i} a_ij k_j + z_i with z_i = h a_ii f(Y_i); the
    slope k_i = z_i / (h a_ii) costs no evaluation. (y_next, converged, evaluations, the
    slowest stage's rate)."""
    eye = jnp.eye(y.shape[0], dtype=y.dtype)
    ks, ok, evals, theta = [], jnp.asarray(True), jnp.asarray(0.0, y.dtype), \
        jnp.asarray(0.0, y.dtype)
    solvers = {}        # one factorisation per distinct diagonal entry
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
        if gii not in solvers:
            solvers[gii] = factorised(eye - (h * gii) * jac)
        z, k1, k2, ok_i, theta_i = newton_solve(lambda z: z - (h * gii) * fun(ti, known + z),
                                                lambda _, f=solvers[gii]: f,
                                                jnp.zeros_like(y), jnp.abs(y), opts)
        ks.append(z / (h * gii))
        ok, evals = ok & ok_i, evals + k1 + k2 * (1 + y.shape[0])
        theta = jnp.maximum(theta, theta_i)
    if tab.stiffly_accurate:
        y_next = known + z          # the last stage is the solution: no cancellation
    else:
        y_next = y + h * weighted(tab.b, ks)
    return y_next, ok, evals, theta


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
    evals = state["evals"] + 1.0
    if lmm.explicit:
        y_next, state = known, dict(state, evals=evals)
    else:
        bk = float(lmm.beta[k])
        guess = jnp.tensordot(jnp.asarray(lmm.predictor, y.dtype), ys, 1)

        def attempt(jac, o):
            fixed = factorised(jnp.eye(y.shape[0], dtype=y.dtype) - (h * bk) * jac)
            v, k1, k2, ok, theta = newton_solve(lambda v: v - (h * bk) * fun(t_next, v) - known,
                                                lambda _: fixed, guess, jnp.abs(y), o)
            return v, ok, jnp.asarray(k1 + k2 * (1 + y.shape[0]), y.dtype), theta

        y_next, ok, spent, state = _solve_reusing(attempt, opts, fun, t, y, state)
        y_next, state = _finish(y, y_next, ok, state, evals + spent)
    f_next = fun(t_next, y_next)
    ys = jnp.concatenate([ys[1:], y_next[None]])
    fs = jnp.concatenate([fs[1:], f_next[None]])
    return y_next, dict(state, ys=ys, fs=fs)
