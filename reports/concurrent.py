"""The report's static figures drawn side by side: Matplotlib's layout and PNG rendering are
pure Python and single-threaded, so each figure goes to a forked worker process (one per
core) while the caller builds the interactive plots."""
from __future__ import annotations

import multiprocessing
import os
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from typing import Callable, Iterator

# The figures of the report being drawn: forked workers inherit them and are sent indices,
# since a figure's thunk (a closure over loaded tables) does not pickle.
_JOBS: list[Callable] = []


def _timed(i: int):
    t0 = time.perf_counter()
    return _JOBS[i](), time.perf_counter() - t0


def workers() -> int:
    """Worker processes to draw with: one per core this process may use, none (draw here)
    where there is one core or the platform cannot fork."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if (cores or 1) < 2 or "fork" not in multiprocessing.get_all_start_methods():
        return 0
    return cores


class Drawing:
    """Starts every job at once; `results()` yields (figure, seconds it took) in the jobs'
    order. The jobs run in forked workers: they must only draw with Matplotlib and NumPy
    and write files (a forked child must not call JAX, whose threads it lacks)."""

    def __init__(self, jobs: list[Callable]):
        global _JOBS
        self.jobs, self.pool = jobs, None
        n = min(workers(), len(jobs))
        if n < 2:
            return
        _JOBS = list(jobs)
        # JAX warns at any fork of a process that has used it; the workers never call it.
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
            self.pool = ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork"))
            self.futures = [self.pool.submit(_timed, i) for i in range(len(jobs))]

    def results(self) -> Iterator[tuple]:
        global _JOBS
        if self.pool is None:
            for job in self.jobs:
                t0 = time.perf_counter()
                yield job(), time.perf_counter() - t0
            return
        try:
            for f in self.futures:
                yield f.result()
        finally:
            self.pool.shutdown(cancel_futures=True)
            _JOBS = []
