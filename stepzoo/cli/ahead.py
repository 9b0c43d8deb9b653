"""Figures 1-6 of `stepzoo run`'s report drawn in a second process while the pipeline plans:
they need only the sweep's tables and the tuned config, and planning keeps one core busy.
The process starts with the pipeline, so that its imports (plotting, JAX) overlap the sweep;
it draws exactly what `stepzoo report` would (report.sweep_figures), and the report writes
those figures' files as drawn."""
from __future__ import annotations

import multiprocessing
import signal


def _jax_settings() -> dict:
    """This process's JAX settings that change what the figures' runs compute or load."""
    import jax
    return {name: getattr(jax.config, name) for name in (
        "jax_enable_x64", "jax_platforms", "jax_compilation_cache_dir",
        "jax_persistent_cache_min_compile_time_secs")}


def _serve(conn, settings: dict) -> None:
    """The drawing process: JAX set as its parent, the report's modules imported, then one
    job (sweep folder, tuned file) answered with Figures 1-6 ([Drawn]), or None where they
    could not be drawn."""
    # Ctrl-C goes to the whole process group: the parent says it was interrupted and ends
    # this process; a second traceback from here would only hide that line.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    import jax
    for name, value in settings.items():
        jax.config.update(name, value)
    from stepzoo.cli import report
    from stepzoo.reports import drawing, load
    try:
        sweep_dir, tuned_path = conn.recv()
    except EOFError:                  # the parent ended before its sweep and tune did
        return
    try:
        sweep, tuned = load.load_sweep(sweep_dir), load.load_tuned(tuned_path)
        answer = drawing.draw_apart(report.sweep_figures(sweep, tuned, lambda line: None))
    except Exception:                 # the report, drawing them itself, says what is wrong
        answer = None
    try:
        conn.send(answer)
    except OSError:                   # the parent was killed meanwhile: no one to answer
        pass


class Ahead:
    """The drawing process of one pipeline: `start(sweep, tuned)` hands it the finished
    sweep folder and tuned file, `drawn()` waits for Figures 1-6 (reports.drawing.Drawn),
    None where the process failed; `close()` ends it."""

    def __init__(self):
        # spawn, not fork: a forked child would inherit JAX's threads mid-flight.
        ctx = multiprocessing.get_context("spawn")
        self._conn, theirs = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(theirs, _jax_settings()), daemon=True,
                                 name="stepzoo-figures")
        self._proc.start()
        theirs.close()
        self._started = self._answered = False

    def start(self, sweep, tuned) -> None:
        self._conn.send((str(sweep), str(tuned)))
        self._started = True

    def drawn(self):
        if not self._started:
            return None
        try:
            drawn = self._conn.recv()
        except (EOFError, OSError):    # the process died (killed, out of memory)
            return None
        self._answered = True
        return drawn

    def close(self) -> None:
        """Ends the process: once it has answered, as it does then; at once otherwise (the
        pipeline stopped early, while it imported or drew)."""
        self._conn.close()
        if not self._answered:
            self._proc.terminate()
        self._proc.join()
