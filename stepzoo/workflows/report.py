"""Report assembly: the sweep folder, tuned config, plans and plan-bench folder loaded, every
figure computed once and drawn by both renderers, the page and its manifest written."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from stepzoo import environment
from stepzoo.errors import UsageError
from stepzoo.results_folder import check_kind, replacing
from stepzoo.validate import DEFAULT_MARGIN


# Used for the summary table's cost column when no tuned config gives them.
DEFAULT_POS_TOL_M = 0.1


DEFAULT_TOL = 1e-3         # in the error norm, for a model without position


def resolve(results, tuned=None, plans=None):
    """(sweep folder, tuned file or None, plans folder or None) from the arguments."""
    results = Path(results)
    run_folder = (results / "sweep").is_dir() and not (results / "runs.parquet").exists()
    sweep = results / "sweep" if run_folder else results
    if run_folder:
        if tuned is None and (results / "tuned.toml").is_file():
            tuned = results / "tuned.toml"
        if plans is None and (results / "plans").is_dir():
            plans = results / "plans"
    return sweep, tuned, plans


def _facts(sweep, tuned, tuned_path, plan_list, plans_dir, out) -> list:
    from stepzoo.reports.provenance import public_path
    facts = [("sweep folder", public_path(sweep.folder, out)),
             ("sweep config sha256", sweep.manifest.get("config_sha256", "not recorded"))]
    timing = sweep.manifest.get("timing")
    if isinstance(timing, dict) and isinstance(timing.get("total_s"), (int, float)):
        facts.append(("sweep computing time", f"{timing['total_s']:.1f} s"))
    notes = [n for n in sweep.summary.get("nonsmooth_note", []) if isinstance(n, str) and n]
    if notes:                      # where f is not smooth, and the remedy (bench.model.nonsmooth)
        facts.append(("non-smooth f", notes[0]))
    rounds = sweep.manifest.get("timing_rounds")
    rule = sweep.manifest.get("timing_rule")
    facts.append(("timing", f"{rule} (timing_rounds = {rounds}); figures use the fastest, "
                  "the tables' hover and Figure 5 give the spread" if rule else
                  f"each run timed in {rounds} rounds after compilation; figures "
                  "use the fastest, the tables' hover and Figure 5 give the spread"
                  if rounds else "each run timed once (a sweep of an older stepzoo)"))
    if tuned:
        facts += [("tuned config", public_path(tuned_path, out)),
                  ("tuned choice", f"{tuned['method']} at h = {tuned['h']:g} s"),
                  ("why", tuned.get("why", "not stated"))]
        made_from = tuned.get("sweep_config_sha256")
        if made_from and made_from != sweep.manifest.get("config_sha256"):
            # Not fatal, but the reader must know the figures and the choice disagree.
            facts.append(("WARNING", "the tuned config was made from a different sweep "
                          f"(config sha256 {made_from})"))
    else:
        facts.append(("tuned config", "none given"))
    facts.append(("plans", f"{len(plan_list)} from {public_path(plans_dir, out)}" if plan_list
                  else "none given"))
    return facts


def _progress(on: bool):
    """say(line): one line to stderr, or nothing when progress is off."""
    def say(line):
        if on:
            sys.stderr.write(f"stepzoo report: {line}\n")
            sys.stderr.flush()
    return say


def parse_verdicts(specs) -> list[tuple[str, float]]:
    """(method, h [s]) of each --verdict METHOD:H, or UsageError naming the bad one."""
    from stepzoo.integrators import METHODS
    from stepzoo.validate import check
    pairs = []
    for spec in specs:
        name, sep, h = str(spec).rpartition(":")
        try:
            step = float(h)
        except ValueError:
            step = None
        if not sep or step is None:
            raise UsageError(f"--verdict {spec!r}: give METHOD:H, such as rk4:0.01")
        if name not in METHODS:
            raise UsageError(f"--verdict {spec!r}: unknown method {name!r}; known: "
                             f"{', '.join(METHODS)}")
        pairs.append((name, check("step", "--verdict", step)))
    return pairs


def build(results, out, tuned_path=None, plans_dir=None, progress=False, verdicts=(),
          bench_dir=None, ahead=None):
    """Load every input, draw the figures (static and interactive), write the report and its
    manifest.json; returns (index, summary, shown). `progress`: a line per stage to stderr;
    `verdicts`: (method, h [s]) pairs whose per-point verdict the report adds; `bench_dir`:
    a plan-bench folder, whose trade-off is Figure 8; `ahead`: Figures 1-6 of these inputs
    already drawn (reports.drawing.Drawn, as `sweep_figures` computes them), as `stepzoo
    run` draws them while it plans."""
    # Imported here, not with the module: pandas, matplotlib and plotly take seconds to
    # import, which `stepzoo report --help` (and `stepzoo run` before its sweep) need not wait.
    from stepzoo.reports import suite_report
    from stepzoo.reports.load import load_plans, load_sweep, load_tuned
    from stepzoo.reports.tradeoff import load_bench_summary
    started = environment.now()
    say = _progress(progress)
    sweep_dir, tuned_path, plans_dir = resolve(results, tuned_path, plans_dir)
    suite = suite_report.suite_manifest(sweep_dir)
    verdicts = parse_verdicts(verdicts)
    if suite:
        if verdicts:
            raise UsageError(f"{sweep_dir} holds a suite of problems; --verdict belongs "
                             "with one problem's report: give its folder, such as "
                             f"{sweep_dir / suite['problems'][0]}")
        if tuned_path is not None or plans_dir is not None or bench_dir is not None:
            raise UsageError(f"{sweep_dir} holds a suite of problems; --tuned, --plans and "
                             "--plan-bench belong with one problem's report: give its folder, "
                             f"such as {sweep_dir / suite['problems'][0]}")
        return suite_report.build(sweep_dir, suite, out, say)
    out = check_kind(out, "report")
    t0 = time.perf_counter()
    sweep = load_sweep(sweep_dir)
    missing = [name for name, _ in verdicts if name not in set(sweep.runs["method"])]
    if missing:
        raise UsageError(f"--verdict {missing[0]}: not a method of the sweep "
                         f"{sweep_dir}; it has {', '.join(sorted(set(sweep.runs['method'])))}")
    if verdicts:        # refused now, not after the figures are drawn
        from stepzoo.bench.sweep.config import load as load_config
        from stepzoo.bench.tune.verdict import check_workload
        check_workload(load_config(sweep_dir / "config.toml"), verdicts)
    tuned = load_tuned(tuned_path, sweep) if tuned_path is not None else None
    plan_list = load_plans(plans_dir) if plans_dir is not None else []
    bench = load_bench_summary(bench_dir) if bench_dir is not None else None
    say(f"read the sweep ({len(sweep.runs)} runs), "
        + (f"{len(plan_list)} plan(s)" if plan_list else "no plans") + (", the tuned config"
                                                                        if tuned else "")
        + f" in {time.perf_counter() - t0:.1f} s")
    # Drawn into a new folder that replaces `out` whole: a kill leaves the old report whole.
    with replacing(out, "report") as into:
        index, md, shown = _draw(sweep, tuned, tuned_path, plan_list, plans_dir, out, into,
                                 started, say, verdicts, bench, bench_dir, ahead)
    return out / index.name, out / md.name, shown


def _tolerance(sweep, tuned):
    """(view, tolerance, margin) of the report: the tuned config's, else the defaults."""
    from stepzoo.reports.load import tolerance
    view = sweep.view.with_tolerance(tuned)
    tol = tolerance(tuned) or (DEFAULT_POS_TOL_M if view.error == "err_pos" else DEFAULT_TOL)
    margin = float(tuned.get("margin", DEFAULT_MARGIN)) if tuned else DEFAULT_MARGIN
    return view, tol, margin


