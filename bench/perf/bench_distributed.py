"""The sweep on 1 and 2 local Dask workers against the in-process run, each from a cold start
as `stepzoo sweep` runs it, and Dask's own cost per task (no-op round trips on loopback).
`figures()` returns the numbers; the test hands them to run.py as kind "distributed"."""
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "envelope.toml"
MODES = {"in_process": [], "local1": ["--scheduler", "local:1"],
         "local2": ["--scheduler", "local:2"]}
NOOPS = 200          # no-op tasks of the pipelined overhead
ROUND_TRIPS = 20     # no-op tasks sent one after the other for the latency


def sweep(config: Path, flags: list[str]) -> dict:
    """{wall_s: the whole command [s], sweep_s: run_sweep alone [s], runs: rows} of one
    `stepzoo sweep` in a fresh process (imports, cluster start and compilation included)."""
    import pandas as pd
    with tempfile.TemporaryDirectory() as tmp:
        started = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "stepzoo", "sweep", str(config),
                               "--out", tmp, "--no-progress", "--format", "json", *flags],
                              capture_output=True, text=True, check=True)
        wall = time.perf_counter() - started
        runs = len(pd.read_parquet(Path(tmp) / "runs.parquet"))
    return {"wall_s": wall, "sweep_s": json.loads(done.stdout)["timing"]["wall_s"],
            "runs": runs}


def task_overhead(workers: int = 2) -> dict:
    """Dask's cost per task [s] on a LocalCluster: the median round trip of one no-op task at
    a time, the wall time per task of NOOPS submitted at once, and the cluster's start."""
    from stepzoo.distributed import connect
    started = time.perf_counter()
    with connect(f"local:{workers}") as client:
        startup = time.perf_counter() - started
        client.submit(abs, -1, pure=False).result()
        trips = []
        for i in range(ROUND_TRIPS):
            t0 = time.perf_counter()
            client.submit(abs, -i, pure=False).result()
            trips.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        client.gather(client.map(abs, range(-NOOPS, 0), pure=False))
        pipelined = (time.perf_counter() - t0) / NOOPS
    return {"task_round_trip_s": statistics.median(trips), "task_overhead_s": pipelined,
            f"local{workers}_startup_s": startup}


def figures(config: Path = CONFIG) -> dict:
    """Flat figures named distributed_*: per mode the command's wall time, run_sweep's, and
    runs per second of run_sweep; speed-ups over the in-process run; Dask's cost per task."""
    fig = {}
    for mode, flags in MODES.items():
        r = sweep(config, flags)
        fig[f"distributed_{mode}_wall_s"] = r["wall_s"]
        fig[f"distributed_{mode}_sweep_s"] = r["sweep_s"]
        fig[f"distributed_{mode}_runs_per_s"] = r["runs"] / r["sweep_s"]
    for mode in ("local1", "local2"):
        fig[f"distributed_{mode}_vs_in_process"] = (fig["distributed_in_process_sweep_s"]
                                                    / fig[f"distributed_{mode}_sweep_s"])
    fig.update({f"distributed_{k}": v for k, v in task_overhead().items()})
    return fig


def test_distributed_sweep(benchmark):
    pytest.importorskip("dask.distributed")
    fig = benchmark.pedantic(figures, rounds=1)
    benchmark.extra_info.update(kind="distributed", figures=fig, config=CONFIG.name)
