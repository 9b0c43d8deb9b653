"""The `stepzoo` command: one subcommand per module, imported only when it runs.

Each subcommand module has `add_arguments(parser)` and `main(args) -> int`. A user mistake
(UsageError, or a bad flag) prints one line and exits with status 2, never a traceback."""
import argparse
import importlib
import signal
import sys

from bench.errors import UsageError

COMMANDS = {
    "run": ("reports.pipeline", "the whole pipeline: sweep -> tune -> plan -> report"),
    "methods": ("bench.cmd_methods", "the zoo: family, order, stages, stability intervals"),
    "simulate": ("bench.cmd_simulate", "one trajectory with one method (or the reference)"),
    "stability": ("bench.cmd_stability", "eigenvalues and predicted largest stable step"),
    "sweep": ("bench.cmd_sweep", "stability/accuracy sweep into a results folder"),
    "tune": ("bench.cmd_tune", "choose (method, h) under a tolerance -> planner config"),
    "plan": ("search.cmd_plan", "plan a scenario (built-in, or map + start + goal)"),
    "report": ("reports.cmd_report", "build the HTML report from result folders"),
}


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        sys.exit(2)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = _Parser(prog="stepzoo", description="Integrator stability benchmarking for "
                     "vehicle models, and the tree planner that uses the tuned step.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser,
                                metavar="COMMAND")
    for name, (module, helptext) in COMMANDS.items():
        p = sub.add_parser(name, help=helptext, description=helptext)
        if name == only:      # the other commands' modules (and JAX) stay unimported
            importlib.import_module(module).add_arguments(p)
    return parser


def main(argv=None) -> int:
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)       # `stepzoo ... | head` ends quietly
    argv = sys.argv[1:] if argv is None else argv
    chosen = next((a for a in argv if not a.startswith("-")), None)
    if chosen not in COMMANDS:
        chosen = None
    args = build_parser(chosen).parse_args(argv)
    try:
        return importlib.import_module(COMMANDS[args.command][0]).main(args) or 0
    except UsageError as err:
        sys.stderr.write(f"stepzoo {args.command}: error: {err}\n")
        return 2


if __name__ == "__main__":
    sys.exit(main())
