"""Rosenbrock (linearly implicit) methods in Hairer & Wanner's notation (Solving ODEs II,
IV.7, (7.4')): with J = df/dy and f_t = df/dt at the step's start (t, y),

    (I - h gamma J) k_i = h f(t + alpha_i h, y + sum_{j<i} alpha_ij k_j)
                          + h J sum_{j<i} gamma_ij k_j + gamma_i h^2 f_t,
    y_1 = y + sum_i b_i k_i,

alpha_i = sum_j alpha_ij, gamma_i = sum_{j<=i} gamma_ij. Every stage shares the diagonal
gamma, so one LU factorisation serves the step; no Newton iteration. The step runs the
equivalent form in u_i = sum_j gamma_ij k_j (HW (7.25)), which needs no product with J."""
from dataclasses import dataclass, field

import numpy as np

from stepzoo.integrators.tableau import ButcherTableau


@dataclass(frozen=True)
class Rosenbrock:
    """Coefficients alpha (s x s, strictly lower), gamma (s x s, lower, one diagonal value),
    weights b and, for an embedded pair, the lower-order weights b_hat. Derived: the nodes
    alpha_i, the sums gamma_i, the transformed coefficients (a_u = alpha Gamma^-1,
    c_u = diag(1/gamma) - Gamma^-1, m_u = b^T Gamma^-1) and, per stage, the first stage with
    the same argument of f (ROS3P's third stage reuses its second's evaluation)."""
    alpha: np.ndarray
    gamma: np.ndarray
    b: np.ndarray
    b_hat: np.ndarray | None = None
    nodes: np.ndarray = field(init=False)
    gamma_sums: np.ndarray = field(init=False)
    a_u: np.ndarray = field(init=False)
    c_u: np.ndarray = field(init=False)
    m_u: np.ndarray = field(init=False)
    same_as: tuple = field(init=False)

    explicit = False

    def __post_init__(self):
        alpha, gamma, b = (np.asarray(v, dtype=float) for v in (self.alpha, self.gamma, self.b))
        s = len(b)
        if alpha.shape != (s, s) or gamma.shape != (s, s):
            raise ValueError(f"shapes disagree: alpha {alpha.shape}, gamma {gamma.shape}, "
                             f"b {b.shape}")
        if np.any(np.triu(alpha) != 0) or np.any(np.triu(gamma, 1) != 0):
            raise ValueError("alpha must be strictly lower triangular, gamma lower triangular")
        g = gamma[0, 0]
        if g <= 0 or np.any(np.diag(gamma) != g):
            raise ValueError(f"gamma needs one positive diagonal value, got {np.diag(gamma)!r}")
        if not np.isclose(b.sum(), 1.0, atol=1e-14):
            raise ValueError(f"weights sum to {b.sum()!r}, not 1")
        if self.b_hat is not None:
            b_hat = np.asarray(self.b_hat, dtype=float)
            if b_hat.shape != (s,) or not np.isclose(b_hat.sum(), 1.0, atol=1e-14):
                raise ValueError(f"b_hat must be {s} weights summing to 1, got {b_hat!r}")
            object.__setattr__(self, "b_hat", b_hat)
        inv = np.linalg.inv(gamma)
        same = tuple(next(j for j in range(i + 1) if np.array_equal(alpha[j], alpha[i]))
                     for i in range(s))
        for name, value in (("alpha", alpha), ("gamma", gamma), ("b", b),
                            ("nodes", alpha.sum(axis=1)), ("gamma_sums", gamma.sum(axis=1)),
                            ("a_u", alpha @ inv), ("c_u", np.eye(s) / g - inv),
                            ("m_u", b @ inv), ("same_as", same)):
            object.__setattr__(self, name, value)

    @property
    def stages(self) -> int:
        return len(self.b)

    @property
    def gamma_diag(self) -> float:
        return float(self.gamma[0, 0])

    @property
    def evals_per_step(self) -> int:
        """Evaluations of f in one step, derivatives not counted: one per distinct stage
        argument."""
        return len(set(self.same_as))

    @property
    def tableau(self) -> ButcherTableau:
        """The underlying DIRK (A = alpha + Gamma, b): on y' = lambda y the Rosenbrock
        method and it share R(z) = 1 + z b^T (I - z A)^-1 1."""
        a = self.alpha + self.gamma
        return ButcherTableau(a, self.b, a.sum(axis=1))
