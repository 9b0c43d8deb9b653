"""`stepzoo stability`: eigenvalues of the linearised lateral dynamics at an operating point
and, per method, the largest stable step they predict."""
import math
import sys

import numpy as np

from stepzoo.output import text_table, to_json
from stepzoo.validate import check, lookup


def add_arguments(p):
    p.add_argument("--vx", type=float, required=True, help="longitudinal speed [m/s]")
    p.add_argument("--delta", type=float, required=True, help="steer angle [rad]")
    p.add_argument("--vehicle", default=None, help="vehicle set (default: the documented one)")
    p.add_argument("--format", choices=["text", "json"], default="text")


def predict(vx: float, delta: float, vehicle=None) -> tuple[np.ndarray, dict]:
    """(eigenvalues [1/s], {method: largest stable step [s] or inf})."""
    from stepzoo import dynamics
    from stepzoo.dynamics.linear import lateral_eigenvalues
    from stepzoo.integrators import METHODS
    from stepzoo.integrators.stability import max_stable_step
    vx, delta = check("speed", "--vx", vx), check("steer", "--delta", delta)
    lookup("vehicle", dynamics.vehicle, vehicle)
    ev = np.asarray(lateral_eigenvalues(vx, delta, dynamics.physical(vehicle)))
    return ev, {name: max_stable_step(m, ev) for name, m in METHODS.items()}


def main(args) -> int:
    ev, hmax = predict(args.vx, args.delta, args.vehicle)
    if args.format == "json":
        out = {"vx": args.vx, "delta": args.delta,
               "eigenvalues": [[float(e.real), float(e.imag)] for e in ev],
               "methods": {k: {"max_stable_step": None if math.isinf(h) else h}
                           for k, h in hmax.items()}}
        print(to_json(out))
    else:
        print("eigenvalues [1/s]: " + ", ".join(f"{e.real:.4g}{e.imag:+.4g}j" for e in ev))
        rows = [{"method": k, "max_stable_step_s": None if math.isinf(h) else h}
                for k, h in hmax.items()]
        sys.stdout.write(text_table(rows, ["method", "max_stable_step_s"]) + "\n")
        print("('-': A-stable, no step-size limit from stability)")
    return 0
