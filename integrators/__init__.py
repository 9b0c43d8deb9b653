"""The integrator zoo: fixed-step methods as data plus one generic step, one scan driver,
the adaptive Dormand-Prince reference and stability analysis."""
from stepzoo.integrators.driver import Trajectory, integrate, integrate_batch
from stepzoo.integrators.methods import METHODS, Method, describe, method

__all__ = ["METHODS", "Method", "Trajectory", "describe", "integrate", "integrate_batch", "method"]
