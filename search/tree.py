"""The search tree as columns: one row per node (row 0 the start), held in preallocated NumPy
arrays that double when full, so adding a batch of children is one append."""
from __future__ import annotations

import numpy as np

# column -> (dtype, shape of one row)
COLUMNS = {
    "states": (float, (5,)),   # [X, Y, psi, vy, r] at the node
    "parent": (np.int64, ()),  # the parent's row, -1 for the start
    "g": (float, ()),          # [m] cost to come: distance driven plus cusp costs
    "H": (float, ()),          # [m] straight distance to the goal
    "rest": (float, ()),       # [m] geodesic lattice distance to the goal
    "guide": (float, ()),      # [m] the guide geodesic (room for the car) to the goal
    "car": (float, ()),        # [m] the car's obstacle-blind bound to the goal
    "steer": (float, ()),      # [rad] the steer at the node: its edge's constant steer if
    #                            instant, where its steer ramp ends if rate-limited
    "steer0": (float, ()),     # [rad] the steer at the start of the node's edge
    "direction": (np.int8, ()),  # +1 forwards, -1 backwards, 0 the start (either way)
    "tight": (bool, ()),       # whether the node's edge is a tight move
}


class Tree:
    """Nodes as the columns of COLUMNS (read as `tree.g`, a view of the rows in use) and
    `edges`, each node's (n+1, 5) shooting from its parent (None for the start)."""

    def __init__(self, capacity: int = 1024):
        self.size = 0
        self._data = {k: np.zeros((capacity, *shape), dtype) for k, (dtype, shape)
                      in COLUMNS.items()}
        self.edges: list = []

    def __len__(self) -> int:
        return self.size

    def __getattr__(self, name):
        data = self.__dict__.get("_data", {})
        if name not in data:
            raise AttributeError(name)
        return data[name][:self.size]

    def add(self, edges: list, **columns) -> range:
        """Append len(edges) nodes, each column given as an array of that length or one value
        for all; returns their rows."""
        count, start = len(edges), self.size
        if start + count > len(self._data["g"]):
            grown = max(2 * len(self._data["g"]), start + count)
            for k, old in self._data.items():
                self._data[k] = np.zeros((grown, *old.shape[1:]), old.dtype)
                self._data[k][:start] = old[:start]
        if set(columns) != set(COLUMNS):
            raise ValueError(f"a node needs every column: {sorted(set(COLUMNS) ^ set(columns))}")
        for k, value in columns.items():
            self._data[k][start:start + count] = value
        self.edges += edges
        self.size += count
        return range(start, start + count)

    def path_to(self, node: int) -> np.ndarray:
        """The rows from the start's child to `node` along the parents."""
        rows, parent = [], self._data["parent"]
        while parent[node] >= 0:
            rows.append(node)
            node = int(parent[node])
        return np.array(rows[::-1], dtype=int)
