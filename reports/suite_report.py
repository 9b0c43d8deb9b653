"""The report of a suite's sweep folder (several problems, `stepzoo sweep` of a config with
[[problem]] tables): observed against declared order, method by problem, with the range each
order was fitted on and why it could not be where it could not; then one work-precision
figure per problem (error against RHS evaluations and against wall time, the fastest of the
timed rounds), as DiffEqDevTools users read them."""
from __future__ import annotations

import json
from functools import partial
from pathlib import Path

from stepzoo import environment
from stepzoo.bench.sweep import metrics
from stepzoo.bench.sweep.engine import most_common
from stepzoo.errors import UsageError
from stepzoo.reports import figure_data, interactive, tables
from stepzoo.reports.drawing import draw_all
from stepzoo.reports.tables import _plain
from stepzoo.reports.html import write_report
from stepzoo.reports.load import load_sweep
from stepzoo.reports.provenance import environment_table, public_path
from stepzoo.results_folder import check_kind, replacing
from stepzoo.safe_parse import json_loads

ORDER_COLUMNS = [
    ("problem", "problem"), ("method", "method"), ("order_declared", "declared order"),
    ("order_fit_median", "observed order"), ("order_h_min", "fitted from h [s]"),
    ("order_h_max", "to h [s]"), ("order_h_rho", "h rho at the finest"),
    ("order_status", "status"), ("note", "why not observable"),
]


def suite_manifest(folder) -> dict | None:
    """The manifest of the suite whose sweep `folder` holds (its "problems" a non-empty
    list); None when it holds one sweep."""
    path = Path(folder) / "manifest.json"
    try:
        manifest = json_loads(path.read_text()) if path.is_file() else {}
    except (json.JSONDecodeError, UnicodeDecodeError):
        return None
    problems = manifest.get("problems")
    return manifest if isinstance(problems, list) and problems else None


def build(results, manifest, out, progress_say):
    """Write the report of the suite in `results` (its manifest from suite_manifest) into
    `out`; returns (index, summary, shown)."""
    started = environment.now()
    results = Path(results)
    if not manifest.get("complete"):
        raise UsageError(f"{results} holds an unfinished suite; finish it: rerun `stepzoo "
                         f"sweep {results / 'config.toml'} --out {results} --resume`")
    out = check_kind(out, "report")
    sweeps = {label: load_sweep(results / label) for label in manifest["problems"]}
    progress_say(f"read the suite's {len(sweeps)} problems")
    rows = order_rows(sweeps)
    with replacing(out, "report") as into:    # a kill leaves the old report whole
        shown, plots = draw_all(
            [partial(figure_data.work_precision, sweep, None, number, label)
             for number, (label, sweep) in enumerate(sweeps.items(), 1)], into, progress_say)
        facts = [("suite folder", public_path(results, out)),
                 ("suite config sha256", manifest.get("config_sha256", "not recorded")),
                 ("problems", ", ".join(sweeps)),
                 ("orders", metrics.orders_matched(
                     (r["order_status"] for r in rows),
                     manifest.get("order_tolerance", metrics.ORDER_TOL))),
                 ("order fit", manifest.get("order_fit", "not recorded"))]
        table = tables.Table(
            "Observed and declared orders", "Per problem and method: the observed order "
            "(slope of log error on log h on the asymptotic range the fit chose, median over "
            "operating points), the range of steps it was fitted on, and its status against "
            "the declared order; where no order can be observed (unstable at every step, as "
            "explicit methods on stiff problems; errors above the solution's size or at the "
            "reference's accuracy) the reason is given. h rho is the fit's finest step times the "
            "largest spectral radius of the Jacobian along the reference: an order that "
            "misses where it exceeds 1 is in the stiff range, where order reduction is the "
            "theory. 'limited by non-smooth f': the model's right-hand side jumps, or its "
            "Jacobian does, along the references (a clamp, a switch), which caps every "
            "method's order.", rows, ORDER_COLUMNS)
        own = environment.provenance("report", started, environment.now())
        appendix = [environment_table({"suite": manifest, "this report": own}, out)]
        index, md = write_report(into, f"stepzoo report: suite {manifest.get('config_name')}",
                                 facts, [table], shown, plots, interactive.plotly_js(),
                                 appendix)
        environment.write_manifest(into, "report", started, {
            "suite": public_path(results, out), "problems": list(sweeps),
            "files": ["index.html", "summary.md", *[n for f in shown for n, _ in f.images]]})
    return out / index.name, out / md.name, shown


def order_rows(sweeps: dict) -> list[dict]:
    """One row per (problem, method): the summary's orders and, where the order is not
    observable, the operating points' most common reason (limits' order_note)."""
    rows = []
    for label, sweep in sweeps.items():
        notes = sweep.limits.groupby("method")["order_note"].agg(most_common)
        for _, s in sweep.summary.iterrows():
            row = {key: _plain(s.get(key)) for key, _ in ORDER_COLUMNS if key in s.index}
            row["problem"] = label
            row["note"] = "" if s["order_status"] == "matches" else notes.get(s["method"], "")
            if s["order_status"] == "limited by non-smooth f":
                row["note"] = s["nonsmooth_note"]          # where, what, and the remedy
            rows.append(row)
    return rows
