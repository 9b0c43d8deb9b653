"""The stage equations of the fully implicit methods hold the right-hand side once, whatever
their stage count: the Jacobian the full-Newton retry factorises, built from one vmapped
Jacobian of f over the stages, is forward mode's through the whole residual to rounding; and
an implicit step's traced program (what XLA compiles, its size what the compile time grows
with) holds f a fixed number of times, and does not grow with the state count beyond the
unrolled elimination's order."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.integrators import method
from stepzoo.integrators.steps import stage_system


def ring(t, y):
    """A nonlinear ring of oscillators, written on whole arrays: its traced size does not
    depend on the state count, so a step's size may not either. arctan marks each of its
    evaluations (its derivative has none)."""
    return -3.0 * y + jnp.arctan(jnp.roll(y, 1)) * (1.0 + 0.1 * t) - 0.5 * y ** 3


@pytest.mark.parametrize("name", ["radau_iia5", "radau_iia3", "gauss_legendre4"])
def test_stage_jacobian_is_forward_mode_through_the_residual(name):
    scheme = method(name).scheme
    rng = np.random.default_rng(11)
    d = 7
    y = jnp.asarray(rng.normal(size=d))
    z = jnp.asarray(0.1 * rng.normal(size=scheme.stages * d))
    _, residual, residual_jacobian = stage_system(scheme, ring, 0.3, y, 0.05)
    got, want = np.asarray(residual_jacobian(z)), np.asarray(jax.jacfwd(residual)(z))
    assert got.shape == (scheme.stages * d,) * 2
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15 * np.abs(want).max())


def _count(jaxpr, prim=None) -> int:
    """Equations of a jaxpr and all its sub-jaxprs (loop bodies, conds, custom rules);
    with `prim`, only those of that primitive."""
    n = 0
    for eqn in jaxpr.eqns:
        n += prim is None or eqn.primitive.name == prim
        for param in eqn.params.values():
            for sub in param if isinstance(param, (list, tuple)) else [param]:
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    n += _count(inner, prim)
    return n


def _step_jaxpr(name, d):
    """The jaxpr of a step of `name` on `ring` with d states, from the shapes of the start's
    state (tracing needs no values; running the start would compile its operations)."""
    m = method(name)
    y, h = jnp.linspace(0.1, 1.0, d), jnp.asarray(0.01)
    fun = lambda t, v: ring(t, v)      # noqa: E731
    state = jax.eval_shape(lambda: m.start(fun, 0.0, y, h)[1])
    return jax.make_jaxpr(lambda v, st: m.step(fun, 0.0, v, h, st))(y, state).jaxpr


def test_a_fully_implicit_step_holds_f_the_same_number_of_times_whatever_its_stages():
    """Once in the simplified iteration, once in the step's Jacobian, once in the retry's
    Jacobian and once in its iteration: 4, for two stages as for three (a loop over the
    stages held it once a stage: 10 for Radau IIA 5)."""
    counts = {name: _count(_step_jaxpr(name, 6), "atan")
              for name in ("radau_iia3", "radau_iia5", "gauss_legendre4")}
    assert set(counts.values()) == {4}, counts


@pytest.mark.parametrize("name", ["radau_iia5", "backward_euler", "trapezoidal", "bdf3"])
def test_a_step_s_traced_size_does_not_grow_with_the_states_above_the_unrolled_order(name):
    """Above newton.SMALL states every elimination is a loop, so a model written on arrays
    gives a step of about one size at 9 and at 29 states: nothing is unrolled over the
    states. Only the norms' halvings (newton.halved) grow, a level each time the states
    double: Radau IIA 5 from 1198 to 1268 equations, where a sum unrolled over the columns
    of its Jacobian made 1314 into 1634."""
    small, large = _count(_step_jaxpr(name, 9)), _count(_step_jaxpr(name, 29))
    assert large <= 1.1 * small, (small, large)
