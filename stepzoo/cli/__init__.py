"""The `stepzoo` command: one subcommand per module, imported only when it runs.

Each subcommand module has `add_arguments(parser)` and `main(args) -> int`. A user mistake
(UsageError, or a bad flag) or an operating-system error (a file it may not read, a full
disk) prints one line and exits with status 2, never a traceback; see EXIT_STATUSES."""
import argparse
import errno
import importlib
import os
import re
import _thread
import signal
import sys
import threading
from pathlib import Path

from stepzoo import __version__, validate
from stepzoo.errors import NoAnswer, UsageError

COMMANDS = {
    "run": ("stepzoo.cli.run", "the whole pipeline: sweep -> tune -> plan -> report"),
    "methods": ("stepzoo.cli.methods", "the zoo: family, order, stages, stability intervals"),
    "simulate": ("stepzoo.cli.simulate", "one trajectory with one method (or the reference)"),
    "stability": ("stepzoo.cli.stability", "eigenvalues and predicted largest stable step"),
    "sweep": ("stepzoo.cli.sweep", "stability/accuracy sweep into a results folder"),
    "verdict": ("stepzoo.cli.verdict", "where a fixed (method, h) is stable and accurate"),
    "tune": ("stepzoo.cli.tune", "choose (method, h) under a tolerance -> planner config"),
    "export": ("stepzoo.cli.export", "the tuned (method, h) for acados, diffrax or JSON"),
    "plan": ("stepzoo.cli.plan", "plan a scenario (built-in, or map + start + goal)"),
    "plan-bench": ("stepzoo.cli.plan_bench", "plan a file of queries N times: a table "
                   "and OMPL benchmark logs"),
    "report": ("stepzoo.cli.report", "build the HTML report from result folders"),
    "serve": ("stepzoo.cli.serve", "keep a planner warm for `stepzoo plan --server`: "
              "no start-up per plan"),
}
# Commands that run long enough to show progress: they take --no-progress and -q.
LONG = ("run", "sweep", "tune", "plan", "plan-bench", "report")
# Commands that integrate or load maps: they estimate their memory and work first
# (--max-memory/-steps), and every refusal of a budget names the flag that raises it.
INTEGRATE = ("run", "simulate", "sweep", "tune", "plan", "plan-bench", "report", "serve")
# A command that resumes where an interrupted call stopped, and how.
RESUME = {"sweep": "resume with --resume", "plan-bench": "resume with --resume",
          "run": "resume: run it again, the same command (finished sweep chunks and plans are "
          "kept)"}
INTERRUPTED = 130          # the shell's status for a command ended by Ctrl-C (128 + SIGINT)
EXIT_STATUSES = """exit status:
  0    success
  1    the command ran correctly but found no answer: a plan that is not exact
       (approximate or no_path), a tuning where no (method, h) qualifies, a stability
       point where the model is not finite
  2    bad input, or a file or folder that cannot be used (unreadable, read-only, disk
       full, busy with another stepzoo command); one line on stderr says which
  130  interrupted (Ctrl-C); a sweep resumes with --resume"""
# Hints for the operating-system errors a user can fix, by errno.
OS_HINTS: dict[int | None, str] = {
            errno.EACCES: "check its permissions", errno.EPERM: "check its permissions",
            errno.EROFS: "the file system is read-only; give another --out",
            errno.ENOSPC: "the disk is full; free space or give another --out",
            errno.EDQUOT: "the disk quota is used up; free space or give another --out",
            errno.EFBIG: "the file would pass the file-size limit (ulimit -f); raise it",
            errno.ENOENT: "check the path", errno.EISDIR: "give a file, not a folder",
            errno.ENOTDIR: "a part of the path is a file, not a folder"}


# XLA:CPU compiles a while loop into one native function only when the loop touches fewer
# bytes than this option (1 kB by default); above it, every operation of every step is a
# separate runtime call. The integration loops touch kilobytes to megabytes, and small
# batches ran slower without it (the measurements:
# docs/studies/measurements-behind-defaults-2026-11.md).
# The command sets it for itself; the library never touches XLA_FLAGS.
XLA_OPTION = "xla_cpu_small_while_loop_byte_threshold=100000000"


def with_xla_option(flags: str) -> str:
    """`flags` with XLA_OPTION merged into its --xla_backend_extra_options (unless set)."""
    if XLA_OPTION.split("=")[0] in flags:
        return flags
    extra = re.search(r"--xla_backend_extra_options=(\S+)", flags)
    if extra:
        return flags.replace(extra.group(0), f"{extra.group(0)},{XLA_OPTION}")
    return f"{flags} --xla_backend_extra_options={XLA_OPTION}".strip()


KEPT_FOLDER = "stepzoo-programs"   # in the compilation cache folder: the traced programs


