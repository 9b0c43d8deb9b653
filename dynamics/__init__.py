"""Vehicle models as pure JAX right-hand sides f(t, x, u, p) -> dx/dt, with published parameters."""
import os
import re

# XLA:CPU compiles a while loop into one native function when the loop touches fewer bytes
# than this option (1 kB by default); above it, every operation of every step is a separate
# runtime call. The integration loops touch kilobytes to megabytes, so the default left them
# all on the slow path: rk4 at batch 1 ran 2.5x and at batch 10 1.8x slower (measured, jax
# 0.10.2), with no change at batch 1e5. Set before jax starts its CPU client.
_OPTION = "xla_cpu_small_while_loop_byte_threshold=100000000"
_flags = os.environ.get("XLA_FLAGS", "")
if _OPTION.split("=")[0] not in _flags:
    _extra = re.search(r"--xla_backend_extra_options=(\S+)", _flags)
    os.environ["XLA_FLAGS"] = (
        _flags.replace(_extra.group(0), f"{_extra.group(0)},{_OPTION}") if _extra
        else f"{_flags} --xla_backend_extra_options={_OPTION}".strip())

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_platforms", "cpu")

from dynamics.models import MODELS, Model, model  # noqa: E402
from dynamics.vehicles import default_vehicle, physical, vehicle, vehicle_names  # noqa: E402

__all__ = ["MODELS", "Model", "model", "default_vehicle", "physical", "vehicle", "vehicle_names"]
