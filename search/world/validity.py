"""Which poses and motions the car may take (OMPL's StateValidityChecker): a protocol the
planner checks every pose, shooting and connection through, and its first implementation,
the car's footprint (+ margin) against the occupancy map."""
from __future__ import annotations

from typing import Protocol

import numpy as np

from stepzoo.search.world.footprint import Footprint, first_collision, poses_collide
from stepzoo.search.world.maps import OccupancyMap


class ValidityChecker(Protocol):
    """Batched validity of poses [X, Y, psi] ([m, m, rad]; extra columns ignored)."""

    def is_valid(self, poses) -> np.ndarray:
        """(..., 3+) poses -> bool (...): the pose is allowed (non-finite poses are not)."""

    def first_invalid(self, paths) -> np.ndarray:
        """(B, N, 3+) paths -> int (B,): the first pose k whose pose, or whose motion from
        pose k-1, is not allowed; -1 if the whole path is."""


class FootprintChecker:
    """The car as a rectangle covered by discs (`footprint`, margin included) on `omap`:
    a pose is valid when no disc touches an obstacle or leaves the map, a motion when the
    straight interpolation between its poses is (search/world/footprint.py)."""

    def __init__(self, omap: OccupancyMap, footprint: Footprint):
        self.omap, self.footprint = omap, footprint

    def is_valid(self, poses) -> np.ndarray:
        return ~poses_collide(self.omap, self.footprint, poses)

    def first_invalid(self, paths) -> np.ndarray:
        return first_collision(self.omap, self.footprint, paths)
