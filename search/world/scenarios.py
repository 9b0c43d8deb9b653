"""Planning scenarios: the paper's five built-in ones (Section 3, files in `scenarios/`) and
scenario TOML files naming a map (a map file, or rectangles on an empty grid), a start, a goal,
a vehicle and a speed. Every mistake in a scenario is one UsageError line."""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Union

import numpy as np

from pydantic import Discriminator, Field, Tag

from stepzoo import config_schema, dynamics
from stepzoo.config_schema import BY_SHAPE, Schema, quantity, ranged
from stepzoo.errors import UsageError
from stepzoo.safe_parse import toml_loads
from stepzoo.validate import check, check_memory
from stepzoo.search.world.maps import (MAP_BYTES_PER_CELL, OccupancyMap, from_array,
                                 load_map)

# The shared ranges of validate.RANGES, as field types.
Cell = Annotated[float, ranged("cell")]
GoalSpeed = Annotated[float, ranged("goal_speed")]
Heading = Annotated[float, ranged("heading")]
Position = Annotated[float, ranged("position")]
Speed = Annotated[float, ranged("speed")]

SCENARIO_DIR = Path(__file__).with_name("scenarios")
DEFAULT_SPEED = 5.0  # [m/s] when a query names none

MapSide = Annotated[float, quantity("a map side", "m", "a map holds at least one cell", gt=0.0)]
Pose = tuple[Position, Position, Heading]
PoseSpeed = tuple[Position, Position, Heading, GoalSpeed]


class RectanglesMap(Schema):
    """[map]: an empty grid with rectangular obstacles."""
    size: tuple[MapSide, MapSide] = Field(description="[width, height] of the map [m]")
    resolution: Cell = Field(description="cell size [m/cell]")
    obstacles: tuple[tuple[float, float, float, float], ...] = Field(
        (), description="rectangles [x0, y0, x1, y1] [m]; a cell whose centre lies in one is "
        "occupied")


class ScenarioFile(Schema):
    """A planning scenario: a map, a start, a goal, a vehicle and the tree's speed."""
    description: str = Field("", description="one line on what the scenario tests")
    map: Annotated[Annotated[str, Tag("value")] | Annotated[RectanglesMap, Tag("table")],
                   BY_SHAPE] = Field(
        description="a map file (relative to the scenario file: an image, .npy or a ROS map "
        "YAML), or a [map] table of rectangles")
    cell_size: Cell | None = Field(None, description="cell size of a map file [m/cell] (a ROS "
                                   "map YAML gives its own)")
    start: Pose = Field(description="start pose [X m, Y m, psi rad]")
    goal: Annotated[Union[Annotated[Pose, Tag("pose")], Annotated[PoseSpeed, Tag("speed")]],
                    Discriminator(lambda v: "speed" if isinstance(v, (list, tuple)) and len(v) == 4
                                  else "pose")] = Field(
        description="goal pose [X m, Y m, psi rad], or with the speed the connection ends at "
        "[X, Y, psi, v m/s]")
    vehicle: str | None = Field(None, description="a vehicle set of dynamics/vehicles.toml "
                                "(default: the default vehicle)")
    speed: Speed = Field(description="constant longitudinal speed of the tree [m/s]")


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    omap: OccupancyMap
    map_source: str               # the map file, or "generated" for rectangles
    start: tuple                  # (X, Y, psi) [m, m, rad]
    goal: tuple                   # (X, Y, psi)
    goal_speed: float | None      # [m/s] the connection ends at, None = free
    vehicle: str                  # a set of dynamics/vehicles.toml
    speed: float                  # [m/s] constant longitudinal speed of the tree


def builtin_names() -> list[str]:
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


def load_scenario(name_or_path) -> Scenario:
    """A built-in scenario by name, or a scenario TOML file by path."""
    text = str(name_or_path)
    if text in builtin_names():
        return scenario_from_toml(SCENARIO_DIR / f"{text}.toml")
    path = Path(text)
    if path.suffix.lower() == ".toml" and path.is_file():
        return scenario_from_toml(path)
    raise UsageError(f"unknown scenario {text!r}; give a built-in one "
                     f"({', '.join(builtin_names())}) or a scenario .toml file")


