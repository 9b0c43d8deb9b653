"""The zoo: each method is data (a tableau or multistep coefficients) plus metadata, and a
registry by name. Adding a method is one `_register` line."""
from dataclasses import asdict, dataclass, field, replace
from functools import cache

import jax.numpy as jnp
import numpy as np
from jax import lax

from stepzoo.integrators import steps
from stepzoo.integrators.multistep import LinearMultistep, adams_bashforth, adams_moulton, bdf
from stepzoo.integrators.newton import NewtonOptions, RunOptions
from stepzoo.integrators.rosenbrock import Rosenbrock
from stepzoo.integrators.tableau import ButcherTableau

S3 = np.sqrt(3.0)
S6 = np.sqrt(6.0)
# Kvaerno's 3(2) ESDIRK diagonal: the root of 6g^3 - 18g^2 + 9g - 1 in (0.3, 0.5), which makes
# the stiffly accurate order-3 method L-stable.
G = float(next(r.real for r in np.roots([6, -18, 9, -1]) if 0.3 < r.real < 0.5))


@dataclass(frozen=True, eq=False)
class Method:
    """A fixed-step method. `scheme` is a ButcherTableau, a Rosenbrock or a LinearMultistep.
    Multistep methods take their first k-1 steps with `starter` (a one-step method of order
    >= theirs). Hashable by identity, so a Method can be a static argument of `jax.jit`.
    `newton` holds the tolerances and iteration limit of an implicit method's nonlinear
    solves (Rosenbrock methods have none). The driver compiles `program` and passes the
    options as run-time values (`run_options`), so methods that differ in them alone share
    one compiled program."""
    name: str
    family: str
    order: int
    scheme: ButcherTableau | Rosenbrock | LinearMultistep
    reference: str
    starter: "Method | None" = None
    newton: NewtonOptions | RunOptions = NewtonOptions()
    origin: "Method | None" = field(default=None, repr=False)

    def with_newton(self, **options) -> "Method":
        """This method (and its starter) with other Newton options (fields of NewtonOptions),
        sharing this one's compiled programs (`program`). A method with no nonlinear solve,
        or options equal to its own, is returned itself."""
        opts = replace(NewtonOptions(*self._option_values()), **options)
        if opts == self.newton or not self.solves:
            return self
        starter = self.starter.with_newton(**options) if self.starter is not None else None
        return replace(self, newton=opts, starter=starter, origin=self.program)

    @property
    def program(self) -> "Method":
        """The Method the driver compiles for this one (a static argument of `jax.jit`): the
        one it was made from by `with_newton`, or itself."""
        return self.origin if self.origin is not None else self

    def run_options(self) -> tuple:
        """Its Newton options and its starter's, as the compiled program takes them (Python
        numbers: run-time arguments of `jax.jit`, weakly typed, so a float32 state stays
        float32)."""
        own = self._option_values()
        return own, None if self.starter is None else self.starter.run_options()

    def _option_values(self) -> tuple:
        return tuple(getattr(self.newton, name) for name in RunOptions._fields)

    def running(self, options, retry: bool = True) -> "Method":
        """This method reading `run_options()`' values (traced inside the driver's program)
        instead of its own; without `retry`, its steps and its starter's leave the
        full-Newton retry out (newton.without_retry)."""
        own, starter = options
        newton = RunOptions(*own) if retry else RunOptions(*own)._replace(max_iter_full=0)
        return replace(self, newton=newton, starter=None if self.starter is None
                       else self.starter.running(starter, retry))

    def _solvers(self) -> list["Method"]:
        """This method and its starter, those of them whose steps solve by Newton's method."""
        chain = [self] if self.starter is None else [self, *self.starter._solvers()]
        return [m for m in chain if m.implicit and not m.is_rosenbrock]

    def retries(self) -> bool:
        """Whether a solve of this method or its starter may retry with full Newton (its
        options' max_iter_full > 0)."""
        return any(isinstance(m.newton, NewtonOptions) and m.newton.max_iter_full > 0
                   for m in self._solvers())

    @property
    def solves(self) -> bool:
        """Whether a step of it or of its starter solves nonlinear equations by Newton's
        method (implicit, not Rosenbrock): the ones `newton` acts on."""
        return bool(self._solvers())

    @property
    def is_multistep(self) -> bool:
        return isinstance(self.scheme, LinearMultistep)

    @property
    def is_rosenbrock(self) -> bool:
        return isinstance(self.scheme, Rosenbrock)

    @property
    def implicit(self) -> bool:
        return not self.scheme.explicit

    @property
    def stages(self) -> int:
        return 1 if isinstance(self.scheme, LinearMultistep) else self.scheme.stages

    @property
    def steps(self) -> int:
        """Step count k of a multistep method (1 for one-step methods)."""
        return self.scheme.steps if isinstance(self.scheme, LinearMultistep) else 1

    @property
    def n_start(self) -> int:
        """Steps taken by the starter before the method's own step takes over."""
        return self.steps - 1

    @property
    def rhs_evals_per_step(self) -> int:
        """Explicit: exact. Rosenbrock: evaluations of f in one step, without the d + 1 of
        its derivatives. Implicit: evaluations of one Newton iteration without the Jacobian
        (the measured count, with Newton iterations, comes from the driver)."""
        if isinstance(self.scheme, LinearMultistep):
            return 1
        if isinstance(self.scheme, Rosenbrock) or self.scheme.explicit:
            return self.scheme.evals_per_step
        return self.scheme.stages

    def init_state(self, y0):
        """Evaluations spent, whether every nonlinear solve so far converged, and, where a
        step solves by Newton's method, the factors it carries to the next (steps.held_state)
        and whether any solve failed (`unsolved`, also from a state already blown up)."""
        # Like y0, so that under shard_map they vary across devices as the steps' counts do.
        state = {"evals": jnp.zeros_like(y0, shape=()),
                 "converged": jnp.ones_like(y0, bool, shape=())}
        if self.implicit and not self.is_rosenbrock:
            state["held"] = steps.held_state(self.scheme, y0)
            state["unsolved"] = jnp.zeros_like(y0, bool, shape=())
        return state

    def step(self, fun, t, y, h, state):
        """One step from (t, y): returns (y_next, state)."""
        if self.is_multistep:
            return steps.multistep_step(self.scheme, self.newton, fun, t, y, h, state)
        if self.is_rosenbrock:
            return steps.rosenbrock_step(self.scheme, fun, t, y, h, state)
        if self.scheme.explicit:
            return steps.explicit_rk_step(self.scheme, fun, t, y, h, state)
        return steps.implicit_rk_step(self.scheme, self.newton, fun, t, y, h, state)

    def start(self, fun, t0, y0, h):
        """Starting values: (ys of steps 1..n_start, state ready for `step` at step n_start)."""
        state = self.init_state(y0)
        if not self.is_multistep:
            return jnp.zeros((0,) + y0.shape, y0.dtype), state
        def one(carry, i):
            y, sub = carry
            y, sub = self.starter.step(fun, t0 + i * h, y, h, sub)
            return (y, sub), y

        # A scan, not a Python loop: one copy of the starter's step to compile (BDF5's four
        # Radau IIA 5 steps unrolled would compile four copies).
        steps_ = jnp.arange(self.n_start, dtype=y0.dtype)
        (_, sub), ys = lax.scan(one, (y0, self.starter.init_state(y0)), steps_)
        hist = jnp.concatenate([y0[None], ys])
        slopes = self.scheme.uses_slopes
        fs = jnp.stack([fun(t0 + i * h, hist[i]) for i in range(self.steps)]) if slopes \
            else jnp.zeros_like(hist)
        state = dict(state, ys=hist, fs=fs, evals=sub["evals"] + (self.steps if slopes else 0),
                     converged=sub["converged"])
        if "unsolved" in sub and "unsolved" in state:
            state["unsolved"] = sub["unsolved"]
        return ys, state


