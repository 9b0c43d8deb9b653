"""The `stepzoo` command: one subcommand per module, imported only when it runs.

Each subcommand module has `add_arguments(parser)` and `main(args) -> int`. A user mistake
(UsageError, or a bad flag) prints one line and exits with status 2, never a traceback."""
import argparse
import importlib
import os
import re
import signal
import sys

from stepzoo.errors import UsageError

COMMANDS = {
    "run": ("stepzoo.reports.pipeline", "the whole pipeline: sweep -> tune -> plan -> report"),
    "methods": ("stepzoo.bench.cmd_methods", "the zoo: family, order, stages, stability intervals"),
    "simulate": ("stepzoo.bench.cmd_simulate", "one trajectory with one method (or the reference)"),
    "stability": ("stepzoo.bench.cmd_stability", "eigenvalues and predicted largest stable step"),
    "sweep": ("stepzoo.bench.cmd_sweep", "stability/accuracy sweep into a results folder"),
    "tune": ("stepzoo.bench.cmd_tune", "choose (method, h) under a tolerance -> planner config"),
    "plan": ("stepzoo.search.cmd_plan", "plan a scenario (built-in, or map + start + goal)"),
    "report": ("stepzoo.reports.cmd_report", "build the HTML report from result folders"),
}


# XLA:CPU compiles a while loop into one native function only when the loop touches fewer
# bytes than this option (1 kB by default); above it, every operation of every step is a
# separate runtime call. The integration loops touch kilobytes to megabytes: rk4 at batch 1
# ran 2.5x and at batch 10 1.8x slower without it (jax 0.10.2), with no change at batch 1e5.
# The command sets it for itself; the library never touches XLA_FLAGS.
XLA_OPTION = "xla_cpu_small_while_loop_byte_threshold=100000000"


def _with_xla_option(flags: str) -> str:
    """`flags` with XLA_OPTION merged into its --xla_backend_extra_options (unless set)."""
    if XLA_OPTION.split("=")[0] in flags:
        return flags
    extra = re.search(r"--xla_backend_extra_options=(\S+)", flags)
    if extra:
        return flags.replace(extra.group(0), f"{extra.group(0)},{XLA_OPTION}")
    return f"{flags} --xla_backend_extra_options={XLA_OPTION}".strip()


def configure_jax(platform: str | None) -> None:
    """What the command needs of JAX, set before its first computation: float64 for analysis,
    and the platform (`--platform`, else JAX_PLATFORMS, else JAX's own choice)."""
    import jax
    jax.config.update("jax_enable_x64", True)
    if platform:
        jax.config.update("jax_platforms", platform)


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        sys.exit(2)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = _Parser(prog="stepzoo", description="Integrator stability benchmarking for "
                     "vehicle models, and the tree planner that uses the tuned step.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser,
                                metavar="COMMAND")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--platform", metavar="NAME",
                        help="JAX platform to run on, e.g. cpu, cuda, rocm (default: "
                        "JAX_PLATFORMS, else JAX's own choice)")
    for name, (module, helptext) in COMMANDS.items():
        p = sub.add_parser(name, help=helptext, description=helptext, parents=[common])
        if name == only:      # the other commands' modules (and JAX) stay unimported
            importlib.import_module(module).add_arguments(p)
    return parser


def main(argv=None) -> int:
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)       # `stepzoo ... | head` ends quietly
    argv = sys.argv[1:] if argv is None else argv
    chosen = next((a for a in argv if not a.startswith("-")), None)
    if chosen not in COMMANDS:
        chosen = None
    # Before any subcommand module is imported: XLA reads its flags when JAX starts.
    os.environ["XLA_FLAGS"] = _with_xla_option(os.environ.get("XLA_FLAGS", ""))
    args = build_parser(chosen).parse_args(argv)
    configure_jax(args.platform)
    try:
        return importlib.import_module(COMMANDS[args.command][0]).main(args) or 0
    except UsageError as err:
        sys.stderr.write(f"stepzoo {args.command}: error: {err}\n")
        return 2


if __name__ == "__main__":
    sys.exit(main())