def compilation_cache_dir() -> Path | None:
    """Where the command keeps JAX's compiled programs between runs: STEPZOO_CACHE_DIR, else
    the user's cache folder (XDG_CACHE_HOME, else ~/.cache) /stepzoo/jax; None when
    STEPZOO_CACHE_DIR is set empty (no cache)."""
    given = os.environ.get("STEPZOO_CACHE_DIR")
    if given is not None:
        return Path(given) if given else None
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "stepzoo" / "jax"


def configure_jax(platform: str | None) -> None:
    """What the command needs of JAX, set before its first computation: float64 for analysis,
    the platform (`--platform`, else JAX_PLATFORMS, else JAX's own choice), and JAX's
    persistent compilation cache, so a repeated command loads its programs instead of
    compiling them. JAX keys each entry on the program itself (a method, a step h, shapes),
    the XLA flags and its version: any change compiles anew."""
    import jax
    jax.config.update("jax_enable_x64", True)
    if platform:
        jax.config.update("jax_platforms", platform)
    cache = compilation_cache_dir()
    if cache is not None:
        jax.config.update("jax_compilation_cache_dir", str(cache))
        # The planner's programs each compile faster than JAX's default caching threshold,
        # yet together they are most of a plan's start-up.
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        # The driver's traced programs beside them: a repeated command neither compiles nor
        # traces its methods and models again (integrators.kept_programs).
        from stepzoo.integrators import kept_programs
        kept_programs.keep_in(cache / KEPT_FOLDER)


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        sys.exit(2)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = _Parser(prog="stepzoo", description="Integrator stability benchmarking for "
                     "vehicle models, and the tree planner that uses the tuned step.",
                     epilog=EXIT_STATUSES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"stepzoo {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser,
                                metavar="COMMAND")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--platform", metavar="NAME",
                        help="JAX platform to run on, e.g. cpu, cuda, rocm (default: "
                        "JAX_PLATFORMS, else JAX's own choice)")
    long = argparse.ArgumentParser(add_help=False)
    long.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    long.add_argument("-q", "--quiet", action="store_true",
                      help="print only results and errors (implies --no-progress)")
    budget = argparse.ArgumentParser(add_help=False)
    budget.add_argument("--max-memory", type=float, metavar="GIB", help="memory the "
                        "trajectories may take [GiB] (default: half of this machine's)")
    budget.add_argument("--max-steps", type=float, metavar="N", help="integration steps, "
                        "summed over trajectories, it may take on (default 1e11)")
    for name, (module, helptext) in COMMANDS.items():
        parents = [common] + [long] * (name in LONG) + [budget] * (name in INTEGRATE)
        p = sub.add_parser(name, help=helptext, description=helptext, epilog=EXIT_STATUSES,
                           formatter_class=argparse.RawDescriptionHelpFormatter,
                           parents=parents)  # type: ignore[arg-type]  # typeshed: parents
        # of the subparsers' class; argparse takes any ArgumentParser
        if name == only:      # the other commands' modules (and JAX) stay unimported
            importlib.import_module(module).add_arguments(p)
    return parser


_REDELIVERY: list[threading.Timer] = []     # the redelivery of a lost Ctrl-C not yet made


def _redeliver_ctrl_c(unraisable, default=sys.unraisablehook) -> None:
    """sys.unraisablehook for the command: a Ctrl-C whose KeyboardInterrupt was raised inside
    a garbage-collector callback (JAX has one) cannot propagate and was lost, so the command
    ran on to its end; the signal is delivered again, to land where the command can stop."""
    if not isinstance(unraisable.exc_value, KeyboardInterrupt):
        default(unraisable)
        return
    while True:
        # From another thread, a moment later: delivered now, its handler would run inside
        # this hook, where its KeyboardInterrupt would be lost again. On a loaded machine the
        # moment can pass before this hook returns (start() waits for the thread): the
        # redelivery then lands here, and is made again.
        try:
            timer = threading.Timer(0.01, _thread.interrupt_main, (signal.SIGINT,))
            timer.daemon = True
            _REDELIVERY.append(timer)
            timer.start()
            return
        except KeyboardInterrupt:
            continue


def _forget_escaped_interrupt() -> None:
    """CPython marks a KeyboardInterrupt that left an exec() of source text (a namedtuple's
    or a dataclass's methods being made, as the command imports) as unhandled even when the
    command then caught it (Ctrl-C, or `serve` stopped), and `python -m stepzoo` then ends by
    SIGINT (status -2) whatever the command returned; an exec that completes clears the mark."""
    exec("pass")


def _drop_redelivery() -> None:
    """The command has stopped for Ctrl-C: a redelivery still pending would land after it,
    in the interpreter's exit, which then ends by SIGINT (status -2) after the command said
    it was interrupted and returned 130."""
    while _REDELIVERY:
        _REDELIVERY.pop().cancel()