def _rk(a, b, c=None, b_hat=None):
    """A tableau from its rows, weights, nodes (default: row sums) and, for an embedded
    pair, the lower-order weights b_hat (kept as error weights b - b_hat)."""
    a, b = np.array(a, dtype=float), np.array(b, dtype=float)
    return ButcherTableau(a, b, a.sum(axis=1) if c is None else np.array(c),
                          None if b_hat is None else b - np.array(b_hat, dtype=float))


def _ros(alpha, gamma, b, b_hat=None) -> Rosenbrock:
    """A Rosenbrock method from its coefficients' rows."""
    return Rosenbrock(np.array(alpha), np.array(gamma), np.array(b),
                      None if b_hat is None else np.array(b_hat))


TABLEAUS = {
    "euler": _rk([[0]], [1]),
    "heun": _rk([[0, 0], [1, 0]], [1 / 2, 1 / 2]),
    "midpoint": _rk([[0, 0], [1 / 2, 0]], [0, 1]),
    "rk3": _rk([[0, 0, 0], [1 / 2, 0, 0], [-1, 2, 0]], [1 / 6, 2 / 3, 1 / 6]),
    "rk4": _rk([[0, 0, 0, 0], [1 / 2, 0, 0, 0], [0, 1 / 2, 0, 0], [0, 0, 1, 0]],
               [1 / 6, 1 / 3, 1 / 3, 1 / 6]),
    "rk6": _rk([[0, 0, 0, 0, 0, 0, 0],
                [1 / 3, 0, 0, 0, 0, 0, 0],
                [0, 2 / 3, 0, 0, 0, 0, 0],
                [1 / 12, 1 / 3, -1 / 12, 0, 0, 0, 0],
                [-1 / 16, 9 / 8, -3 / 16, -3 / 8, 0, 0, 0],
                [0, 9 / 8, -3 / 8, -3 / 4, 1 / 2, 0, 0],
                [9 / 44, -9 / 11, 63 / 44, 18 / 11, 0, -16 / 11, 0]],
               [11 / 120, 0, 27 / 40, 27 / 40, -4 / 15, -4 / 15, 11 / 120]),
    "dopri5": _rk([[0, 0, 0, 0, 0, 0, 0],
                   [1 / 5, 0, 0, 0, 0, 0, 0],
                   [3 / 40, 9 / 40, 0, 0, 0, 0, 0],
                   [44 / 45, -56 / 15, 32 / 9, 0, 0, 0, 0],
                   [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0, 0, 0],
                   [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656, 0, 0],
                   [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0]],
                  [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0],
                  # Embedded fourth-order weights, for the adaptive reference's error.
                  b_hat=[5179 / 57600, 0, 7571 / 16695, 393 / 640, -92097 / 339200,
                         187 / 2100, 1 / 40]),
    "backward_euler": _rk([[1]], [1]),
    "trapezoidal": _rk([[0, 0], [1 / 2, 1 / 2]], [1 / 2, 1 / 2]),
    "gauss_legendre4": _rk([[1 / 4, 1 / 4 - S3 / 6], [1 / 4 + S3 / 6, 1 / 4]], [1 / 2, 1 / 2]),
    "radau_iia3": _rk([[5 / 12, -1 / 12], [3 / 4, 1 / 4]], [3 / 4, 1 / 4]),
    "radau_iia5": _rk([[(88 - 7 * S6) / 360, (296 - 169 * S6) / 1800, (-2 + 3 * S6) / 225],
                       [(296 + 169 * S6) / 1800, (88 + 7 * S6) / 360, (-2 - 3 * S6) / 225],
                       [(16 - S6) / 36, (16 + S6) / 36, 1 / 9]],
                      [(16 - S6) / 36, (16 + S6) / 36, 1 / 9]),
    "kvaerno3": _rk([[0, 0, 0, 0], [G, G, 0, 0],
                     [(-4 * G ** 2 + 6 * G - 1) / (4 * G), (1 - 2 * G) / (4 * G), G, 0],
                     [(6 * G - 1) / (12 * G), -1 / ((24 * G - 12) * G),
                      (-6 * G ** 2 + 6 * G - 1) / (6 * G - 3), G]],
                    [(6 * G - 1) / (12 * G), -1 / ((24 * G - 12) * G),
                     (-6 * G ** 2 + 6 * G - 1) / (6 * G - 3), G]),
}

