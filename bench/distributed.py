"""Chunks of a sweep, or a batch of plans, as tasks on a Dask cluster: connect to a scheduler
(or start a LocalCluster here), submit with retries, and hand results back as they finish.
Dask is imported only when a scheduler is asked for: the core runs without it."""
from __future__ import annotations

import contextlib
import logging

from stepzoo.errors import UsageError

CONNECT_TIMEOUT_S = 10.0      # [s] a scheduler silent this long is reported, not waited for
# Re-runs of a task that raised on a worker. A task whose worker died is re-run by the
# scheduler itself (up to distributed.scheduler.allowed-failures times, 3 by default).
RETRIES = 2
FIX = ("start one with `dask scheduler` and give its tcp://HOST:8786, or use local:N for N "
       "worker processes on this machine")

_caches: dict = {}            # on a worker: config sha256 -> compute_chunk's cache


@contextlib.contextmanager
def connect(address: str):
    """A Dask client of the scheduler at `address` ('tcp://host:8786'), or of a LocalCluster
    of N single-threaded worker processes on loopback for 'local:N'; closed on exit."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise UsageError("--scheduler needs Dask, which is not installed; "
                         "pip install 'stepzoo[distributed]'") from None
    if address.startswith("local:"):
        n = address.removeprefix("local:")
        if not n.isdigit() or int(n) < 1:
            raise UsageError(f"--scheduler {address}: local:N needs a worker count N >= 1, "
                             "such as local:2")
        # Processes of one thread: a chunk's Python parts hold the GIL, so threads of one
        # worker would take turns; Dask's nanny already pins OMP/MKL/OpenBLAS to one thread.
        with LocalCluster(n_workers=int(n), threads_per_worker=1, processes=True,
                          host="127.0.0.1", dashboard_address=None,
                          silence_logs=logging.ERROR) as cluster, \
                Client(cluster) as client:
            yield client
        return
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError, TypeError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise UsageError(f"no Dask scheduler answers at {address} ({first}); {FIX}") from None
    with client:
        yield client


def tasks(todo: list[str], slots: int) -> list[list[str]]:
    """The chunk ids grouped into tasks: each kind's chunks (the reference, or one method)
    in at most `slots` runs of consecutive blocks, so a worker compiles a method once for many
    blocks and a task carries seconds of work rather than one block's milliseconds."""
    kinds: dict[str, list[str]] = {}
    for cid in todo:
        kinds.setdefault(cid.rpartition("-b")[0], []).append(cid)
    out = []
    for ids in kinds.values():
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

    from stepzoo.bench.sweep import compute_chunk
    jax.config.update("jax_enable_x64", True)
    if cfg.sha256 not in _caches:
        _caches.clear()            # a long-lived worker keeps only the latest sweep's state
        _caches[cfg.sha256] = {}
    return [(cid, compute_chunk(cfg, cid, _caches[cfg.sha256])) for cid in ids]


def gather_in_order(client, fn, items, *args) -> list:
    """[fn(item, *args) for item in items], one task per item on the client's cluster."""
    return client.gather([client.submit(fn, item, *args, retries=RETRIES, pure=False)
                          for item in items])
