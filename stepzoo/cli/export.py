"""`stepzoo export TUNED --to acados|diffrax|json [--interval S] [--out DIR]`: the tuned (method,
h) where it is used: acados' integrator settings for a shooting interval, a runnable diffrax
snippet, or JSON with both and the step schedule (the largest safe step per envelope value)."""
import sys

from stepzoo.output import text_table, to_json


def add_arguments(p):
    from stepzoo.bench.tune.export import TARGETS
    p.add_argument("tuned", metavar="TUNED", help="a tuned config written by `stepzoo tune`")
    p.add_argument("--to", required=True, choices=TARGETS,
                   help="acados: integrator settings for --interval; diffrax: a runnable "
                   "snippet; json: both and the step schedule")
    p.add_argument("--interval", type=float, metavar="SECONDS",
                   help="shooting interval [s], split into equal steps no longer than the tuned "
                   "h (needed by acados; diffrax's default: the sweep's horizon)")
    p.add_argument("--sweep", metavar="DIR", help="the sweep folder the tuning read (default: "
                   "the one the tuned config records)")
    p.add_argument("--out", metavar="DIR", help="also write the export and schedule.csv (the "
                   "step schedule) into this folder")


def main(args) -> int:
    from stepzoo.bench.tune import export
    from stepzoo.errors import UsageError
    from stepzoo.validate import check
    interval = None if args.interval is None else check("horizon", "--interval", args.interval)
    if args.to == "acados" and interval is None:
        raise UsageError("--to acados needs --interval S, the shooting interval [s]")
    tuned = export.load_tuned(args.tuned)
    sweep = export.sweep_of(tuned, args.sweep)
    if args.to == "acados":
        assert interval is not None       # checked above
        settings = export.acados(tuned, interval, export.sweep_newton(sweep))
        _say_if_other(settings, tuned)
        text, name = export.acados_text(settings), "acados.py"
        table = export.schedule(tuned, sweep, settings["method"])
    elif args.to == "diffrax":
        text, name = export.diffrax_snippet(tuned, sweep, interval), "diffrax_snippet.py"
        settings = export.diffrax_settings(tuned, interval)
        _say_if_other(settings, tuned)
        table = export.schedule(tuned, sweep, settings["method"])
    else:
        table = export.schedule(tuned, sweep)
        text = to_json(export.as_json(tuned, args.tuned, sweep, table, interval)) + "\n"
        name = "export.json"
    sys.stdout.write(text)
    if args.to == "acados":
        sys.stdout.write("step schedule (largest safe step per envelope value):\n"
                         + text_table(table.to_dict("records"), list(table.columns)) + "\n")
    if args.out:
        _write(args.out, name, text, table)
    return 0


def _say_if_other(settings: dict, tuned: dict) -> None:
    """One line on stderr where the tool gets another method than the tuned one: stdout
    (often redirected into a file) says it only in a comment."""
    if settings["method"] != tuned["method"]:
        sys.stderr.write(f"stepzoo export: {settings['why']}\n")


def _write(out, name: str, text: str, table) -> None:
    from stepzoo.output import atomic_write
    from stepzoo.results_folder import claim
    with claim(out, "export") as folder:
        atomic_write(folder / name, text)
        atomic_write(folder / "schedule.csv", table.to_csv(index=False))
    sys.stderr.write(f"wrote {folder / name} and {folder / 'schedule.csv'}\n")