# Rosenbrock coefficients in Hairer & Wanner's (alpha, gamma) form. An s-stage method of
# order s has R(-inf) = L_s(1/gamma), L_s the Laguerre polynomial (HW IV.7): ROS2's gamma is a
# root of L_2 (L-stable), ROS3P's gives sqrt(3) - 1. Rodas3's last stage is the solution
# (stiffly accurate), hence R(-inf) = 0.
G2 = 1 + 1 / np.sqrt(2.0)
G3P = 1 / 2 + S3 / 6
ROSENBROCK = {
    "ros2": _ros([[0, 0], [1, 0]], [[G2, 0], [-2 * G2, G2]], [1 / 2, 1 / 2], b_hat=[1, 0]),
    "ros3p": _ros([[0, 0, 0], [1, 0, 0], [1, 0, 0]],
                  [[G3P, 0, 0], [-1, G3P, 0], [-G3P, -1 / 2 - S3 / 3, G3P]],
                  [2 / 3, 0, 1 / 3], b_hat=[1 / 3, 1 / 3, 1 / 3]),
    "rodas3": _ros([[0, 0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 0], [3 / 4, -1 / 4, 1 / 2, 0]],
                   [[1 / 2, 0, 0, 0], [1, 1 / 2, 0, 0], [-1 / 4, -1 / 4, 1 / 2, 0],
                    [1 / 12, 1 / 12, -2 / 3, 1 / 2]],
                   [5 / 6, -1 / 6, -1 / 6, 1 / 2], b_hat=[3 / 4, -1 / 4, 1 / 2, 0]),
}

