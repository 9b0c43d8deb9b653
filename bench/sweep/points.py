"""The batch of operating points one sweep chunk runs: a block of the config's envelope as a
fixed number of lanes, the last block padded by repeating its last point, so that every
block of a method shares one compiled program."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Points:
    """Lanes of operating points: `ids` the config's point indices of the real lanes, `lanes`
    the point index of every lane (padding repeats the last), `values` (B, variables) their
    envelope values, and the model's arrays x0 (B, d), u (B, m), p {name: (B,)}."""
    ids: tuple
    lanes: tuple
    values: np.ndarray
    x0: np.ndarray
    u: np.ndarray
    p: dict
    variables: tuple

    @classmethod
    def block(cls, cfg, block: int) -> Points:
        """Block `block` of cfg's points, in lanes of cfg.chunks.points (fewer where the
        config has fewer points)."""
        pts = cfg.points
        size = min(cfg.chunks.points, len(pts))
        first = block * cfg.chunks.points
        ids = tuple(range(first, min(first + size, len(pts))))
        lanes = ids + (ids[-1],) * (size - len(ids))
        x0, u, p = cfg.spec.arrays([pts[i] for i in lanes])
        return cls(ids, lanes, np.array([pts[i] for i in lanes], float).reshape(size, -1),
                   x0, u, p, tuple(cfg.spec.variables))

    @classmethod
    def repeated(cls, spec, point, size: int) -> Points:
        """One operating point in `size` lanes (a batch that keeps a block's compiled shape)."""
        x0, u, p = spec.arrays([point] * size)
        return cls((), (), np.tile(np.asarray(point, float), (size, 1)), x0, u, p,
                   tuple(spec.variables))

    def __len__(self) -> int:
        return len(self.x0)

    @property
    def n_real(self) -> int:
        return len(self.ids)

    def take(self, idx) -> tuple:
        """(x0, u, p) of the lanes idx (N,), in that order."""
        return self.x0[idx], self.u[idx], {k: v[idx] for k, v in self.p.items()}

    def columns(self) -> dict:
        """The envelope's variables as columns over the lanes."""
        return {var: self.values[:, j] for j, var in enumerate(self.variables)}
