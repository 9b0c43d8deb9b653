"""plan-bench's query file, declared: a JSON list of queries, each an object of the keys of
QueryFile (stepzoo.config_schema checks each against it, and the config reference lists
them)."""
from __future__ import annotations

from typing import Annotated

from pydantic import Field

from stepzoo.config_schema import Schema, quantity

# Any size a map file may be read at; the map itself bounds it further when it is opened.
CellSize = Annotated[float, quantity("", "m/cell", "a cell has a size", gt=0.0)]


class QueryFile(Schema):
    """A plan-bench query file: a JSON list of queries, each an object with these keys (the
    map path relative to the file)."""
    map: str = Field(description="the map file, relative to the query file")
    cell_size: CellSize | None = Field(None, description="its cell size [m/cell], for formats "
                                       "that do not store it (MovingAI maps)")
    start: tuple[float, ...] = Field(description="start pose [X m, Y m, psi rad]")
    goal: tuple[float, ...] = Field(description="goal pose [X m, Y m, psi rad]")
    id: str | int | None = Field(None, description="names the query's rows and files "
                                 "(default: its place in the list, from 0)")
