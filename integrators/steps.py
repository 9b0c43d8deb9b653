"""The one generic step of each family: explicit RK, implicit RK (Newton on all stages) and
linear multistep (explicit or implicit). `fun(t, y)` is the right-hand side with inputs and
parameters already bound; every step returns (y_next, state) and counts its evaluations
in state["evals"] (implicit: residual and Jacobian evaluations of Newton included)."""
import jax.numpy as jnp
import numpy as np

from stepzoo.integrators.newton import newton_solve


def explicit_rk_step(tab, fun, t, y, h, state):
    """One step of an explicit tableau, evaluating only the stages it needs."""
    k = [None] * tab.stages
    for i in range(tab.stages):
        if not tab.needed[i]:
            continue
        yi = y
        for j in range(i):
            if tab.a[i, j] != 0.0:
                yi = yi + (h * tab.a[i, j]) * k[j]
        k[i] = fun(t + tab.c[i] * h, yi)
    incr = sum(tab.b[i] * k[i] for i in range(tab.stages) if tab.b[i] != 0.0)
    return y + h * incr, dict(state, evals=state["evals"] + tab.evals_per_step)


def implicit_rk_step(tab, fun, t, y, h, state):
    """One step of any tableau: Newton on the stage increments Z_i = h sum_j a_ij f(Y_j)."""
    s, d = tab.stages, y.shape[0]
    a = jnp.asarray(tab.a)

    def stage_f(z):
        zz = z.reshape(s, d)
        return jnp.stack([fun(t + tab.c[i] * h, y + zz[i]) for i in range(s)])

    def residual(z):
        return z - h * (a @ stage_f(z)).reshape(-1)

    z, iters = newton_solve(residual, jnp.zeros(s * d, y.dtype), jnp.max(jnp.abs(y)))
    zz = z.reshape(s, d)
    if np.linalg.matrix_rank(tab.a) == s:
        # y + h b^T F = y + b^T A^-1 Z: no evaluation of f, whose h*lambda-sized values
        # would cancel badly on stiff problems.
        y_next = y + jnp.asarray(np.linalg.solve(tab.a.T, tab.b)) @ zz
        extra = 0
    else:
        y_next = y + h * (jnp.asarray(tab.b) @ stage_f(z))
        extra = s
    evals = state["evals"] + iters * (s + s * d) + extra
    return y_next, dict(state, evals=evals)


def multistep_step(lmm, fun, t, y, h, state):
    """One step of sum_j alpha_j y_{n+j} = h sum_j beta_j f_{n+j}; state holds the last k
    values `ys` and slopes `fs`, oldest first; t is the time of the newest."""
    k = lmm.steps
    ys, fs = state["ys"], state["fs"]
    known = -jnp.tensordot(jnp.asarray(lmm.alpha[:k]), ys, 1) \
        + h * jnp.tensordot(jnp.asarray(lmm.beta[:k]), fs, 1)
    t_next = t + h
    evals = state["evals"] + 1.0
    if lmm.explicit:
        y_next = known
    else:
        bk = lmm.beta[k]
        y_next, iters = newton_solve(lambda v: v - h * bk * fun(t_next, v) - known,
                                     ys[-1], jnp.max(jnp.abs(y)))
        evals = evals + iters * (1 + y.shape[0])
    f_next = fun(t_next, y_next)
    ys = jnp.concatenate([ys[1:], y_next[None]])
    fs = jnp.concatenate([fs[1:], f_next[None]])
    return y_next, dict(state, ys=ys, fs=fs, evals=evals)
