"""The model registry: name -> right-hand side, state and input names, and how to build the
parameter pytree and the initial state 'from rest' for an operating point (vx, delta)."""
from dataclasses import dataclass
from typing import Callable

import jax.numpy as jnp

from stepzoo.dynamics import bicycle, kinematic
from stepzoo.dynamics.vehicles import physical


@dataclass(frozen=True)
class Model:
    name: str
    rhs: Callable
    states: tuple
    inputs: tuple
    description: str

    def params(self, vehicle: str | None, vx: float) -> dict:
        """Parameter pytree for a vehicle set at speed vx [m/s]."""
        p = physical(vehicle)
        if self.name == "dynamic5":
            p = dict(p, vx=float(vx), Fxf=0.0)
        elif self.name == "kinematic":
            p = dict(p, L=p["Lf"] + p["Lr"])
        return p

    def from_rest(self, vx: float, delta: float):
        """(x0, u): at the origin, heading 0, no lateral motion, constant steer, no forces."""
        n = len(self.states)
        x0 = jnp.zeros(n)
        if "vx" in self.states:
            x0 = x0.at[self.states.index("vx")].set(vx)
        if "v" in self.states:
            x0 = x0.at[self.states.index("v")].set(vx)
        u = jnp.zeros(len(self.inputs)).at[0].set(delta)
        return x0, u


MODELS = {
    "dynamic5": Model("dynamic5", bicycle.reduced_bicycle, bicycle.REDUCED_STATES,
                      bicycle.REDUCED_INPUTS, "dynamic bicycle, 5 states, constant vx (paper eq. 4)"),
    "dynamic6": Model("dynamic6", bicycle.full_bicycle, bicycle.FULL_STATES,
                      bicycle.FULL_INPUTS, "dynamic bicycle, 6 states, vx a state (paper eq. 1)"),
    "kinematic": Model("kinematic", kinematic.kinematic_bicycle, kinematic.STATES,
                       kinematic.INPUTS, "kinematic bicycle (paper eq. pm)"),
}
DEFAULT_MODEL = "dynamic5"


def model(name: str | None = None) -> Model:
    name = name or DEFAULT_MODEL
    if name not in MODELS:
        raise KeyError(f"unknown model {name!r}; known: {', '.join(MODELS)}")
    return MODELS[name]
