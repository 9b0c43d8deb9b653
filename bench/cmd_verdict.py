"""`stepzoo verdict CONFIG --method M --h H [--tol E | --pos-tol M]`: where in a config's
envelope a fixed (method, h) is stable and accurate and where not, with the worst error."""
import math
import sys

from stepzoo.errors import UsageError
from stepzoo.output import text_table, to_json
from stepzoo.validate import check


def add_arguments(p):
    p.add_argument("config", metavar="CONFIG", help="a sweep TOML: the model and envelope")
    p.add_argument("--method", required=True, action="append", metavar="NAME",
                   help="the method (repeat with --h for several configurations)")
    p.add_argument("--h", required=True, type=float, action="append", metavar="SECONDS",
                   help="its fixed step [s]")
    p.add_argument("--tol", type=float, help="accurate: error norm <= E (default 0.01)")
    p.add_argument("--pos-tol", type=float, metavar="METRES",
                   help="accurate: position error <= M [m] (vehicle models)")
    p.add_argument("--format", choices=["text", "json"], default="text")


def main(args) -> int:
    from stepzoo.bench import model_nan
    from stepzoo.bench.sweep_config import load
    from stepzoo.bench.verdict import region, verdict
    from stepzoo.integrators import METHODS
    if len(args.method) != len(args.h):
        raise UsageError("give one --h per --method")
    for name in args.method:
        if name not in METHODS:
            raise UsageError(f"unknown method {name!r}; known: {', '.join(METHODS)}")
    hs = [check("step", "--h", h) for h in args.h]
    if args.pos_tol is not None and args.tol is not None:
        raise UsageError("give --tol or --pos-tol, not both")
    column, tol = ("err_pos", check("pos_tol", "--pos-tol", args.pos_tol)) \
        if args.pos_tol is not None else ("err", check("tol", "--tol", args.tol or 0.01))
    cfg = load(args.config)
    if column == "err_pos" and not cfg.spec.vehicle:
        raise UsageError(f"{cfg.model} has no position (X, Y); use --tol E")
    variables = list(cfg.spec.variables)
    out = []
    for name, h in zip(args.method, hs):
        table = verdict(cfg, name, h)
        good = table["stable"] & (table[column] <= tol)
        worst = table.loc[table[column].idxmax()]
        out.append({
            "method": name, "h": h, "points": len(table), "stable": int(table["stable"].sum()),
            "accurate": int(good.sum()),
            "unstable_where": region(table, ~table["stable"] & (table["cause"] == "unstable"),
                                     variables),
            "solver_failed_where": region(table, table["cause"] == "solver failed", variables),
            "model_nan_where": region(table, table["cause"].str.startswith(model_nan.PREFIX),
                                      variables),
            "inaccurate_where": region(table, table["stable"] & ~good, variables),
            "worst_error": float(worst[column]),
            "worst_at": {v: float(worst[v]) for v in variables},
            "h_pred_min": float(table["h_pred"].min()),
            "tolerance": {column: tol},
        })
    if args.format == "json":
        # JSON has no inf: a blown-up worst error is null.
        for v in out:
            v["worst_error"] = None if math.isinf(v["worst_error"]) else v["worst_error"]
        print(to_json({"model": cfg.model, "config": str(args.config), "verdicts": out}))
        return 0
    unit = " m" if column == "err_pos" else ""
    for v in out:
        worst = ("inf (blows up)" if math.isinf(v["worst_error"])
                 else f"{v['worst_error']:.3g}{unit}")
        print(f"{v['method']} at h = {v['h']:g} s on {cfg.model} ({v['points']} points): "
              f"stable at {v['stable']}, within {tol:g}{unit} at {v['accurate']}; smallest "
              f"predicted limit {v['h_pred_min']:.4g} s")
        rows = [{"verdict": "unstable", "where": v["unstable_where"]},
                {"verdict": "solver failed", "where": v["solver_failed_where"]},
                {"verdict": "model returned NaN", "where": v["model_nan_where"]},
                {"verdict": "stable, not accurate", "where": v["inaccurate_where"]},
                {"verdict": "worst error", "where": f"{worst} at " + ", ".join(
                    f"{k} = {x:.4g}" for k, x in v["worst_at"].items())}]
        sys.stdout.write(text_table(rows, ["verdict", "where"]) + "\n")
    return 0
