"""A sweep computes its chunks on one thread per core (bench/sweep/distributed.py `threaded`,
engine.jobs): two jobs run at once, a job's error reaches the caller and stops the other
threads, a stopped sweep leaves no thread running; the tables are those of one thread; and
the estimate is the length of the same schedule."""
import threading
import time

import numpy as np
import pandas as pd
import pytest

from stepzoo.bench.sweep import distributed, engine
from stepzoo.bench.sweep import tables as schema
from stepzoo.bench.sweep.config import load
from stepzoo.bench.sweep.estimate import estimate, schedule


def _own_threads():
    return [t for t in threading.enumerate() if t.name.startswith("stepzoo-sweep-")]


def test_two_workers_run_two_jobs_at_once():
    """Each job waits at a barrier the other must reach too: only side by side do both end
    (a barrier's timeout fails the test rather than hanging it)."""
    meet = threading.Barrier(2, timeout=20)

    def job(name):
        def run():
            meet.wait()
            yield name
        return run

    got = list(distributed.threaded([job("a"), job("b")], 2))
    assert sorted(got) == ["a", "b"] and not _own_threads()


def test_one_worker_runs_the_jobs_here_in_order():
    main = threading.get_ident()
    got = list(distributed.threaded([lambda: [(1, threading.get_ident())],
                                     lambda: [(2, threading.get_ident())]], 1))
    assert got == [(1, main), (2, main)]


def test_a_jobs_error_is_raised_here_and_stops_the_other_thread():
    """The other job runs Python forever: it is stopped at its next statement and joined."""
    started = threading.Event()

    def forever():
        started.set()
        while True:
            time.sleep(0.01)
        yield

    def fails():
        started.wait(20)
        raise ValueError("no such chunk")
        yield

    with pytest.raises(ValueError, match="no such chunk"):
        list(distributed.threaded([forever, fails], 2))
    assert not _own_threads()


def test_closing_the_items_early_stops_every_thread():
    """What Ctrl-C does to the sweep's loop over the chunks: the generator is closed."""
    def slow():
        for i in range(1000):
            time.sleep(0.01)
            yield i

    items = distributed.threaded([slow, slow], 2)
    assert next(items) in range(1000)
    items.close()
    assert not _own_threads()


def test_the_jobs_put_the_references_first_and_the_longest_method_next(tiny_sweep):
    from types import SimpleNamespace
    cfg = load(tiny_sweep[0])
    todo = engine.chunk_ids(cfg)
    est = SimpleNamespace(methods={"euler": {"chunk_s": 1.0}, "heun": {"chunk_s": 2.0}})
    ran = []
    real = engine.compute_chunk
    try:
        engine.compute_chunk = lambda cfg, cid, cache: ran.append(cid) or {}
        for job in engine.jobs(cfg, todo, {}, est):
            list(job())
    finally:
        engine.compute_chunk = real
    assert ran == ["reference-b000", "reference-b001", "heun-b000", "heun-b001",
                   "euler-b000", "euler-b001"]


def _tables(folder):
    out = {}
    for name in schema.PARQUET:
        df = pd.read_parquet(folder / f"{name}.parquet")
        out[name] = df.drop(columns=[c for c in df.columns if c in schema.MEASURED])
    return out


def test_a_sweep_on_two_threads_gives_the_tables_of_one(tiny_sweep, tmp_path, monkeypatch):
    """The tiny sweep's chunks on two threads: chunks of both threads' jobs ran, and every
    table (but its measured times) is the one thread's."""
    config, whole = tiny_sweep
    threads = set()
    real = engine.compute_chunk

    def recording(cfg, cid, cache):
        threads.add(threading.get_ident())
        return real(cfg, cid, cache)

    monkeypatch.setattr(engine, "compute_chunk", recording)
    engine.run_sweep(load(config), tmp_path / "two", progress=False, workers=2)
    assert len(threads) == 2 and threading.get_ident() not in threads
    one, two = _tables(whole), _tables(tmp_path / "two")
    for name in one:
        pd.testing.assert_frame_equal(one[name], two[name], check_exact=True, obj=name)


def test_the_schedule_is_taken_in_order_by_the_first_free_thread():
    assert schedule([5.0, 4.0, 3.0, 3.0], 2) == 8.0       # 5 + 3 | 4 + 3
    assert schedule([5.0, 4.0, 3.0, 3.0], 1) == 15.0
    assert schedule([5.0, 1.0], 4) == 5.0


def test_the_estimate_on_two_threads_is_its_calibration_and_the_schedule_of_its_jobs(
        tiny_sweep):
    """Its total is the calibration plus the two threads' schedule of the other blocks'
    references and each method's chunks, the longest first."""
    cfg = load(tiny_sweep[0])
    est = estimate(cfg, {}, 2, workers=2)
    m = est.methods
    per = sorted((2 * v["chunk_s"] for v in m.values()), reverse=True)
    assert est.workers == 2 and est.record()["workers"] == 2
    assert est.total_s == pytest.approx(est.calibration_s + schedule([est.shared_s, *per], 2),
                                        rel=1e-12)
    assert np.isfinite(est.shared_s) and est.shared_s >= 0
