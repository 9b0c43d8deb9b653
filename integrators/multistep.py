"""Linear multistep methods sum_j alpha_j y_{n+j} = h sum_j beta_j f_{n+j} (j = 0..k,
alpha_k = 1), with factories for Adams-Bashforth, Adams-Moulton and BDF of any step count."""
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import polynomial as P


@dataclass(frozen=True)
class LinearMultistep:
    alpha: np.ndarray
    beta: np.ndarray

    def __post_init__(self):
        alpha, beta = np.asarray(self.alpha, float), np.asarray(self.beta, float)
        if alpha.shape != beta.shape or alpha[-1] != 1.0:
            raise ValueError("alpha and beta need k+1 entries each, with alpha_k = 1")
        j = np.arange(len(alpha))
        if abs(alpha.sum()) > 1e-13 or abs((j * alpha).sum() - beta.sum()) > 1e-13:
            raise ValueError("coefficients are not consistent (rho(1) = 0, rho'(1) = sigma(1))")
        object.__setattr__(self, "alpha", alpha)
        object.__setattr__(self, "beta", beta)

    @property
    def steps(self) -> int:
        return len(self.alpha) - 1

    @property
    def explicit(self) -> bool:
        return self.beta[-1] == 0.0

    @property
    def uses_slopes(self) -> bool:
        """Whether a step needs the past slopes f_n .. f_{n+k-1} (not BDF's: beta_j = 0 for
        j < k), and so an evaluation of f at each new state."""
        return bool(np.any(self.beta[:-1] != 0.0))

    @property
    def predictor(self) -> np.ndarray:
        """Weights on the last k values (oldest first) of the polynomial through them,
        evaluated one step ahead: the Newton start of an implicit step, as in DASSL and VODE
        (no slope in it, so a stiff component does not throw it off)."""
        k = self.steps
        return np.array([P.polyval(float(k), _lagrange(np.arange(k, dtype=float), j))
                         for j in range(k)])


def _lagrange(nodes, i):
    """Coefficients (low to high) of the Lagrange basis polynomial of node i."""
    poly = np.array([1.0])
    for m, xm in enumerate(nodes):
        if m != i:
            poly = P.polymul(poly, np.array([-xm, 1.0]) / (nodes[i] - xm))
    return poly


def _integral_0_1(poly):
    antider = P.polyint(poly)
    return P.polyval(1.0, antider) - P.polyval(0.0, antider)


def adams_bashforth(k: int) -> LinearMultistep:
    """k-step explicit Adams, order k: interpolate f at s = 0, -1, ..., -(k-1), integrate 0..1."""
    nodes = -np.arange(k, dtype=float)
    beta = np.zeros(k + 1)
    for i in range(k):
        beta[k - 1 - i] = _integral_0_1(_lagrange(nodes, i))
    alpha = np.zeros(k + 1)
    alpha[k], alpha[k - 1] = 1.0, -1.0
    return LinearMultistep(alpha, beta)


def adams_moulton(k: int) -> LinearMultistep:
    """k-step implicit Adams, order k + 1: nodes s = 1, 0, ..., -(k-1)."""
    nodes = 1.0 - np.arange(k + 1, dtype=float)
    beta = np.zeros(k + 1)
    for i in range(k + 1):
        beta[k - i] = _integral_0_1(_lagrange(nodes, i))
    alpha = np.zeros(k + 1)
    alpha[k], alpha[k - 1] = 1.0, -1.0
    return LinearMultistep(alpha, beta)


def bdf(k: int) -> LinearMultistep:
    """k-step backward differentiation formula, order k: differentiate the interpolant of
    y at s = 1, 0, ..., 1-k at s = 1 and set it to h f_{n+1}."""
    nodes = 1.0 - np.arange(k + 1, dtype=float)
    d = np.array([P.polyval(1.0, P.polyder(_lagrange(nodes, i))) for i in range(k + 1)])
    alpha = d[::-1] / d[0]
    beta = np.zeros(k + 1)
    beta[k] = 1.0 / d[0]
    return LinearMultistep(alpha, beta)
