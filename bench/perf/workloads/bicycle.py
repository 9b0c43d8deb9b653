"""The benchmark problem every contender solves: the reduced dynamic bicycle, float64, from
seeded operating points across the planner's envelope, N_STEPS fixed steps of H_S."""
import numpy as np

from stepzoo import dynamics

H_S = 0.01          # [s]
N_STEPS = 500
MODEL = dynamics.model("dynamic5")


def problem(batch: int, seed: int = 0):
    """(x0 (B, 5), u (B, 1), p dict of (B,) arrays) as NumPy: speeds 5-25 m/s, steers
    +-0.5 rad, a small initial lateral speed; every point is stable for RK4 at H_S."""
    rng = np.random.default_rng(seed)
    p = {k: np.full(batch, float(v)) for k, v in MODEL.params(None, 15.0).items()}
    p["vx"] = rng.uniform(5.0, 25.0, batch)
    x0 = np.zeros((batch, 5))
    x0[:, 3] = rng.uniform(-1.0, 1.0, batch)
    return x0, rng.uniform(-0.5, 0.5, (batch, 1)), p