METHODS: dict[str, Method] = {}


def _register(name, family, order, scheme, reference, starter=None):
    METHODS[name] = Method(name, family, order, scheme, reference, starter)


_register("euler", "explicit RK", 1, TABLEAUS["euler"], "Euler 1768; forward Euler")
_register("heun", "explicit RK", 2, TABLEAUS["heun"], "Heun 1900; explicit trapezoidal")
_register("midpoint", "explicit RK", 2, TABLEAUS["midpoint"], "Runge 1895; explicit midpoint")
_register("rk3", "explicit RK", 3, TABLEAUS["rk3"], "Kutta 1901; third-order method")
_register("rk4", "explicit RK", 4, TABLEAUS["rk4"], "Kutta 1901; classical RK4")
_register("rk6", "explicit RK", 6, TABLEAUS["rk6"], "Butcher 1964; 7-stage sixth order")
_register("dopri5", "explicit RK", 5, TABLEAUS["dopri5"],
          "Dormand & Prince 1980; fifth-order weights, fixed step (FSAL stage unused)")
_register("backward_euler", "implicit RK", 1, TABLEAUS["backward_euler"],
          "backward Euler; A- and L-stable")
_register("trapezoidal", "implicit RK", 2, TABLEAUS["trapezoidal"],
          "trapezoidal rule (Crank-Nicolson); A-stable")
_register("gauss_legendre4", "implicit RK", 4, TABLEAUS["gauss_legendre4"],
          "Butcher 1964; 2-stage Gauss-Legendre collocation, A-stable, symplectic")
