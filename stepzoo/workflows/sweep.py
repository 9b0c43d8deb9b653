"""A sweep as the commands run it: a config file (one model or a suite) swept into a results
folder, here or on a Dask cluster, and its summary printed."""
import sys
from typing import Callable

from stepzoo.bench.model import nonfinite as model_nan
from stepzoo.output import text_table, to_json


def sweep(config, out, *, resume=False, overwrite=False, progress=True,
          scheduler=None, runner=None) -> dict:
    """Run the sweep of the TOML file `config` into the folder `out` (on the Dask cluster at
    `scheduler` if given, or through run_sweep's `runner`) and return its manifest. `stepzoo
    sweep` and `stepzoo run` call it."""
    from stepzoo.bench.sweep.suite import SuiteConfig, load, run_suite
    from stepzoo.bench.sweep.engine import run_sweep
    cfg = load(config)
    run: Callable[..., dict] = run_suite if isinstance(cfg, SuiteConfig) else run_sweep
    if scheduler is None:
        return run(cfg, out, resume=resume, overwrite=overwrite, progress=progress,
                   runner=runner)
    from stepzoo.bench.sweep.distributed import sweep_runner
    from stepzoo.distributed import connect
    with connect(scheduler) as client:
        return run(cfg, out, resume=resume, overwrite=overwrite, progress=progress,
                   runner=sweep_runner(client))


def show(manifest: dict, out, fmt: str = "text") -> None:
    """Print what a sweep into `out` did: the summary table, whether the model is stiff (at
    the report's default tolerance) and timing, or JSON."""
    import pandas as pd

    from stepzoo.bench.sweep.engine import _finite
    suite = bool(manifest.get("problems"))
    if fmt == "json":
        print(to_json({"out": str(out), "config_sha256": manifest["config_sha256"],
                       "timing": manifest["timing"],
                       **({} if suite else {"stiffness": _finite(stiffness(out))})}))
        return
    t = manifest["timing"]
    if suite:
        _show_suite(manifest, out)
        return
    summary = pd.read_csv(f"{out}/summary.csv").to_dict("records")
    # A failed nonlinear solve is the solver's limit, shown apart from the method's.
    solver = ["solver_limited_points", "h_solver_limit_min"] \
        if any(r.get("solver_limited_points", 0) for r in summary) else []
    sys.stdout.write(text_table(summary, ["method", "order_declared", "order_fit_median",
                                          "h_pred_min", "h_meas_min", "worst_ratio",
                                          *solver]) + "\n")
    found = stiffness(out)
    (tol_column, tol), = found["tolerance"].items()
    print(f"at {tol_column} <= {tol:g} (the report's default): {found['says']}")
    nan_note = model_nan.note(pd.read_csv(f"{out}/limits.csv"),
                              manifest["model_spec"]["variables"])
    if nan_note:
        print(nan_note)
    compile_s = ", ".join(f"{k} {v:.2f}" for k, v in t["compile_s"].items())
    for note in dict.fromkeys(r.get("nonsmooth_note") for r in summary):
        if isinstance(note, str) and note:         # where f is not smooth, and the remedy
            print(note)
    print(f"wrote {out}: runs.parquet, limits.parquet/csv, summary.parquet/csv, "
          "eigenvalues.parquet, trajectories.parquet, manifest.json")
    print(f"timing [s]: total {t['total_s']:.1f} (this call {t['wall_s']:.1f}); compile "
          f"{sum(t['compile_s'].values()):.1f} ({compile_s}); reference {t['reference_s']:.1f}; "
          f"integration {t['integration_s']:.1f}; stability {t['stability_s']:.1f}; "
          f"metrics {t['metrics_s']:.1f}")


def _show_suite(manifest: dict, out) -> None:
    """Observed orders, method by problem (NaN: not observable, or not one of the problem's
    methods), where they differ from the declared ones, what was written and the time it
    took."""
    import pandas as pd

    from stepzoo.bench.sweep import metrics
    orders = pd.read_csv(f"{out}/orders.csv")
    columns = list(orders.columns)
    rows = [{k: (round(v, 2) if isinstance(v, float) else v) for k, v in r.items()}
            for r in orders.to_dict("records")]
    sys.stdout.write("observed order (asymptotic range; NaN: not observable, or the method "
                     "is not one of that problem's)\n"
                     + text_table(rows, columns) + "\n")
    summary = pd.read_csv(f"{out}/summary.csv")
    off = summary[summary["order_status"] != "matches"]
    print(metrics.orders_matched(summary["order_status"], manifest["order_tolerance"])
          + (": the rest " + ", ".join(f"{s} {n}" for s, n in
                                       off["order_status"].value_counts().items())
             if len(off) else ""))
    sys.stdout.write("by method: problems that match, and the others (observed order, status)\n"
                     + text_table(_by_method(summary), ["method", "declared", "matches",
                                                        "others"]) + "\n")
    print(f"wrote {out}: one sweep folder per problem ({', '.join(manifest['problems'])}), "
          "and all of them in runs.parquet, limits.parquet/csv, summary.parquet/csv, "
          "eigenvalues.parquet, trajectories.parquet (column problem), orders.csv, "
          "manifest.json")
    t = manifest["timing"]
    print(f"timing [s]: total {t['total_s']:.1f} (this call {t['wall_s']:.1f})")


def _by_method(summary) -> list[dict]:
    """One row per method: how many problems match its declared order, and each other
    problem with its observed order and status."""
    rows = []
    for name, own in summary.groupby("method", sort=True):
        off = own[own["order_status"] != "matches"]
        rows.append({"method": name, "declared": int(own["order_declared"].iloc[0]),
                     "matches": f"{len(own) - len(off)}/{len(own)}",
                     "others": "; ".join(f"{r.problem} {r.order_fit_median:.2f} "
                                         f"{r.order_status}" for r in off.itertuples())})
    return rows


def stiffness(out) -> dict:
    """Whether the swept model is stiff (bench/model/stiffness.py) at the report's default
    tolerance (position, or the error norm), from the folder's tables and config."""
    import pandas as pd

    from stepzoo.bench.model import stiffness as rule
    from stepzoo.bench.sweep.config import load
    from stepzoo.workflows.report import DEFAULT_POS_TOL_M, DEFAULT_TOL
    runs, limits = (pd.read_parquet(f"{out}/{t}.parquet") for t in ("runs", "limits"))
    cfg = load(f"{out}/config.toml")
    column, tol = ("err_pos", DEFAULT_POS_TOL_M) if "err_pos" in runs else ("err", DEFAULT_TOL)
    found = rule.of_sweep(runs, limits, column, tol, cfg, list(cfg.spec.variables))
    return {**found, "tolerance": {column: tol}}