def sweep_figures(sweep, tuned, say, verdicts=()) -> list:
    """Callables computing Figures 1-6's data, in the report's order, from the loaded sweep
    and tuned config (or None) alone; Figures 1-2's runs are made first where the tuned
    choice binds elsewhere than the sweep ran them (`say` gets a line then)."""
    from stepzoo.reports import figure_data, recompute
    _, _, margin = _tolerance(sweep, tuned)
    t0 = time.perf_counter()
    at, why = recompute.figure_point(sweep, tuned, margin)
    if at is not sweep:
        point = ", ".join(f"{k} = {v:g}" for k, v in at.manifest["trajectory_point"].items())
        say(f"ran Figures 1-2's runs at {point}, where the tuned choice binds, in "
            f"{time.perf_counter() - t0:.1f} s")
    return [lambda: figure_data.yaw_rate(at, why, tuned),
            lambda: figure_data.xy_paths(at, why, tuned),
            lambda: figure_data.stability_regions(sweep, tuned),
            lambda: figure_data.error_vs_step(sweep, verdicts),
            lambda: figure_data.work_precision(sweep, tuned),
            lambda: figure_data.stable_step_vs_speed(sweep, verdicts)]


def _draw(sweep, tuned, tuned_path, plan_list, plans_dir, out, into, started, say,
          verdicts=(), bench=None, bench_dir=None, ahead=None):
    """The report of the folder `out`, written into the folder `into` (which becomes it)."""
    from stepzoo.reports import figure_data, interactive, recompute, tables
    from stepzoo.reports.drawing import draw_all
    from stepzoo.reports.html import write_report
    from stepzoo.reports.load import load_manifest
    from stepzoo.reports.provenance import environment_table, public_path
    view, tol, margin = _tolerance(sweep, tuned)
    # Each figure's data, in the report's order; both renderers draw it (reports.drawing).
    computes = [] if ahead else sweep_figures(sweep, tuned, say, verdicts)
    computes.append(lambda: figure_data.plans(plan_list))
    if bench is not None:
        from stepzoo.reports import tradeoff
        computes.append(lambda: tradeoff.tradeoff(tradeoff.tradeoff_points(bench, tuned)))
    shown, plots = draw_all(computes, into, say, ahead or ())
    unit = f" {view.error_unit}" if view.error_unit else ""
    t0 = time.perf_counter()
    verdict_tables = recompute.verdict_tables(sweep, verdicts, view, tol, margin)
    if verdicts:
        say(f"judged {len(verdicts)} verdict(s) in {time.perf_counter() - t0:.1f} s")
    summary = tables.Table(
        "Methods", f"Per method: declared and fitted order, stability intervals on the real "
        f"and imaginary axes, the smallest predicted and measured largest stable step over "
        f"the envelope (measured where the method blew up, or nothing failed) and their "
        f"worst ratio, how many runs had a nonlinear solve fail (never counted stable: a "
        f"solver failure, not the method's instability), and apart from the measured limits "
        f"the points where a failed solve ended the stable range, with the smallest step "
        f"[s] up to which their solves converge; then the "
        f"largest swept step stable everywhere, at most {1 - margin:g} of the measured limit, "
        f"with worst {view.error_label} <= {tol:g}{unit}"
        f"{'' if tuned else ' (defaults: no tuned config given)'}, and its "
        f"cost (wall time: the fastest of the timed rounds).",
        tables.method_summary(sweep, tol, margin, view.error), tables.METHOD_COLUMNS)
    decision = tables.Table(
        "Tuning decision", tables.tuning_caption(tuned) if tuned else "No tuned config was given.",
        tables.tuning_rows(tuned) if tuned else [], tables.TUNING_COLUMNS)
    facts = _facts(sweep, tuned, tuned_path, plan_list, plans_dir, out)
    own = environment.provenance("report", started, environment.now())
    manifests = {"sweep": sweep.manifest}
    if plans_dir is not None:
        manifests["plans"] = load_manifest(plans_dir)
    if bench_dir is not None:
        manifests["plan-bench"] = load_manifest(bench_dir)
    manifests["this report"] = own
    appendix = [environment_table(manifests, out)]
    index, md = write_report(into, "stepzoo report", facts, [decision, summary,
                                                              *verdict_tables], shown, plots,
                             interactive.plotly_js(), appendix)
    environment.write_manifest(into, "report", started, {
        "sweep": public_path(sweep.folder, out),
        "tuned": public_path(tuned_path, out) if tuned_path is not None else None,
        "plans": public_path(plans_dir, out) if plans_dir is not None else None,
        "plan_bench": public_path(bench_dir, out) if bench_dir is not None else None,
        "files": ["index.html", "summary.md", *[n for f in shown for n, _ in f.images]]})
    say(f"wrote {out / index.name} ({index.stat().st_size / 2 ** 20:.1f} MiB, figures "
        f"inline) and {md.name}")
    return index, md, shown
