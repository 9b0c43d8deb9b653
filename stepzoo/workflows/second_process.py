"""`stepzoo run`'s second process, for the work that can run beside the pipeline's own on a
second core: the sweep's chunks, shared with the pipeline item by item (`Ahead.shared`: the
pipeline takes items from the front of the list, this process from the back, each as it is
free, so neither waits while the other has work left); Figures 1-6 once the sweep is tuned
(they need only the sweep's tables and the tuned config); the built-in scenarios' plans
still left by then, shared the same way; then the rest of the report once the plans are
written. It computes exactly what `stepzoo sweep`, `stepzoo plan` and `stepzoo report`
compute (sweep.compute_chunk, plan.timed_plan, report.sweep_figures, report.build); the
pipeline writes the chunks and the plans, so each folder has one writer. It starts with the
pipeline, so that its start-up overlaps the pipeline's; it imports the plotting libraries
when it first draws, and the pipeline itself never imports them."""
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


def _claim(ends, serial: int, back: bool) -> int | None:
    """The next item of the shared job `serial` (`ends`: a shared array [serial, front,
    back], the items front..back-1 not yet taken): from the back (the second process) or
    the front (the pipeline); None when none is left, or the job is no longer `serial`."""
    with ends.get_lock():
        job, front, end = ends[:]
        if job != serial or front >= end:
            return None
        if back:
            ends[2] = end - 1
            return end - 1
        ends[1] = front + 1
        return front


def _serve(conn, ends, settings: dict) -> None:
    """The second process: JAX set as its parent, then the jobs ("chunks", (serial, sweep config
    file, chunk ids)) and ("plans", (serial, built-in scenarios' names, planner config,
    seed)), shared through `ends` (`_claim`), each item it takes answered with (serial,
    index, its tables or plan.timed_plan's (record, seconds, plan.png)), None for one that
    failed (it then takes no more); ("figures", (sweep folder, tuned file)), unanswered; and
    ("report", build's arguments), answered with the index's path, None where it failed."""
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
    drawn = None
    cache: dict = {}
    while True:
        try:
            kind, args = conn.recv()
        except EOFError:                # the parent has ended
            return
        if kind in ("chunks", "plans"):
            if not _take(conn, ends, kind, args, cache):
                return
            continue
        answer: str | None
        from stepzoo.workflows import report
        from stepzoo.reports import drawing, load
        try:
            if kind == "figures":
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


def _take(conn, ends, kind: str, job: tuple, cache: dict) -> bool:
    """Take the items of a shared job from the back, one at a time, answering each; False
    where the parent has gone."""
    serial, *args = job
    if kind == "chunks":
        from stepzoo.bench.sweep.config import load as load_config
        from stepzoo.bench.sweep.engine import compute_chunk
        ids = args[1]
        try:
            cfg = load_config(args[0])
        except Exception:               # the parent computes every chunk
            return True

        def item(i):
            return compute_chunk(cfg, ids[i], cache)
    else:
        from stepzoo.search.world.scenarios import load_scenario
        from stepzoo.workflows.plan import timed_plan
        names, config, seed = args

        def item(i):
            return timed_plan(load_scenario(names[i]), config, seed)
    while (i := _claim(ends, serial, back=True)) is not None:
        try:
            answer = item(i)
        except Exception:               # the parent computes it, and what is left
            answer = None
        try:
            conn.send((serial, i, answer))
        except OSError:                 # the parent was killed meanwhile: no one to answer
            return False
        if answer is None:
            break
    return True


