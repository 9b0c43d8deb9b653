"""`stepzoo verdict CONFIG --method M --h H [--tol E | --pos-tol M] [--margin F] [--csv FILE]`:
for a fixed (method, h), point by point over a config's envelope, whether it is stable (with
the margin `tune` keeps, or how close to the limit) and accurate; then where each verdict
holds, and the worst error."""
import math
import sys

from stepzoo.errors import UsageError
from stepzoo.output import text_table, to_json
from stepzoo.validate import DEFAULT_MARGIN, check


def add_arguments(p):
    p.add_argument("config", metavar="CONFIG", help="a sweep TOML: the model and envelope")
    p.add_argument("--method", required=True, action="append", metavar="NAME",
                   help="the method (repeat with --h for several configurations)")
    p.add_argument("--h", required=True, type=float, action="append", metavar="SECONDS",
                   help="its fixed step [s]")
    p.add_argument("--tol", type=float, help="accurate: error norm <= E (default 0.01)")
    p.add_argument("--pos-tol", type=float, metavar="METRES",
                   help="accurate: position error <= M [m] (vehicle models)")
    p.add_argument("--margin", type=float, default=DEFAULT_MARGIN, metavar="FRACTION",
                   help="stable with margin: h <= (1 - margin) x the measured largest stable "
                   f"step at the point, as `stepzoo tune` keeps (default {DEFAULT_MARGIN})")
    p.add_argument("--allow-beyond-predicted-limit", action="store_true",
                   help="risky: call a step stable with margin above its predicted "
                   "(frozen-Jacobian) largest stable step where the measurement saw no "
                   "instability; by default the margin is kept below the smaller of the "
                   "predicted and measured limits")
    p.add_argument("--csv", metavar="FILE", help="also write one row per (method, h, point) "
                   "to this CSV file")
    p.add_argument("--format", choices=["text", "json"], default="text")


def _csv(path, cfg, results, config) -> None:
    import pandas as pd

    from stepzoo.bench.tune.verdict import POINT_FIELDS
    from stepzoo.output import atomic_write
    from stepzoo.results_folder import VERDICT_CSV, check_file_target
    check_file_target(path, "--csv", kind=VERDICT_CSV, inputs=[config])
    variables = list(cfg.spec.variables)
    frames = [t.assign(method=v["method"], h=v["h"])[["method", "h", "point", *variables,
                                                       *POINT_FIELDS]] for v, t in results]
    atomic_write(path, pd.concat(frames, ignore_index=True).to_csv(index=False))


def main(args) -> int:
    from stepzoo.bench.sweep.engine import _finite
    from stepzoo.bench.sweep.config import load
    from stepzoo.bench.tune.verdict import verdicts
    from stepzoo.integrators import METHODS
    if len(args.method) != len(args.h):
        raise UsageError("give one --h per --method")
    for name in args.method:
        if name not in METHODS:
            raise UsageError(f"unknown method {name!r}; known: {', '.join(METHODS)}")
    hs = [check("step", "--h", h) for h in args.h]
    if args.pos_tol is not None and args.tol is not None:
        raise UsageError("give --tol or --pos-tol, not both")
    margin = check("margin", "--margin", args.margin)
    # --tol 0 is checked (and refused), not taken for the default.
    tol_given = 0.01 if args.tol is None else args.tol
    column, tol = ("err_pos", check("pos_tol", "--pos-tol", args.pos_tol)) \
        if args.pos_tol is not None else ("err", check("tol", "--tol", tol_given))
    if args.csv is not None:
        from stepzoo.results_folder import VERDICT_CSV, check_file_target
        # refused before the work, not after
        check_file_target(args.csv, "--csv", kind=VERDICT_CSV, inputs=[args.config])
    cfg = load(args.config)
    if column == "err_pos" and not cfg.spec.vehicle:
        raise UsageError(f"{cfg.spec.name} has no position (X, Y); use --tol E")
    unit = " m" if column == "err_pos" else ""
    results = verdicts(cfg, list(zip(args.method, hs)), column, tol, margin, unit,
                       args.allow_beyond_predicted_limit)
    if args.csv is not None:
        _csv(args.csv, cfg, results, args.config)
    if args.format == "json":
        out = []
        for v, _ in results:
            v = dict(v)
            v["points"], v["n_points"] = v.pop("points_list"), v["points"]
            # JSON has neither inf nor NaN: a blown-up worst error, an unbounded limit, a limit
            # where the model returned NaN, is null.
            for key in ("worst_error", "h_meas_min", "h_pred_min", "h_over_h_pred_max"):
                v[key] = v[key] if math.isfinite(v[key]) else None
            v["stiffness"] = _finite(v["stiffness"])
            out.append(v)
        print(to_json({"model": cfg.spec.name, "config": str(args.config), "verdicts": out}))
        return 0
    for v, table in results:
        _show(cfg, v, table, tol, unit)
    if args.csv is not None:
        print(f"wrote {args.csv}: one row per (method, h, operating point)")
    return 0


