"""The grids of a sweep config: a list of values, or a table spanning them ({min, max, num},
log-spaced or even); the step grid's steps [s] in the shared step range."""
from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import AfterValidator, Field, Tag, model_validator

from stepzoo.config_schema import BY_SHAPE, Schema, quantity, ranged

Step = Annotated[float, ranged("step")]

MAX_GRID = 10_000       # values of one grid, or points of an envelope: more is a typo, and
                        # would be allocated before any estimate of the work

GridSize = Annotated[int, quantity(
    "a number of grid values", "", "more is a typo, and would be allocated before any estimate "
    "of the work", ge=1, le=MAX_GRID)]


def _distinct(values: tuple) -> tuple:
    """A grid written as a list: at least one value, none twice, at most MAX_GRID."""
    if not values:
        raise ValueError("must list at least one value")
    if len(values) > MAX_GRID:
        raise ValueError(f"lists {len(values)} values; at most {MAX_GRID}")
    if len(set(values)) != len(values):
        raise ValueError("lists a value twice; list each once")
    return values


class Span(Schema):
    """A grid as a table: {values = [...]}, or `num` values from `min` to `max`, evenly
    spaced (log-spaced with log = true)."""
    values: tuple[float, ...] | None = Field(None, description="the values themselves")
    min: float | None = Field(None, description="the first value")
    max: float | None = Field(None, description="the last value, >= min")
    num: GridSize | None = Field(None, description="how many values")
    log: bool = Field(False, description="log-spaced (min > 0) rather than evenly")

    @model_validator(mode="after")
    def _one_form(self):
        given = self.model_fields_set - {"log"}
        if given == {"values"}:
            _distinct(self.values)
        elif given != {"min", "max", "num"}:
            raise ValueError("must be {values = [...]} or {min = ..., max = ..., num = ...}, "
                             f"got the keys {', '.join(sorted(self.model_fields_set))}")
        elif self.min > self.max:
            raise ValueError(f"must be {{min, max, num}} with min <= max, got min {self.min:g} "
                             f"> max {self.max:g}")
        elif self.log and self.min <= 0:
            raise ValueError(f"must be {{min, max, num}} with min > 0 for log spacing, got "
                             f"min {self.min:g}")
        return self

    def grid(self) -> list[float]:
        if self.values is not None:
            return [float(v) for v in self.values]
        assert self.min is not None and self.max is not None and self.num is not None
        spaced = np.geomspace if self.log else np.linspace
        return [float(v) for v in spaced(self.min, self.max, self.num)]


class StepSpan(Span):
    """A grid of steps [s] as a table, log-spaced unless log = false."""
    values: tuple[Step, ...] | None = Field(None, description="the steps themselves [s]")
    min: Step | None = Field(None, description="the smallest step [s]")
    max: Step | None = Field(None, description="the largest step [s], >= min")
    log: bool = Field(True, description="log-spaced rather than evenly")


Grid = Annotated[Annotated[tuple[float, ...], AfterValidator(_distinct), Tag("list")]
                 | Annotated[Span, Tag("table")], BY_SHAPE]
StepGrid = Annotated[Annotated[tuple[Step, ...], AfterValidator(_distinct), Tag("list")]
                     | Annotated[StepSpan, Tag("table")], BY_SHAPE]


def grid_values(grid) -> list[float]:
    """The values of a Grid or StepGrid as written (a list) or spanned (a table)."""
    return grid.grid() if isinstance(grid, Span) else [float(v) for v in grid]