class Ahead:
    """The second process of one pipeline: `sweep_runner(config)` is a `run_sweep` runner
    that shares the chunks with it; `plans(...)` shares the built-in scenarios' plans with it
    (plan.plan_all's `beside`); `figures(sweep, tuned)` hands it the finished sweep folder
    and tuned file to draw Figures 1-6 from; `report(...)`
    (report.build's arguments) has it build the report and returns the index's path, or None
    where it could not (the caller then builds it); `close()` ends it."""

    def __init__(self):
        # spawn, not fork: a forked child would inherit JAX's threads mid-flight.
        ctx = multiprocessing.get_context("spawn")
        self._conn, theirs = ctx.Pipe()
        self._ends = ctx.Array("q", 3)     # [serial, front, back] of the shared job
        self._serial = 0
        self._proc = ctx.Process(target=_serve, args=(theirs, self._ends, _jax_settings()),
                                 daemon=True, name="stepzoo-report")
        self._proc.start()
        theirs.close()
        self._done = False

    def shared(self, kind: str, args: tuple, n: int, here):
        """(i, answer) of each item i < n of the job (kind, args), as they are done: this
        process takes items from the front (`here(i)` computes one), the second process from
        the back (`_serve`), each as it is free; an item it does not answer (it failed, or
        died) is computed here. No thread: a Ctrl-C meets this process in its own work or
        in its wait for the other's answer."""
        self._serial += 1
        serial = self._serial
        with self._ends.get_lock():
            self._ends[:] = [serial, 0, n]
        theirs: dict = {}                   # the second process's answers by item
        alive = self._send((kind, (serial, *args)))
        while (i := _claim(self._ends, serial, back=False)) is not None:
            yield i, here(i)
            while alive and self.ready():
                alive = self._receive(serial, theirs)
        # What is left is the second process's: [back, n), answered or still coming.
        for i in range(self._ends[2], n):
            while alive and i not in theirs:
                alive = self._receive(serial, theirs)
            got = theirs.get(i)
            yield i, here(i) if got is None else got

    def _receive(self, serial: int, into: dict) -> bool:
        """One answer of the shared job `serial` into `into` (one of an earlier job, which an
        error abandoned, is dropped); False where the process has died."""
        try:
            job, i, answer = self._conn.recv()
        except (EOFError, OSError):     # the process died (killed, out of memory)
            return False
        if job == serial:
            into[i] = answer
        return True

    def sweep_runner(self, config):
        """run_sweep's runner for the sweep config file `config`: the chunks shared with the
        second process (`shared`), the implicit methods' (the longest to compile and to run)
        last, where it starts, each process with its own cache of references."""
        def run(cfg, todo):
            from stepzoo.bench.sweep.distributed import by_kind
            from stepzoo.bench.sweep.engine import compute_chunk
            from stepzoo.integrators import method
            last = [c for kind, ids in by_kind(todo).items()
                    if kind != "reference" and method(kind).implicit for c in ids]
            ids = [c for c in todo if c not in last] + last
            cache: dict = {}
            for i, tables in self.shared("chunks", (str(config), ids), len(ids),
                                         lambda i: compute_chunk(cfg, ids[i], cache)):
                yield ids[i], tables
        return run

    def plans(self, scenarios, config, seed, here):
        """(i, plan.timed_plan's answer) of each of `scenarios` planned with `config` and
        `seed`, as they are done (`shared`; `here(i)` plans scenario i in this process);
        all here where one is not built in (the second process plans by name)."""
        from stepzoo.search.world.scenarios import builtin_names
        if any(s.name not in builtin_names() for s in scenarios):
            return ((i, here(i)) for i in range(len(scenarios)))
        return self.shared("plans", ([s.name for s in scenarios], config, seed),
                           len(scenarios), here)

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

    def _answer(self):
        """The answer to the report (the answers of a shared job left unread, where an error
        abandoned it, passed over); None where the process failed."""
        try:
            while isinstance(got := self._conn.recv(), tuple):
                pass
            return got
        except (EOFError, OSError):     # the process died (killed, out of memory)
            return None

    def figures(self, sweep, tuned) -> None:
        """Has the process draw Figures 1-6 of the finished sweep and tuned file (then take
        what is left of the plans' job that follows)."""
        self._send(("figures", (str(sweep), str(tuned))))

    def ready(self) -> bool:
        """Whether an answer has come (or the process has died: reading says so)."""
        try:
            return self._conn.poll()
        except OSError:
            return True

    def report(self, results: Path, out: Path, tuned_path: Path, plans_dir: Path,
               progress: bool) -> Path | None:
        if not self._send(("report", (results, out, tuned_path, plans_dir, progress))):
            return None
        index = self._answer()
        self._done = True
        return None if index is None else Path(index)

    def close(self) -> None:
        """Ends the process: once it has answered, as it does then; at once otherwise (the
        pipeline stopped early, while it imported or drew)."""
        self._conn.close()
        if not self._done:
            self._proc.terminate()
        self._proc.join()