def main(argv=None) -> int:
    """The `stepzoo` command on `argv` (default: this process's arguments, and then, as
    the process's own entry point, a command stopped by Ctrl-C ends the process); returns
    its exit status."""
    process = argv is None
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)       # `stepzoo ... | head` ends quietly
    sys.unraisablehook = _redeliver_ctrl_c
    argv = sys.argv[1:] if argv is None else argv
    chosen = next((a for a in argv if not a.startswith("-")), None)
    if chosen not in COMMANDS:
        chosen = None
    # Before any subcommand module is imported: XLA reads its flags when JAX starts.
    os.environ["XLA_FLAGS"] = with_xla_option(os.environ.get("XLA_FLAGS", ""))
    code = dispatch(build_parser(chosen).parse_args(argv), argv)
    _forget_escaped_interrupt()
    if code == INTERRUPTED and process:
        _end_interrupted()
    return code


def _end_interrupted() -> None:
    """End the process at once with INTERRUPTED, its output flushed: a Ctrl-C that landed
    while XLA compiled leaves XLA's threads running, and the interpreter's exit, tearing
    down JAX beside them, then ended the command by SIGSEGV after it said it was
    interrupted. What the command wrote was finished or removed as the Ctrl-C unwound it."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):   # a closed pipe: nothing more reaches it anyway
            pass
    os._exit(INTERRUPTED)


def dispatch(args, argv=None) -> int:
    """Run the command parsed into `args`: here, or with `plan --server PATH` in the `stepzoo
    serve` process at PATH, which is sent `argv` (then this process never imports JAX)."""
    served = getattr(args, "server", None)
    if args.command in LONG:
        args.progress = not (args.no_progress or args.quiet)
    stdout, budget = sys.stdout, validate.BUDGET
    sys.stdout = _Stdout(stdout)
    try:
        if not served:
            validate.check_address_space()
            configure_jax(args.platform)
        if served:
            from stepzoo.search.plans.request import request
            code = request(served, argv, args.platform, args.server_timeout)
        else:
            if args.command in INTEGRATE:
                _set_budget(args.max_memory, args.max_steps)
            code = importlib.import_module(COMMANDS[args.command][0]).main(args) or 0
        sys.stdout.flush()             # a full stdout fails here, not in a traceback at exit
        return code
    except StdoutError as err:
        _silence_stdout(stdout)
        return _fail(args.command, f"cannot write the output to stdout: {err.strerror}")
    except NoAnswer as err:
        sys.stderr.write(f"stepzoo {args.command}: no answer: {err}\n")
        return 1
    except UsageError as err:
        return _fail(args.command, str(err))
    except OSError as err:
        return _fail(args.command, os_message(err))
    except MemoryError:     # past the process's own limit (ulimit -v), which no estimate saw
        return _fail(args.command, "ran out of memory; use a larger step, a shorter horizon "
                     "or fewer points (--max-memory GIB says what the estimates may take), or "
                     "give the process more memory")
    except (KeyboardInterrupt, RuntimeError) as err:
        # Python 3.11 turns a Ctrl-C that lands in a class's __set_name__ (as a module
        # defining a pydantic model is imported) into a RuntimeError caused by it.
        if isinstance(err, RuntimeError) and not isinstance(err.__cause__, KeyboardInterrupt):
            raise
        _drop_redelivery()
        hint = RESUME.get(args.command)
        sys.stderr.write(f"stepzoo {args.command}: interrupted{'; ' + hint if hint else ''}\n")
        return INTERRUPTED
    finally:
        sys.stdout, validate.BUDGET = stdout, budget     # main() may be called again


class StdoutError(OSError):
    """Writing the command's output to stdout failed (a full disk, a closed pipe)."""


class _Stdout:
    """The command's stdout, whose write errors say they are stdout's: an OSError from a
    file write, or from a library reading a file, may name no file either."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text):
        try:
            return self._stream.write(text)
        except OSError as err:
            raise StdoutError(err.errno, err.strerror) from None

    def flush(self):
        try:
            self._stream.flush()
        except OSError as err:
            raise StdoutError(err.errno, err.strerror) from None

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _set_budget(max_memory, max_steps):
    for flag, value in (("--max-memory", max_memory), ("--max-steps", max_steps)):
        if value is not None and not (value > 0 and value < float("inf")):
            raise UsageError(f"{flag} must be a number > 0, got {value!r}")
    validate.BUDGET = validate.Budget(max_memory and max_memory * validate.GIB, max_steps)


def os_message(err: OSError) -> str:
    """One line for an operating-system error: what failed, on which file, what to do."""
    text = f"{err.strerror or err}: {err.filename}" if err.filename else str(err.strerror or err)
    hint = OS_HINTS.get(err.errno)
    return f"{text}; {hint}" if hint else text


def _silence_stdout(stream):
    """Point a failed stdout at /dev/null, or Python flushes it again at exit and prints a
    traceback (the process's own stdout only: `stepzoo run` lends stderr to its stages)."""
    if stream is sys.__stdout__:
        os.dup2(os.open(os.devnull, os.O_WRONLY), stream.fileno())


def _fail(command: str, message: str) -> int:
    sys.stderr.write(f"stepzoo {command}: error: {message}\n")
    return 2
