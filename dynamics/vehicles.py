"""Published vehicle parameter sets, loaded from `vehicles.toml` beside this module."""
import tomllib
from functools import cache
from pathlib import Path

PHYSICAL = ("m", "Iz", "Lf", "Lr", "Caf", "Car")
LIMITS = ("max_steer_rate", "max_lateral_acceleration")  # [rad/s], [m/s^2]
G = 9.81        # [m/s^2] gravity, CommonRoad's value


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
    length, width [m], the limits max_steer_rate [rad/s] and max_lateral_acceleration
    [m/s^2], and `source` (`limits_source` for the limits). Raises KeyError naming the known sets."""
    name = name or default_vehicle()
    table = _table()
    if name not in table or not isinstance(table[name], dict):
        raise KeyError(f"unknown vehicle {name!r}; known: {', '.join(vehicle_names())}")
    return dict(table[name], name=name)


def physical(name: str | None = None) -> dict:
    """Only the float parameters the right-hand sides read (a JAX-friendly pytree)."""
    v = vehicle(name)
    return {k: float(v[k]) for k in PHYSICAL}


def limits(name: str | None = None) -> dict:
    """The car's limits the planner respects: max_steer_rate [rad/s], max_lateral_acceleration
    [m/s^2]."""
    v = vehicle(name)
    return {k: float(v[k]) for k in LIMITS}


def _sub_table(name: str | None, kind: str) -> dict:
    v = vehicle(name)
    if kind not in v:
        have = [k for k in vehicle_names() if kind in _table()[k]]
        raise KeyError(f"vehicle {v['name']!r} has no {kind} parameter set; sets with one: "
                       f"{', '.join(have)}")
    return v[kind]


def axle_loads(p: dict) -> tuple[float, float]:
    """Static front and rear axle loads Fz [N] of a set with m, Lf, Lr."""
    L = p["Lf"] + p["Lr"]
    return p["m"] * G * p["Lr"] / L, p["m"] * G * p["Lf"] / L


def tyre_params(name: str | None, tyre: str) -> dict:
    """The extra parameters a tyre law reads, per axle (suffix f, r): pacejka B, C, D [N], E;
    fiala mu and Fz [N]; linear none (it reads Caf, Car)."""
    if tyre == "linear":
        return {}
    t = _sub_table(name, tyre)
    Fzf, Fzr = axle_loads(physical(name))
    if tyre == "pacejka":
        return {"Bf": t["B"], "Cf": t["C"], "Df": t["mu"] * Fzf, "Ef": t["E"],
                "Br": t["B"], "Cr": t["C"], "Dr": t["mu"] * Fzr, "Er": t["E"]}
    return {"mu": float(t["mu"]), "Fzf": Fzf, "Fzr": Fzr}


def st_params(name: str | None) -> dict:
    """Parameters of the CommonRoad single-track model for a set (see [NAME.st])."""
    return {k: float(v) for k, v in _sub_table(name, "st").items() if k != "source"}
