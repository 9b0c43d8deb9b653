"""Vehicle models as pure JAX right-hand sides f(t, x, u, p) -> dx/dt, with published parameters."""
import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_platforms", "cpu")

from dynamics.models import MODELS, Model, model  # noqa: E402
from dynamics.vehicles import default_vehicle, physical, vehicle, vehicle_names  # noqa: E402

__all__ = ["MODELS", "Model", "model", "default_vehicle", "physical", "vehicle", "vehicle_names"]
