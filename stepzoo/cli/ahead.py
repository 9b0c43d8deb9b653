"""`stepzoo run`'s report made in a second process: Figures 1-6 drawn while the pipeline plans
(they need only the sweep's tables and the tuned config, and planning keeps one core busy),
then the rest of the report once the plans are written. The process starts with the
pipeline, so that its imports (plotting, JAX) overlap the sweep and the pipeline itself never
imports them; it builds exactly what `stepzoo report` builds (report.sweep_figures,
report.build)."""
from __future__ import annotations

import multiprocessing
import signal
import sys
from pathlib import Path


def _jax_settings() -> dict:
    """This process's JAX settings that change what the figures' runs compute or load."""
    import jax
    return {name: getattr(jax.config, name) for name in (
        "jax_enable_x64", "jax_platforms", "jax_compilation_cache_dir",
        "jax_persistent_cache_min_compile_time_secs")}


def _serve(conn, settings: dict) -> None:
    """The report's process: JAX set as its parent, the report's modules imported, then the
    jobs ("figures", (sweep folder, tuned file)), unanswered, and ("report", build's
    arguments), answered with the index's path or None where the report failed."""
    # Ctrl-C goes to the whole process group: the parent says it was interrupted and ends
    # this process, which then removes its unfinished report folder as an error would.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    import jax
    for name, value in settings.items():
        jax.config.update(name, value)
    from stepzoo.cli import report
    from stepzoo.reports import drawing, load
    drawn = None
    while True:
        try:
            kind, args = conn.recv()
        except EOFError:                # the parent has ended
            return
        try:
            if kind == "figures":
                sweep, tuned = load.load_sweep(args[0]), load.load_tuned(args[1])
                drawn = drawing.draw_apart(report.sweep_figures(sweep, tuned,
                                                                lambda line: None))
                continue
            answer = str(report.build(*args, ahead=drawn)[0])
        except Exception:               # the parent, building the report itself, says why
            drawn, answer = None, None
            if kind == "figures":
                continue
        try:
            conn.send(answer)
        except OSError:                 # the parent was killed meanwhile: no one to answer
            return


class Ahead:
    """The report's process of one pipeline: `figures(sweep, tuned)` hands it the finished
    sweep folder and tuned file to draw Figures 1-6 from, `report(...)` (report.build's
    arguments) has it build the report and returns the index's path, or None where it could
    not (the caller then builds it); `close()` ends it."""

    def __init__(self):
        # spawn, not fork: a forked child would inherit JAX's threads mid-flight.
        ctx = multiprocessing.get_context("spawn")
        self._conn, theirs = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(theirs, _jax_settings()), daemon=True,
                                 name="stepzoo-report")
        self._proc.start()
        theirs.close()
        self._done = False

    def figures(self, sweep, tuned) -> None:
        self._conn.send(("figures", (str(sweep), str(tuned))))

    def report(self, *args):
        try:
            self._conn.send(("report", args))
            index = self._conn.recv()
        except (EOFError, OSError):     # the process died (killed, out of memory)
            return None
        self._done = True
        return None if index is None else Path(index)

    def close(self) -> None:
        """Ends the process: once it has answered, as it does then; at once otherwise (the
        pipeline stopped early, while it imported or drew)."""
        self._conn.close()
        if not self._done:
            self._proc.terminate()
        self._proc.join()