def _show(cfg, v, table, tol, unit) -> None:
    variables = list(cfg.spec.variables)
    # An infinite error is a run that left the finite range: it blows up (or a failed solve
    # left it so); a finite error at an unstable point is a bounded instability.
    first = v["worst_cause"].split("; ")[0]
    if math.isinf(v["worst_error"]):
        worst = f"inf ({'blows up' if first == 'unstable' else first})"
    else:
        worst = f"{v['worst_error']:.3g}{unit}" + (
            f" ({first}, the run stays finite)" if first in ("unstable", "solver failed")
            else "")
    # As the sweep's summary does, a limit where a nonlinear solve failed is the solver's,
    # told apart from the measured stability limits.
    solver = table["limit_cause"] == "solver failed"
    own = table.loc[~solver, "h_meas"]
    # inf: no blow-up up to h_probe_max; NaN: the model returned NaN there.
    own = own[own.map(math.isfinite)]
    measured = f"smallest measured {own.min():.4g} s" if len(own) else "no measured limit"
    if solver.any():
        measured += (f"; a nonlinear solve failed above {table.loc[solver, 'h_meas'].min():.4g}"
                     f" s at {int(solver.sum())} point(s)")
    print(f"{v['method']} at h = {v['h']:g} s on {cfg.spec.name} ({v['points']} points): "
          f"stable at {v['stable']} ({v['stable_with_margin']} with margin {v['margin']:g}), "
          f"within {tol:g}{unit} at {v['accurate']}; smallest predicted limit "
          f"{v['h_pred_min']:.4g} s, {measured}")
    if v["beyond_predicted"]:
        print(f"beyond the predicted limit at {v['beyond_predicted']} point(s), up to "
              f"{v['h_over_h_pred_max']:.3g} x h_pred: "
              + ("allowed by --allow-beyond-predicted-limit" if
                 v["allow_beyond_predicted_limit"] else "never called stable with margin"))
    print(v["stiffness"]["says"])
    rows = [{**{k: r[k] for k in variables},
             **{"h/h_meas": r["h_over_h_meas"], "stable": "yes" if r["stable"] else "no",
                "error": r["error"], "accurate": "yes" if r["accurate"] else "no",
                "verdict": r["verdict"]}} for _, r in table.iterrows()]
    sys.stdout.write(text_table(rows, [*variables, "h/h_meas", "stable", "error", "accurate",
                                       "verdict"]) + "\n")
    summary = [{"verdict": k["verdict"], "points": k["points"], "where": k["where"]}
               for k in v["classes"]]
    summary.append({"verdict": "worst error", "points": "", "where": f"{worst} at " + ", ".join(
        f"{k} = {x:.4g}" for k, x in v["worst_at"].items())})
    sys.stdout.write(text_table(summary, ["verdict", "points", "where"]) + "\n")
