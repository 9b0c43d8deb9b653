"""`stepzoo simulate`: one trajectory of a vehicle model from rest with a constant steer, by
one method of the zoo or by the adaptive reference, as CSV or JSON on stdout."""
import csv
import io
import json
import math
import sys

import numpy as np

from stepzoo.errors import UsageError
from stepzoo.validate import check, check_budget, lookup


def add_arguments(p):
    p.add_argument("--method", required=True, help="a name from `stepzoo methods`, or reference")
    p.add_argument("--h", type=float, required=True, help="step size [s]")
    p.add_argument("--T", type=float, required=True, help="horizon [s]")
    p.add_argument("--vx", type=float, required=True, help="longitudinal speed [m/s]")
    p.add_argument("--delta", type=float, required=True, help="steer angle [rad]")
    p.add_argument("--vehicle", default=None, help="vehicle set (default: the documented one)")
    p.add_argument("--model", default="dynamic5", help="dynamic5 | dynamic6 | kinematic | st")
    p.add_argument("--tyre", default=None,
                   help="tyre of the dynamic bicycles: linear (default) | pacejka | fiala")
    p.add_argument("--rtol", type=float, default=1e-10, help="reference relative tolerance")
    p.add_argument("--atol", type=float, default=1e-12, help="reference absolute tolerance")
    p.add_argument("--format", choices=["csv", "json"], default="csv")


def simulate(method_name, h, T, vx, delta, vehicle=None, model_name="dynamic5",
             rtol=1e-10, atol=1e-12, tyre=None):
    """(columns, t, x, vehicle dict) of one run; raises UsageError on bad input."""
    from stepzoo import dynamics
    from stepzoo.integrators import integrate, method
    from stepzoo.integrators.reference import reference
    h, T = check("step", "--h", h), check("horizon", "--T", T)
    vx, delta = check("speed", "--vx", vx), check("steer", "--delta", delta)
    if h > T:
        raise UsageError(f"--h {h} is larger than the horizon --T {T}; use h <= T")
    if method_name == "reference":
        check("rtol", "--rtol", rtol), check("atol", "--atol", atol)
    from stepzoo.dynamics.models import VEHICLE_MODELS
    if model_name not in VEHICLE_MODELS:
        lookup("model", dynamics.model, model_name)
        raise UsageError(f"simulate runs the vehicle models ({', '.join(VEHICLE_MODELS)}), "
                         f"not {model_name!r}")
    model = lookup("model", lambda name: dynamics.model(name, tyre=tyre), model_name)
    veh = lookup("vehicle", dynamics.vehicle, vehicle)
    p = lookup("vehicle", lambda name: model.params(name, vx), vehicle)
    x0, u = model.from_rest(vx, delta)
    n = int(round(T / h))
    if abs(n * h - T) > 1e-9 * T:
        n = int(math.floor(T / h))
    check_budget(f"a run of {n:.3g} steps", n + 1, 1, len(model.states))
    if method_name == "reference":
        ts = h * np.arange(n + 1)
        ref = reference(model.rhs, x0, u, p, ts, rtol=rtol, atol=atol)
        t, x = np.asarray(ts), np.asarray(ref.x)
    else:
        meth = lookup("method", method, method_name)
        tr = integrate(meth, model.rhs, x0, u, p, h, n)
        t, x = np.asarray(tr.t), np.asarray(tr.x)
    return ["t", *model.states], t, x, veh


def _tyre(model_name, tyre):
    """The tyre law the run used (null for the models without tyres)."""
    from stepzoo import dynamics
    return dynamics.model(model_name, tyre=tyre).tyre


def main(args) -> int:
    cols, t, x, veh = simulate(args.method, args.h, args.T, args.vx, args.delta, args.vehicle,
                               args.model, args.rtol, args.atol, args.tyre)
    if args.format == "json":
        vehicle = {k: veh[k] for k in ("name", "m", "Iz", "Lf", "Lr", "Caf", "Car",
                                       "length", "width", "source")}
        # Blow-up is a result: non-finite values are written as null, not dropped.
        xs = [[float(v) if np.isfinite(v) else None for v in row] for row in x]
        sys.stdout.write(json.dumps({"columns": cols, "t": t.tolist(), "x": xs,
                                     "method": args.method, "h": args.h, "vx": args.vx,
                                     "delta": args.delta, "model": args.model,
                                     "tyre": _tyre(args.model, args.tyre), "vehicle": vehicle})
                         + "\n")
    else:
        write_csv(cols, t, x)
    return 0


# Rows formatted per write: the text of a run of millions of steps is never held whole (it
# is several times the trajectory's own memory), so a run that fits in memory prints.
CSV_BLOCK_ROWS = 10_000


def write_csv(cols, t, x) -> None:
    """The header and one row per time, each float as repr writes it, to stdout in blocks of
    CSV_BLOCK_ROWS rows."""
    sys.stdout.write(",".join(cols) + "\n")
    for start in range(0, len(t), CSV_BLOCK_ROWS):
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        for ti, row in zip(t[start:start + CSV_BLOCK_ROWS], x[start:start + CSV_BLOCK_ROWS]):
            w.writerow([repr(float(ti))] + [repr(float(v)) for v in row])
        sys.stdout.write(buf.getvalue())
