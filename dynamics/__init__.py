"""Models as pure JAX right-hand sides f(t, x, u, p) -> dx/dt, with published parameters."""
from stepzoo.dynamics.models import MODELS, Model, model
from stepzoo.dynamics.vehicles import default_vehicle, physical, vehicle, vehicle_names

__all__ = ["MODELS", "Model", "model", "default_vehicle", "physical", "vehicle", "vehicle_names"]
