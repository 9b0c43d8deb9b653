"""The connection OCP (search.planner.connection_ocp) with single and multiple shooting on
seeded problems
3-30 m apart, after a warm-up that builds each solver."""
import numpy as np
import pytest

from stepzoo.dynamics.vehicles import vehicle
from stepzoo.search.planner.connection_ocp import connect

CAR = vehicle("bmw320i")
L, M = CAR["Lf"] + CAR["Lr"], CAR["m"]


def problems(n=5, seed=0):
    """(start [X, Y, theta, v], goal [X, Y, theta]) pairs in [m, rad, m/s]."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        start = np.r_[rng.uniform(-10, 10, 2), rng.uniform(-np.pi, np.pi), rng.uniform(0, 10)]
        d, bearing = rng.uniform(3, 30), rng.uniform(-np.pi, np.pi)
        out.append((start, np.r_[start[:2] + d * np.array([np.cos(bearing), np.sin(bearing)]),
                                 rng.uniform(-np.pi, np.pi)]))
    return out


@pytest.mark.parametrize("shooting", ("single", "multiple"))
def test_connect(benchmark, shooting):
    cases = problems()
    solve = lambda: [connect(s, g, L=L, m=M, shooting=shooting) for s, g in cases]
    solved = benchmark.pedantic(solve, rounds=3, warmup_rounds=1)
    benchmark.extra_info.update(kind="connect", shooting=shooting, problems=len(cases),
                                solved=sum(c.success for c in solved))
