"""The reference a sweep measures errors against: one protocol, `solve(points, h, n, watch)`,
and its three back-ends (the model's closed form, SciPy's solve_ivp, the adaptive JAX
Dormand-Prince 5(4)), of which a config's settings choose one, once."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, NamedTuple, Protocol

import numpy as np

from stepzoo.bench.sweep.config import SweepConfig
from stepzoo.bench.sweep.model_table import default_solver

if TYPE_CHECKING:
    from stepzoo.bench.model.spec import ModelSpec

REF_WINDOW = 64        # output times per adaptive call: its cost per step grows with them


class Solution(NamedTuple):
    """x (B, n+1, d): the reference at t = k h, k = 0..n, per lane; ok (B,): where it
    succeeded (a failed lane's states are not to be trusted)."""
    x: np.ndarray
    ok: np.ndarray


class Reference(Protocol):
    @property
    def description(self) -> str:
        """The manifest's "reference"."""

    def solve(self, points, h: float, n: int, watch) -> Solution:
        """The reference of every lane of `points` (bench.sweep.points.Points) at t = k h [s],
        k = 0..n; its time goes to watch's reference_s."""


@dataclass(frozen=True)
class Exact:
    """The model's closed form (the config keeps every lane at the model's own problem,
    which the closed form solves)."""
    model: str
    description: str = "the model's closed form (reference.exact)"

    def solve(self, points, h, n, watch) -> Solution:
        from stepzoo import dynamics
        with watch.clock("reference_s"):
            exact = dynamics.MODELS[self.model].exact
            assert exact is not None      # model_table.closed_form_problem: the model has one
            x = exact(h * np.arange(n + 1))
        x = np.broadcast_to(np.asarray(x, float), (len(points), n + 1, len(x[0]))).copy()
        return Solution(x, np.ones(len(points), bool))


@dataclass(frozen=True)
class SciPy:
    """SciPy's solve_ivp (`dynamics.solutions.solve`) with `solver`, once per distinct lane;
    a lane it fails on is NaN and not ok."""
    spec: ModelSpec
    solver: str
    rtol: float
    atol: float

    @property
    def description(self) -> str:
        return f"SciPy's {self.solver} at reference.rtol/atol, per distinct lane"

    def solve(self, points, h, n, watch) -> Solution:
        from stepzoo.dynamics.solutions import solve
        ts = h * np.arange(n + 1)
        x0, u, p = points.x0, points.u, points.p
        out = np.full((len(x0), n + 1, len(self.spec.states)), np.nan)
        ok = np.zeros(len(x0), bool)
        done = {}
        with watch.clock("reference_s"):
            for b in range(len(x0)):
                key = (tuple(x0[b]), tuple(u[b]), tuple(v[b] for v in p.values()))
                if key not in done:
                    try:
                        done[key] = solve(self.spec.rhs, x0[b], u[b],
                                          {k: v[b] for k, v in p.items()}, ts,
                                          method=self.solver, rtol=self.rtol, atol=self.atol)
                    except RuntimeError:
                        done[key] = None
                if done[key] is not None:
                    out[b], ok[b] = done[key], True
        return Solution(out, ok)


@dataclass(frozen=True)
class Dopri5:
    """The adaptive Dormand-Prince 5(4) of integrators.reference, jitted over the lanes,
    restarted every REF_WINDOW output times from where the last window ended."""
    spec: ModelSpec
    rtol: float
    atol: float
    description: str = ("adaptive Dormand-Prince 5(4) at reference.rtol/atol, restarted every "
                        f"{REF_WINDOW} output times")

    def solve(self, points, h, n, watch) -> Solution:
        import jax.numpy as jnp
        fn = _batched_dopri5(self.spec.rhs, self.rtol, self.atol)
        uj, pj = jnp.asarray(points.u), {k: jnp.asarray(v) for k, v in points.p.items()}
        ts = h * np.arange(n + 1)
        out = np.empty((len(points), n + 1, len(self.spec.states)))
        out[:, 0] = points.x0
        ok = np.ones(len(points), bool)
        with watch.clock("reference_s"):
            for j in range(0, n, REF_WINDOW):
                window = ts[j: j + REF_WINDOW + 1]
                # Every call has REF_WINDOW + 1 output times: one compilation serves them all.
                padded = np.concatenate([window,
                                         np.full(REF_WINDOW + 1 - len(window), window[-1])])
                ref = fn(jnp.asarray(out[:, j]), uj, pj, jnp.asarray(padded))
                out[:, j: j + len(window)] = np.asarray(ref.x)[:, : len(window)]
                ok &= np.asarray(ref.success)
        return Solution(out, ok)


@cache
def _batched_dopri5(f, rtol, atol):
    """The adaptive reference, jitted and vmapped over lanes (one compilation per model)."""
    import jax
    from stepzoo.integrators.reference import reference
    return jax.jit(jax.vmap(lambda x0, u, p, ts: reference(f, x0, u, p, ts, rtol, atol),
                            in_axes=(0, 0, 0, None)))


def choose(cfg: SweepConfig) -> Reference:
    """The config's reference: the closed form where reference.exact, else reference.solver
    (the model's default where not given): dopri5 in JAX, any other by SciPy."""
    if cfg.reference.exact:
        return Exact(cfg.spec.name)
    solver = cfg.reference.solver or default_solver(cfg.spec)
    if solver == "dopri5":
        return Dopri5(cfg.spec, cfg.reference.rtol, cfg.reference.atol)
    return SciPy(cfg.spec, solver, cfg.reference.rtol, cfg.reference.atol)
