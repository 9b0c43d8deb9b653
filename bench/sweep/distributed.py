"""Chunks of a sweep as tasks computed side by side: on this process's threads, one per core
(`threaded`: JAX runs a compiled program, and XLA compiles one, without Python's lock), or on
a Dask cluster (connected through `stepzoo.distributed`): grouped by kind, submitted with
retries, and handed back as they finish."""
from __future__ import annotations

import ctypes
import os
import queue
import threading
from collections.abc import Callable, Iterable, Iterator

from stepzoo.distributed import RETRIES

_caches: dict = {}            # on a worker: config sha256 -> compute_chunk's cache


def by_kind(todo: list[str]) -> dict[str, list[str]]:
    """The chunk ids by their kind (the reference, or one method), in their order."""
    kinds: dict[str, list[str]] = {}
    for cid in todo:
        kinds.setdefault(cid.rpartition("-b")[0], []).append(cid)
    return kinds


def tasks(todo: list[str], slots: int) -> list[list[str]]:
    """The chunk ids grouped into tasks: each kind's chunks (the reference, or one method)
    in at most `slots` runs of consecutive blocks, so a worker compiles a method once for many
    blocks and a task carries seconds of work rather than one block's milliseconds."""
    out = []
    for ids in by_kind(todo).values():
        size = -(-len(ids) // min(len(ids), max(slots, 1)))
        out += [ids[i: i + size] for i in range(0, len(ids), size)]
    return out


def sweep_runner(client):
    """A `runner` for `run_sweep`: the missing chunks as tasks on the client's cluster,
    yielded as (chunk id, tables) in the order the tasks finish."""
    def run(cfg, todo):
        from dask.distributed import as_completed
        slots = sum(client.nthreads().values())
        submitted = as_completed(
            client.submit(compute_chunks, cfg, ids, retries=RETRIES, pure=False,
                          key=f"stepzoo-{cfg.sha256[:12]}-{ids[0]}-{len(ids)}")
            for ids in tasks(todo, slots))
        for future in submitted:
            yield from future.result()
            future.release()           # the tables are on disk: the cluster can drop them
    return run


def compute_chunks(cfg, ids: list[str]) -> list[tuple[str, dict]]:
    """On a worker: [(chunk id, tables)] of a task, with the process's cache for this config,
    so each worker compiles each method and computes each reference once. A sweep is
    analysis in float64, which the worker process, like the `stepzoo` command, turns on."""
    import jax

    from stepzoo.bench.sweep.engine import compute_chunk
    jax.config.update("jax_enable_x64", True)
    if cfg.sha256 not in _caches:
        _caches.clear()            # a long-lived worker keeps only the latest sweep's state
        _caches[cfg.sha256] = {}
    return [(cid, compute_chunk(cfg, cid, _caches[cfg.sha256])) for cid in ids]


def cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:                      # not on Linux
        return os.cpu_count() or 1


class _Stopped(SystemExit):
    """Raised in a worker thread when the caller stops (Ctrl-C, or another job's error); a
    SystemExit, which ends a thread without a traceback wherever it lands."""


def threaded(jobs: list[Callable[[], Iterable]], workers: int) -> Iterator:
    """Every item of every job, as the jobs yield them: `workers` threads take the jobs in
    their order, each the next one as it finishes its own (so jobs given longest first end
    close together). One worker, or one job, runs here in order. A job's error is raised
    here; when this generator stops early (an error, Ctrl-C, closed), each worker is
    stopped at its next Python statement, as Ctrl-C stops the main thread, and joined:
    no thread outlives it."""
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            yield from job()
        return
    todo: queue.SimpleQueue = queue.SimpleQueue()
    for job in jobs:
        todo.put(job)
    out: queue.SimpleQueue = queue.SimpleQueue()

    def work():
        try:
            while True:
                try:
                    job = todo.get_nowait()
                except queue.Empty:
                    return
                for item in job():
                    out.put((True, item))
        except _Stopped:
            pass
        except BaseException as err:            # noqa: BLE001  handed to the caller
            out.put((False, err))
        finally:
            out.put((False, None))

    threads = [threading.Thread(target=work, name=f"stepzoo-sweep-{i}", daemon=True)
               for i in range(min(workers, len(jobs)))]
    for t in threads:
        t.start()
    running = len(threads)
    try:
        while running:
            try:
                ok, item = out.get(timeout=0.5)
            except queue.Empty:
                continue
            if ok:
                yield item
            elif item is None:
                running -= 1
            else:
                raise item
    finally:
        for t in threads:
            if t.is_alive() and t.ident is not None:
                ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(t.ident),
                                                           ctypes.py_object(_Stopped))
        for t in threads:
            t.join()
