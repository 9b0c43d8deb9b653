"""Published vehicle parameter sets, loaded from `vehicles.toml` beside this module."""
import tomllib
from functools import cache
from pathlib import Path

PHYSICAL = ("m", "Iz", "Lf", "Lr", "Caf", "Car")


@cache
def _table() -> dict:
    with open(Path(__file__).with_name("vehicles.toml"), "rb") as fh:
        return tomllib.load(fh)


def default_vehicle() -> str:
    """Name of the documented default set."""
    return _table()["default"]


def vehicle_names() -> list[str]:
    return sorted(k for k, v in _table().items() if isinstance(v, dict))


def vehicle(name: str | None = None) -> dict:
    """Parameters of a named set: m [kg], Iz [kg m^2], Lf, Lr [m], Caf, Car [N/rad],
    length, width [m], and `source`. Raises KeyError naming the known sets."""
    name = name or default_vehicle()
    table = _table()
    if name not in table or not isinstance(table[name], dict):
        raise KeyError(f"unknown vehicle {name!r}; known: {', '.join(vehicle_names())}")
    return dict(table[name], name=name)


def physical(name: str | None = None) -> dict:
    """Only the float parameters the right-hand sides read (a JAX-friendly pytree)."""
    v = vehicle(name)
    return {k: float(v[k]) for k in PHYSICAL}
