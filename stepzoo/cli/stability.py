"""`stepzoo stability`: at one operating point of any model, the eigenvalues of df/dx at its
initial state and, per method, the largest stable step they predict along the reference
trajectory (frozen Jacobians), with where it binds. The model comes from a sweep config
(CONFIG, the point by --at VAR=VALUE, else the config's trajectory point) or by name
(--model, --tyre; a vehicle model at --vx and --delta). Where the model is not finite on
the reference, no limit is predicted and it says so (exit status 1)."""
import math
import sys

import numpy as np

from stepzoo.errors import UsageError
from stepzoo.output import text_table, to_json
from stepzoo.validate import check

DEFAULT_HORIZON_S = 2.0       # a vehicle model's accuracy horizon, as in the paper


def add_arguments(p):
    p.add_argument("config", metavar="CONFIG", nargs="?",
                   help="a sweep TOML: its model and envelope (instead of --model)")
    p.add_argument("--model", default=None, help="a built-in model (default dynamic5)")
    p.add_argument("--tyre", default=None, help="tyre law of a dynamic bicycle: linear, "
                   "pacejka or fiala")
    p.add_argument("--vx", type=float, help="longitudinal speed [m/s] (vehicle models)")
    p.add_argument("--delta", type=float, help="steer angle [rad] (vehicle models)")
    p.add_argument("--at", action="append", default=[], metavar="VAR=VALUE",
                   help="an envelope variable's value at the point (repeatable)")
    p.add_argument("--vehicle", default=None, help="vehicle set (default: the documented one)")
    p.add_argument("--format", choices=["text", "json"], default="text")


def config_from_args(args):
    """The sweep config whose model and envelope the point is taken from."""
    from stepzoo.bench.sweep.config import load, validate
    if args.config:
        if args.model or args.tyre or args.vehicle:
            raise UsageError("give either CONFIG or --model/--tyre/--vehicle, not both")
        return load(args.config)
    from stepzoo import dynamics
    name = args.model or "dynamic5"
    raw = {"model": name, "steps": {"h": [0.01]}}
    for key in ("tyre", "vehicle"):
        if getattr(args, key) is not None:
            raw[key] = getattr(args, key)
    m = dynamics.MODELS.get(name)
    if m is None:
        raise UsageError(f"unknown model {name!r}; known: {', '.join(dynamics.MODELS)}")
    envelope = {}
    if m.family == "vehicle":
        if args.vx is None or args.delta is None:
            raise UsageError(f"model {name} needs --vx M/S and --delta RAD (the operating "
                             "point)")
        vx, delta = check("speed", "--vx", args.vx), check("steer", "--delta", args.delta)
        speed = "vx" if "vx" in m.states or "vx" in m.defaults else "v"
        envelope = {speed: [vx], "delta": [delta]}
        raw["horizon"] = DEFAULT_HORIZON_S
    else:
        if args.vx is not None or args.delta is not None:
            raise UsageError(f"--vx and --delta are for vehicle models; {name} takes --at")
        first = m.states[0]
        envelope = {first: [float(m.x0[0])]}
        raw["horizon"] = float(m.t_span[1] - m.t_span[0])
    raw["envelope"] = envelope
    return validate(raw, f"--model {name}")


def at_point(cfg, assignments) -> tuple:
    """The operating point: the trajectory point, with --at VAR=VALUE applied."""
    point = dict(zip(cfg.spec.variables, cfg.trajectories.point))
    for item in assignments:
        var, eq, value = item.partition("=")
        if not eq or var not in point:
            raise UsageError(f"--at {item!r}: give VAR=VALUE with VAR one of the envelope's "
                             f"variables ({', '.join(point)})")
        try:
            point[var] = float(value)
        except ValueError:
            raise UsageError(f"--at {item!r}: {value!r} is not a number") from None
        if not math.isfinite(point[var]):
            raise UsageError(f"--at {item!r}: the value must be finite")
    return tuple(point.values())


def predict(cfg, point) -> dict:
    """Eigenvalues at the initial state and, per method, the predicted largest stable step
    [s] along the reference over the config's horizon, where it binds (t [s], lambda);
    model_nan_t [s]: where f or df/dx is first not finite on the reference (None: nowhere),
    and then no method has a prediction."""
    import dataclasses

    from stepzoo.bench.model import frozen_jacobian as frozen
    from stepzoo.bench.model import nonfinite as model_nan
    from stepzoo.bench.sweep.block import Block
    from stepzoo.integrators import METHODS
    spec = dataclasses.replace(cfg.spec, envelope=tuple(
        (var, (value,)) for var, value in zip(cfg.spec.variables, point)))
    one = cfg.changed(spec=spec, chunks={"points": 1},
                      trajectories=cfg.trajectories.at(dict(zip(spec.variables, point))))
    work = Block(one, 0, {})
    along = work.along()
    ts, lam = along.ts, along.lam
    nan_t = float(model_nan.lane_times(work)[0])
    ev = lam[0, 0]
    ev = ev[np.abs(ev) > frozen.REL_ZERO * np.nanmax(np.abs(ev), initial=0.0)]
    methods = {}
    for name, m in METHODS.items():
        h, k, j = frozen.predicted_limit(m, lam[0]) if math.isnan(nan_t) else (math.nan, -1, -1)
        methods[name] = {"max_stable_step": None if not math.isfinite(h) else h,
                         "t_bind": None if k < 0 else float(ts[k]),
                         "lambda_bind": None if k < 0 else [float(lam[0, k, j].real),
                                                            float(lam[0, k, j].imag)]}
    return {"model": cfg.spec.name, "point": dict(zip(cfg.spec.variables, point)),
            "horizon_s": cfg.horizon, "jacobian_finite": math.isnan(nan_t),
            "model_nan_t": None if math.isnan(nan_t) else nan_t,
            "eigenvalues": [[float(e.real), float(e.imag)]
                            for e in sorted(ev, key=lambda z: (z.real, z.imag))],
            "methods": methods}


def main(args) -> int:
    from stepzoo.bench.model import nonfinite as model_nan
    cfg = config_from_args(args)
    out = predict(cfg, at_point(cfg, args.at))
    if "vx" in out["point"] and "delta" in out["point"]:
        out = {"vx": out["point"]["vx"], "delta": out["point"]["delta"], **out}
    # No prediction where the model is not finite: a correct run without an answer.
    status = 0 if out["jacobian_finite"] else 1
    if args.format == "json":
        print(to_json(out))
        return status
    point = ", ".join(f"{k} = {v:g}" for k, v in out["point"].items())
    print(f"{out['model']} at {point}")
    if not out["jacobian_finite"]:
        print(f"the Jacobian is not finite at this point ({model_nan.cause(out['model_nan_t'])}"
              " on the reference): no largest stable step is predicted")
        return status
    print("eigenvalues of df/dx at the initial state [1/s]: "
          + ", ".join(f"{re:.4g}{im:+.4g}j" for re, im in out["eigenvalues"]))
    rows = [{"method": k, "max_stable_step_s": v["max_stable_step"], "binds_at_t_s": v["t_bind"]}
            for k, v in out["methods"].items()]
    sys.stdout.write(text_table(rows, ["method", "max_stable_step_s", "binds_at_t_s"]) + "\n")
    print(f"(smallest over the reference trajectory on [0, {out['horizon_s']:g}] s; '-': no "
          "limit, A-stable on these eigenvalues)")
    return 0
