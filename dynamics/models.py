"""The model registry: every built-in model is data of one shape, `Model`: a right-hand side
f(t, x, u, p) (pure JAX, in x's dtype), state and input names, parameter values, a default
problem (initial state, constant inputs, interval) and its truth, a closed form or a tight
reference. `model(name, tyre=...)` returns the same object for the same arguments.

The vehicle models (dynamic5, dynamic6, kinematic, kinematic_cg, st) also take a vehicle set by name
(`params(vehicle, vx)`) and start 'from rest' at an operating point (`from_rest(vx, delta)`)."""
from dataclasses import dataclass, field
from functools import cache
from typing import Callable

import numpy as np

from stepzoo.dynamics import bicycle, kinematic, single_track, solutions, wheel
from stepzoo.dynamics.problems import detest
from stepzoo.dynamics.problems import stiff
from stepzoo.dynamics.tyres import TYRES, tyre_name
from stepzoo.dynamics.vehicles import physical, st_params, tyre_params

PAPER_POINT = (15.0, np.pi / 4)     # [m/s], [rad]: the paper's test, vx and steer
VEHICLE_HORIZON = (0.0, 2.0)        # [s]: the paper's accuracy horizon


@dataclass(frozen=True, eq=False)
class Model:
    name: str
    rhs: Callable                   # f(t, x, u, p) -> dx/dt
    states: tuple
    inputs: tuple
    description: str
    defaults: dict = field(repr=False)    # parameter values p of the default problem
    x0: tuple = ()                  # default initial state
    u0: tuple = ()                  # default inputs, constant in time
    t_span: tuple = VEHICLE_HORIZON  # [s] interval of the default problem
    exact: Callable | None = field(default=None, repr=False)  # exact(ts) -> (len(ts), n)
    stiff: bool = False             # its reference needs an implicit solver
    family: str = "vehicle"         # vehicle | detest | stiff | wheel
    source: str = ""
    tyre: str | None = None         # the tyre law of a dynamic bicycle
    vehicle_params: Callable | None = field(default=None, repr=False)  # (vehicle, vx) -> p

    def params(self, vehicle: str | None = None, vx: float | None = None) -> dict:
        """Parameter pytree: for a vehicle model the named set (default: the documented one)
        with its tyre parameters and, for dynamic5, the speed vx [m/s]; otherwise the
        model's own values."""
        if self.vehicle_params is None:
            if vehicle is not None:
                raise KeyError(f"model {self.name!r} takes no vehicle set; vehicle models: "
                               f"{', '.join(VEHICLE_MODELS)}")
            return dict(self.defaults)
        return self.vehicle_params(vehicle, PAPER_POINT[0] if vx is None else vx)

    def from_rest(self, vx: float, delta: float):
        """(x0, u) of a vehicle model: at the origin, heading 0, no lateral motion, speed vx
        [m/s] (a state or, for dynamic5, a parameter), steer delta [rad] held constant."""
        import jax.numpy as jnp
        x0, u = _rest(self.states, self.inputs, vx, delta)
        return jnp.asarray(x0), jnp.asarray(u)

    @property
    def solution_kind(self) -> str:
        return "exact" if self.exact is not None else "reference"

    def solution(self, ts) -> np.ndarray:
        """The truth of the default problem at the times ts [s] (ts[0] = t_span[0]): the
        closed form where one exists, else the tight reference of `solutions`."""
        ts = np.asarray(ts, float)
        if self.exact is not None:
            return np.asarray(self.exact(ts), float)
        return solutions.cached(self, tuple(ts))


# -- vehicle models --------------------------------------------------------------------------
def _rest(states, inputs, vx, delta):
    x0, u = np.zeros(len(states)), np.zeros(len(inputs))
    for speed in ("vx", "v"):
        if speed in states:
            x0[states.index(speed)] = vx
    if "delta" in states:
        x0[states.index("delta")] = delta
    else:
        u[inputs.index("delta")] = delta
    return x0, u


def _bicycle_params(tyre, speed_param):
    def params(vehicle, vx):
        p = dict(physical(vehicle), **tyre_params(vehicle, tyre))
        return dict(p, vx=float(vx), Fxf=0.0) if speed_param else p
    return params


def _kinematic_params(vehicle, vx):
    p = physical(vehicle)
    return dict(p, L=p["Lf"] + p["Lr"])


def _st_params(vehicle, vx):
    return st_params(vehicle)


def _vehicle(name, rhs, states, inputs, description, params, tyre=None, exact=None):
    x0, u0 = _rest(states, inputs, *PAPER_POINT)
    return Model(name, rhs, states, inputs, description, defaults=params(None, PAPER_POINT[0]),
                 x0=tuple(x0.tolist()), u0=tuple(u0.tolist()), exact=exact, tyre=tyre,
                 vehicle_params=params, source="vehicles.toml")