def scenario_from_toml(path) -> Scenario:
    """The scenario of a TOML file, checked against ScenarioFile (unknown keys refused)."""
    path = Path(path)
    try:
        data = toml_loads(path.read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise UsageError(f"cannot read scenario {path}: {err}") from None
    f = config_schema.check(ScenarioFile, data, f"scenario {path}")
    if isinstance(f.map, RectanglesMap):
        omap, source = rectangles_map(f.map, path), "generated"
    else:
        map_path = path.parent / f.map
        omap, source = open_map(map_path, f.cell_size), str(map_path)
    return Scenario(path.stem, f.description, omap, source, f.start, f.goal[:3],
                    f.goal[3] if len(f.goal) == 4 else None, vehicle_name(f.vehicle), f.speed)


def custom_scenario(map_path, cell_size, start, goal, vx, vehicle=None) -> Scenario:
    """A query on a map file: start (X, Y, psi), goal (X, Y, psi[, v])."""
    omap = open_map(Path(map_path), cell_size)
    goal = tuple(goal)
    return Scenario(Path(map_path).stem, f"query on {map_path}", omap, str(map_path),
                    tuple(start), goal[:3], goal[3] if len(goal) == 4 else None,
                    vehicle_name(vehicle), speed(DEFAULT_SPEED if vx is None else vx, "--speed"))


def open_map(path: Path, cell_size=None) -> OccupancyMap:
    if cell_size is not None:
        check("cell", "--cell-size", cell_size)
    try:
        return load_map(path, cell_size=cell_size)
    except ValueError as err:
        raise UsageError(str(err)) from None


def rectangles_map(spec: RectanglesMap, path: Path) -> OccupancyMap:
    """An empty grid of `size` [m] at `resolution` [m/cell] with rectangles [x0, y0, x1, y1]
    [m] as obstacles: a cell is occupied if its centre lies in a rectangle."""
    (width, height), res = spec.size, spec.resolution
    boxes = np.array(spec.obstacles, dtype=float).reshape(-1, 4)
    if not (width >= res and height >= res):
        raise UsageError(f"scenario {path}: map size {width} x {height} m must hold at least one "
                         f"cell of {res} m")
    cells = (width / res) * (height / res)
    check_memory(f"scenario {path}: a map of {width:g} x {height:g} m", cells * MAP_BYTES_PER_CELL,
                 f"{cells:.3g} cells of {res:g} m", "use a smaller map or larger cells")
    xs = (np.arange(round(width / res)) + 0.5) * res
    ys = (np.arange(round(height / res)) + 0.5) * res
    occupied = np.zeros((ys.size, xs.size), bool)
    for x0, y0, x1, y1 in boxes:
        occupied |= ((ys[:, None] >= y0) & (ys[:, None] <= y1)
                     & (xs[None, :] >= x0) & (xs[None, :] <= x1))
    return from_array(occupied, res)


def pose(values, what: str, allow_speed=False) -> tuple:
    """(X, Y, psi) or, if allowed, (X, Y, psi, v) as finite floats; else UsageError."""
    sizes = (3, 4) if allow_speed else (3,)
    try:
        numbers = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        numbers = ()
    if len(numbers) not in sizes or not all(math.isfinite(v) for v in numbers):
        shape = "X,Y,PSI[,V]" if allow_speed else "X,Y,PSI"
        raise UsageError(f"{what} must be {shape} (metres, radians, m/s), got {values!r}")
    kinds = ("position", "position", "heading", "goal_speed")
    for kind, part, value in zip(kinds, ("X", "Y", "PSI", "V"), numbers):
        check(kind, f"{what}: {part}", value)
    return numbers


def speed(value, what: str) -> float:
    return check("speed", what, value)


def vehicle_name(name) -> str:
    try:
        return dynamics.vehicle(name)["name"]
    except KeyError as err:
        raise UsageError(f"{err.args[0]}; choose one of those") from None
