"""The integrator zoo: fixed-step methods as data plus one generic step, one scan driver,
the adaptive Dormand-Prince reference and stability analysis.

The public API: `integrate(method, f, x0, u=None, p=None, h=..., n_steps=...)`,
`integrate_batch` (the same over a batch) and `reference` (adaptive, to a tolerance), with
`METHODS` (the zoo by name), `method(name)` and `describe(method)`."""
from stepzoo.integrators.driver import Trajectory, integrate, integrate_batch
from stepzoo.integrators.methods import METHODS, Method, describe, method
from stepzoo.integrators.reference import Reference, reference

__all__ = ["METHODS", "Method", "Reference", "Trajectory", "describe", "integrate",
           "integrate_batch", "method", "reference"]