_register("radau_iia3", "implicit RK", 3, TABLEAUS["radau_iia3"],
          "Ehle 1969; 2-stage Radau IIA, A- and L-stable")
_register("radau_iia5", "implicit RK", 5, TABLEAUS["radau_iia5"],
          "Ehle 1969; 3-stage Radau IIA (RADAU5's method), A- and L-stable")
_register("kvaerno3", "implicit RK", 3, TABLEAUS["kvaerno3"],
          "Kvaerno 2004; 4-stage ESDIRK 3(2), stiffly accurate, A- and L-stable")
_register("ros2", "Rosenbrock", 2, ROSENBROCK["ros2"],
          "Verwer, Spee, Blom & Hundsdorfer 1999; gamma = 1 + 1/sqrt(2), A- and L-stable")
_register("ros3p", "Rosenbrock", 3, ROSENBROCK["ros3p"],
          "Lang & Verwer 2001; no order reduction on parabolic problems, A-stable, "
          "|R(-inf)| = sqrt(3) - 1")
_register("rodas3", "Rosenbrock", 3, ROSENBROCK["rodas3"],
          "Sandu et al. 1997; stiffly accurate, A- and L-stable")
_rk4 = METHODS["rk4"]
for _k in (2, 3, 4):
    _register(f"ab{_k}", "Adams-Bashforth", _k, adams_bashforth(_k),
              f"Adams-Bashforth {_k}-step; started with RK4", _rk4)
# Implicit multistep methods are started by an implicit one-step method of at least their
# order, so that a stiff problem does not blow up in the starting steps.
_register("am3", "Adams-Moulton", 3, adams_moulton(2),
          "Adams-Moulton 2-step (order 3); started with Radau IIA", METHODS["radau_iia3"])
_register("am4", "Adams-Moulton", 4, adams_moulton(3),
          "Adams-Moulton 3-step (order 4); started with Gauss-Legendre", METHODS["gauss_legendre4"])
_register("bdf2", "BDF", 2, bdf(2), "backward differentiation formula, 2-step; A-stable, "
          "started with Radau IIA", METHODS["radau_iia3"])
# BDF3-5 are A(alpha)-stable only (Hairer & Wanner II, V.2, Table 2.1). Their starter,
# Radau IIA 5 (order 5 >= k, L-stable), makes starting values with errors O(h^6), below the
# O(h^k) that keeps the order k, and damps stiff modes in the start as BDF does after it.
for _k, _alpha in ((3, 86.03), (4, 73.35), (5, 51.84)):
    _register(f"bdf{_k}", "BDF", _k, bdf(_k), f"backward differentiation formula, {_k}-step; "
              f"A(alpha)-stable, alpha = {_alpha} deg; started with Radau IIA 5",
              METHODS["radau_iia5"])


def method(name: str, newton: NewtonOptions | None = None) -> Method:
    """The zoo's method `name`, with Newton options `newton` where given: one Method per
    (name, options) in a process, so each compiles once however often it is asked for."""
    if name not in METHODS:
        raise KeyError(f"unknown method {name!r}; known: {', '.join(METHODS)}")
    if newton is not None and not isinstance(newton, NewtonOptions):
        raise TypeError(f"newton must be a NewtonOptions (stepzoo.integrators.newton), got "
                        f"{type(newton).__name__} {newton!r}; e.g. method({name!r}, "
                        "NewtonOptions(max_iter=20))")
    return METHODS[name] if newton is None else _with_options(name, newton)


@cache
def _with_options(name: str, newton: NewtonOptions) -> Method:
    return METHODS[name].with_newton(**asdict(newton))


def describe(m: Method) -> dict:
    """Metadata row of `stepzoo methods`."""
    return {"name": m.name, "family": m.family, "order": m.order, "stages": m.stages,
            "steps": m.steps, "implicit": m.implicit,
            "rhs_evals_per_step": m.rhs_evals_per_step, "reference": m.reference}


