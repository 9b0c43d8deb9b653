"""`stepzoo run`'s second process, for the work that can run beside the pipeline's own on a
second core: the implicit methods' sweep chunks while the pipeline computes the others,
then Figures 1-6 while the pipeline plans (they need only the sweep's tables and the tuned
config), then the rest of the report once the plans are written. It computes exactly what
`stepzoo sweep` and `stepzoo report` compute (sweep.compute_chunk, report.sweep_figures,
report.build); the pipeline writes the chunks, so the sweep folder has one writer. Once it
has drawn them it plans some of the built-in scenarios, as the pipeline plans the others
(plan.plan_all); the pipeline writes the plans. It starts
with the pipeline, so that its imports (plotting, JAX) overlap the sweep and the pipeline
itself never imports the plotting libraries."""
from __future__ import annotations

import multiprocessing
import signal
import threading
from pathlib import Path


def _jax_settings() -> dict:
    """This process's JAX settings that change what the figures' runs compute or load, and
    where it keeps the driver's programs (integrators.kept_programs)."""
    import jax
    from stepzoo.integrators import kept_programs
    return {**{name: getattr(jax.config, name) for name in (
        "jax_enable_x64", "jax_platforms", "jax_compilation_cache_dir",
        "jax_persistent_cache_min_compile_time_secs")}, KEPT: kept_programs.folder()}


KEPT = "kept_programs"


def _serve(conn, settings: dict) -> None:
    """The second process: JAX set as its parent, the report's modules imported, then the
    jobs ("chunks", (sweep config file, chunk ids)), answered with [(chunk id, tables)],
    ("figures", (sweep folder, tuned file)), unanswered, ("plan", (built-in scenario's name,
    planner config, seed)), answered with plan.timed_plan's (record, seconds, plan.png), and
    ("report", build's arguments), answered with the index's path; None answers a job that
    failed."""
    # Ctrl-C goes to the whole process group: the parent says it was interrupted and ends
    # this process (SIGTERM, silent); a report it was writing leaves a hidden folder, which
    # the next report into that folder removes (results_folder.replacing).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    import jax
    from stepzoo.integrators import kept_programs
    settings = dict(settings)
    kept_programs.keep_in(settings.pop(KEPT))
    for name, value in settings.items():
        jax.config.update(name, value)
    from stepzoo.workflows import report
    from stepzoo.reports import drawing, load
    drawn = None
    cache: dict = {}
    while True:
        try:
            kind, args = conn.recv()
        except EOFError:                # the parent has ended
            return
        answer: list | str | tuple | None
        try:
            if kind == "plan":
                from stepzoo.search.world.scenarios import load_scenario
                from stepzoo.workflows.plan import timed_plan
                answer = timed_plan(load_scenario(args[0]), *args[1:])
            elif kind == "chunks":
                from stepzoo.bench.sweep.config import load as load_config
                from stepzoo.bench.sweep.engine import compute_chunk
                cfg = load_config(args[0])
                answer = [(cid, compute_chunk(cfg, cid, cache)) for cid in args[1]]
            elif kind == "figures":
                sweep = load.load_sweep(args[0])
                tuned = load.load_tuned(args[1], sweep)
                drawn = drawing.draw_apart(report.sweep_figures(sweep, tuned,
                                                                lambda line: None))
                continue
            else:
                results, out, tuned_path, plans_dir, progress = args
                answer = str(report.build(results, out, tuned_path, plans_dir, progress,
                                          ahead=drawn)[0])
        except Exception:               # the parent, building the report itself, says why
            drawn, answer = None, None
            if kind == "figures":
                continue
        try:
            conn.send(answer)
        except OSError:                 # the parent was killed meanwhile: no one to answer
            return


class Ahead:
    """The second process of one pipeline: `sweep_runner(config)` is a `run_sweep` runner
    that shares the chunks with it; `figures(sweep, tuned)` hands it the finished sweep
    folder and tuned file to draw Figures 1-6 from, `start`, `ready` and `answer` have it
    plan a built-in scenario (plan.plan_all's `beside`), `report(...)` (report.build's arguments)
    has it build the report and returns the index's path, or None where it could not (the
    caller then builds it); `close()` ends it."""

    def __init__(self):
        # spawn, not fork: a forked child would inherit JAX's threads mid-flight.
        ctx = multiprocessing.get_context("spawn")
        self._conn, theirs = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(theirs, _jax_settings()), daemon=True,
                                 name="stepzoo-report")
        self._proc.start()
        theirs.close()
        self._done = False

    def sweep_runner(self, config):
        """run_sweep's runner for the sweep config file `config`: the chunks of implicit
        methods (the longest to compile and to run) computed in the second process while
        this one computes the others (and the references), each process with its own cache
        of references; the second process's chunks follow this one's, or are computed here
        where it failed."""
        def run(cfg, todo):
            from stepzoo.bench.sweep.distributed import by_kind
            from stepzoo.bench.sweep.engine import compute_chunk
            from stepzoo.integrators import method
            theirs = [c for kind, ids in by_kind(todo).items()
                      if kind != "reference" and method(kind).implicit for c in ids]
            sent = bool(theirs) and self._send(("chunks", (str(config), theirs)))
            cache = {}
            for cid in todo:
                if cid not in theirs:
                    yield cid, compute_chunk(cfg, cid, cache)
            got = self.answer() if sent else None
            for cid, tables in got or ((c, compute_chunk(cfg, c, cache)) for c in theirs):
                yield cid, tables
        return run

    def _send(self, job) -> bool:
        """Send `job`; False where the process has died (killed, out of memory). Its end
        of the pipe is then closed, and writing there raises SIGPIPE, which the `stepzoo`
        command leaves at its default, ending the process (for `stepzoo ... | head`): it is
        ignored while this process writes, so the write fails instead."""
        main = threading.current_thread() is threading.main_thread()
        before = signal.signal(signal.SIGPIPE, signal.SIG_IGN) if main else None
        try:
            self._conn.send(job)
        except OSError:
            return False
        finally:
            if main:
                signal.signal(signal.SIGPIPE, before)
        return True

    def answer(self):
        """The answer to the last job, waited for; None where the process failed."""
        try:
            return self._conn.recv()
        except (EOFError, OSError):     # the process died (killed, out of memory)
            return None

    def figures(self, sweep, tuned) -> None:
        self._send(("figures", (str(sweep), str(tuned))))

    def start(self, scenario, config, seed) -> bool:
        """Has the process plan `scenario`, a built-in one (sent by name: a small message,
        which the pipe takes while the process still draws); False where it cannot."""
        from stepzoo.search.world.scenarios import builtin_names
        return scenario.name in builtin_names() and self._send(
            ("plan", (scenario.name, config, seed)))

    def ready(self) -> bool:
        """Whether an answer has come (or the process has died: `answer` then says None)."""
        try:
            return self._conn.poll()
        except OSError:
            return True

    def report(self, results: Path, out: Path, tuned_path: Path, plans_dir: Path,
               progress: bool) -> Path | None:
        if not self._send(("report", (results, out, tuned_path, plans_dir, progress))):
            return None
        index = self.answer()
        self._done = True
        return None if index is None else Path(index)

    def close(self) -> None:
        """Ends the process: once it has answered, as it does then; at once otherwise (the
        pipeline stopped early, while it imported or drew)."""
        self._conn.close()
        if not self._done:
            self._proc.terminate()
        self._proc.join()
