"""Butcher tableaus as validated data: rows sum to c, weights sum to one, embedded error
weights (if any) sum to zero; explicitness and the stages actually needed by the step are
derived, not declared."""
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ButcherTableau:
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    e: np.ndarray | None = None   # error weights b - b_hat of an embedded pair, or None
    explicit: bool = field(init=False)
    diagonally_implicit: bool = field(init=False)
    stiffly_accurate: bool = field(init=False)
    needed: tuple = field(init=False)

    def __post_init__(self):
        a, b, c = (np.asarray(v, dtype=float) for v in (self.a, self.b, self.c))
        s = len(b)
        if a.shape != (s, s) or c.shape != (s,):
            raise ValueError(f"tableau shapes disagree: a {a.shape}, b {b.shape}, c {c.shape}")
        if not np.isclose(b.sum(), 1.0, atol=1e-14):
            raise ValueError(f"weights sum to {b.sum()!r}, not 1")
        if not np.allclose(a.sum(axis=1), c, atol=1e-14):
            raise ValueError("row sums of a differ from c")
        if self.e is not None:
            e = np.asarray(self.e, dtype=float)
            if e.shape != (s,) or not np.isclose(e.sum(), 0.0, atol=1e-14):
                raise ValueError(f"error weights must be {s} numbers summing to 0, got {e!r}")
            object.__setattr__(self, "e", e)
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "c", c)
        object.__setattr__(self, "explicit", bool(np.all(np.triu(a) == 0)))
        object.__setattr__(self, "diagonally_implicit", bool(np.all(np.triu(a, 1) == 0)))
        # b is the last row of a: the last stage is the step's result (no cancellation).
        object.__setattr__(self, "stiffly_accurate", bool(np.array_equal(a[-1], b)))
        # A stage is needed if its weight is non-zero or a needed later stage reads it; the
        # FSAL stage of Dormand-Prince (weight 0, read by nobody) is dropped by this rule.
        need = b != 0
        for i in range(s - 1, -1, -1):
            need[i] |= bool(np.any((a[:, i] != 0) & need))
        object.__setattr__(self, "needed", tuple(bool(x) for x in need))

    @property
    def stages(self) -> int:
        return len(self.b)

    @property
    def evals_per_step(self) -> int:
        """Right-hand-side evaluations of one explicit step (stages actually needed)."""
        return sum(self.needed)
