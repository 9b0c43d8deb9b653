"""Chunks of a sweep as tasks on a Dask cluster (connected through `stepzoo.distributed`):
grouped by kind, submitted with retries, and handed back as they finish."""
from __future__ import annotations

from stepzoo.distributed import RETRIES

_caches: dict = {}            # on a worker: config sha256 -> compute_chunk's cache


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

    from stepzoo.bench.sweep.engine import compute_chunk
    jax.config.update("jax_enable_x64", True)
    if cfg.sha256 not in _caches:
        _caches.clear()            # a long-lived worker keeps only the latest sweep's state
        _caches[cfg.sha256] = {}
    return [(cid, compute_chunk(cfg, cid, _caches[cfg.sha256])) for cid in ids]