def _dynamic5_exact(ts):
    from stepzoo.dynamics.exact import exact_reduced
    p = _bicycle_params("linear", True)(None, PAPER_POINT[0])
    return exact_reduced(ts, np.zeros(5), PAPER_POINT[1], p)


def _dynamic(name, tyre):
    tyre = tyre_name(tyre)
    tail = "" if tyre == "linear" else f", {tyre} tyres"
    if name == "dynamic5":
        return _vehicle(name, bicycle.reduced(tyre), bicycle.REDUCED_STATES,
                        bicycle.REDUCED_INPUTS,
                        f"dynamic bicycle, 5 states, constant vx (paper eq. 4){tail}",
                        _bicycle_params(tyre, True), tyre,
                        exact=_dynamic5_exact if tyre == "linear" else None)
    return _vehicle(name, bicycle.full(tyre), bicycle.FULL_STATES, bicycle.FULL_INPUTS,
                    f"dynamic bicycle, 6 states, vx a state (paper eq. 1){tail}",
                    _bicycle_params(tyre, False), tyre)


VEHICLE_MODELS = ("dynamic5", "dynamic6", "kinematic", "kinematic_cg", "st")
TYRE_MODELS = ("dynamic5", "dynamic6")


def _build(name: str) -> Model:
    if name == "kinematic":
        return _vehicle(name, kinematic.kinematic_bicycle, kinematic.STATES, kinematic.INPUTS,
                        "kinematic bicycle (paper eq. pm)", _kinematic_params)
    if name == "kinematic_cg":
        return _vehicle(name, kinematic.rigid_bicycle, kinematic.RIGID_STATES,
                        kinematic.INPUTS, "kinematic bicycle as a rigid car, at its centre of "
                        "gravity", _kinematic_params)
    if name == "st":
        return _vehicle(name, single_track.single_track, single_track.STATES,
                        single_track.INPUTS, "CommonRoad single-track model (ST), 7 states",
                        _st_params)
    if name in detest.PROBLEMS:
        d = detest.PROBLEMS[name]
        return Model(name, d["rhs"], tuple(f"y{i + 1}" for i in range(len(d["x0"]))), (),
                     d["description"], defaults={}, x0=tuple(d["x0"]), t_span=detest.T_SPAN,
                     exact=d["exact"], family="detest", source=detest.SOURCE)
    if name in wheel.PROBLEMS:
        d = wheel.PROBLEMS[name]
        return Model(name, d["rhs"], d["states"], d["inputs"], d["description"],
                     defaults=dict(d.get("params", wheel.PARAMS)), x0=d["x0"], u0=d["u0"],
                     t_span=d["t_span"],
                     family="wheel", source=wheel.SOURCE)
    d = stiff.PROBLEMS[name]
    return Model(name, d["rhs"], tuple(f"y{i + 1}" for i in range(len(d["x0"]))), (),
                 d["description"], defaults=d.get("params", {}),
                 x0=tuple(d["x0"]), t_span=d["t_span"], exact=d["exact"], stiff=True,
                 family="stiff", source=d["source"])


MODEL_NAMES = (VEHICLE_MODELS + tuple(detest.PROBLEMS) + tuple(stiff.PROBLEMS)
               + tuple(wheel.PROBLEMS))
DEFAULT_MODEL = "dynamic5"


def model(name: str | None = None, tyre: str | None = None) -> Model:
    """A built-in model by name; `tyre` (linear | pacejka | fiala) for the dynamic bicycles.
    Raises KeyError naming the known choices."""
    name = name or DEFAULT_MODEL
    if name not in MODEL_NAMES:
        raise KeyError(f"unknown model {name!r}; known: {', '.join(MODEL_NAMES)}")
    if name in TYRE_MODELS:
        return _dynamic_cached(name, tyre_name(tyre))
    if tyre not in (None, "linear"):
        raise KeyError(f"model {name!r} has no tyre option (tyres: {', '.join(TYRES)}); "
                       f"models with one: {', '.join(TYRE_MODELS)}")
    return _cached(name)


@cache
def steered(rhs: Callable) -> Callable:
    """`rhs` (whose first input is the steer angle delta [rad]) with the steer a state instead,
    driven by its rate, as CommonRoad's models take it: the state [*x, delta], the inputs
    [ddelta [rad/s], *u[1:]]. The same function for the same `rhs`, so a driver compiles once."""
    import jax.numpy as jnp

    def steered_rhs(t, x, u, p):
        inner = rhs(t, x[:-1], jnp.concatenate([x[-1:], u[1:]]), p)
        return jnp.concatenate([inner, u[:1]])
    return steered_rhs


_cached = cache(_build)
_dynamic_cached = cache(_dynamic)


# Every built-in model with its default options (the linear tyre), by name.
MODELS = {name: model(name) for name in MODEL_NAMES}
