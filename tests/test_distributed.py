"""Sweeps and plans on a Dask cluster give what the in-process run gives: a LocalCluster of two
worker processes on loopback, a worker killed while it holds a chunk, resume across the two
modes; a scheduler that does not answer, or Dask missing, is one line and exit status 2."""
import json
import os
import signal
import socket
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

pytestmark = [pytest.mark.slow, pytest.mark.e2e]    # first, in make test-e2e: tests/conftest.py

pytest.importorskip("dask.distributed")

from stepzoo import distributed as cluster  # noqa: E402
from stepzoo.bench.sweep import distributed  # noqa: E402
from stepzoo.bench.sweep import tables as schema
from stepzoo.cli import main as stepzoo  # noqa: E402
from stepzoo.bench.sweep.engine import chunk_ids, run_sweep  # noqa: E402
from stepzoo.bench.sweep.config import load  # noqa: E402

CONFIGS = Path(__file__).resolve().parents[1] / "bench" / "configs"
RESULTS = ("runs", "limits", "eigenvalues", "trajectories", "summary")
# Wall-clock measurements, not results: they differ between any two runs of one config.
TIMED = sorted(schema.MEASURED)


class Stop(Exception):
    """Raised by a chunk hook to cut a sweep off."""


def tables(out) -> dict:
    return {name: pd.read_parquet(Path(out) / f"{name}.parquet").drop(columns=TIMED,
                                                                       errors="ignore")
            for name in RESULTS}


def assert_same_tables(out, expected):
    got = tables(out)
    for name in RESULTS:
        assert len(expected[name]), name
        pd.testing.assert_frame_equal(got[name], expected[name], obj=name)


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    """The small config cut to two methods, four steps and two blocks of points (six chunks),
    written to a file so the command can read it too."""
    small = load(CONFIGS / "small.toml")
    path = tmp_path_factory.mktemp("config") / "cut.toml"
    path.write_text(CONFIGS.joinpath("small.toml").read_text()
                    .replace('"euler", "heun", "rk4", "ab2", "trapezoidal"', '"rk4", "trapezoidal"')
                    .replace("num = 10 }", "num = 4 }")
                    .replace("points = 9 ", "points = 5 "))
    cut = load(path)
    assert len(cut.hs) == 4 and cut.changed(steps={"h": small.hs}) == small.changed(
        methods=("rk4", "trapezoidal"), chunks={"points": 5})
    return cut


@pytest.fixture(scope="module")
def in_process(cfg, tmp_path_factory):
    out = tmp_path_factory.mktemp("in_process")
    run_sweep(cfg, out, progress=False)
    return tables(out)


@pytest.fixture(scope="module")
def client():
    with cluster.connect("local:2") as c:
        yield c


def test_chunks_are_grouped_by_kind_into_at_most_one_run_per_slot():
    todo = [f"{k}-b{i:03d}" for k in ("reference", "rk4") for i in range(5)]
    assert distributed.tasks(todo, 2) == [todo[0:3], todo[3:5], todo[5:8], todo[8:10]]
    assert distributed.tasks(todo, 8) == [[c] for c in todo]
    assert distributed.tasks(todo[1:2], 0) == [todo[1:2]]


def test_a_sweep_on_a_local_cluster_gives_the_in_process_tables(cfg, in_process, client,
                                                                  tmp_path):
    manifest = run_sweep(cfg, tmp_path, progress=False,
                         runner=distributed.sweep_runner(client))
    assert manifest["complete"] and manifest["chunks"] == chunk_ids(cfg)
    assert_same_tables(tmp_path, in_process)
    # The work was done by both worker processes, none of it here.
    ran = client.run(lambda: cfg.sha256 in distributed._caches)
    assert len(ran) == 2 and all(ran.values())
    assert cfg.sha256 not in distributed._caches


def test_a_worker_killed_while_it_holds_a_chunk_loses_nothing(cfg, in_process, client,
                                                              tmp_path):
    killed = {}

    def kill_a_busy_worker(_cid):
        busy = {w: keys for w, keys in client.processing().items() if keys}
        if killed or not busy:
            return
        worker, keys = next(iter(busy.items()))
        killed.update(pid=client.run(os.getpid, workers=[worker])[worker], held=keys)
        os.kill(killed["pid"], signal.SIGKILL)

    run_sweep(cfg, tmp_path, progress=False, on_chunk=kill_a_busy_worker,
              runner=distributed.sweep_runner(client))
    assert killed["held"], "no worker held a chunk when one was finished"
    assert_same_tables(tmp_path, in_process)
    client.wait_for_workers(2, timeout=120)          # the nanny brings the worker back
    assert killed["pid"] not in client.run(os.getpid).values()


@pytest.mark.parametrize("first, then", [("here", "cluster"), ("cluster", "here")])
def test_a_sweep_cut_off_in_one_mode_resumes_in_the_other(cfg, in_process, client, tmp_path,
                                                          first, then):
    def stop_after_two(cid):
        if len(list((tmp_path / "chunks").iterdir())) == 2:
            raise Stop

    address = client.scheduler.address
    runner = distributed.sweep_runner(client) if first == "cluster" else None
    with pytest.raises(Stop):
        run_sweep(cfg, tmp_path, progress=False, on_chunk=stop_after_two, runner=runner)
    kept = {p.name: p.stat().st_ino for p in (tmp_path / "chunks").iterdir()}
    assert len(kept) == 2
    flags = ["--scheduler", address] if then == "cluster" else []
    assert stepzoo(["sweep", str(cfg.source), "--out", str(tmp_path), "--resume",
                    "--no-progress", "--format", "json", *flags]) == 0
    assert_same_tables(tmp_path, in_process)
    # The chunks done before the cut were kept, not computed again.
    assert {n: (tmp_path / "chunks" / n).stat().st_ino for n in kept} == kept


def test_a_batch_of_scenarios_plans_on_the_cluster_as_it_does_here(client, tmp_path):
    occupied = np.zeros((40, 80), bool)         # [cells] of 0.5 m, a block in the middle
    occupied[10:30, 36:44] = True
    np.save(tmp_path / "grid.npy", occupied)
    scenario = tmp_path / "query.toml"
    scenario.write_text('map = "grid.npy"\ncell_size = 0.5\nvehicle = "ge2021"\nspeed = 4.0\n'
                        "start = [4.0, 10.0, 0.0]\ngoal = [36.0, 10.0, 0.0, 2.0]\n")
    batch = ["street", str(scenario)]
    for name, flags in (("here", []), ("cluster", ["--scheduler", client.scheduler.address])):
        assert stepzoo(["plan", *batch, "--out", str(tmp_path / name), "--format", "json",
                        *flags]) == 0
    for folder in ("street", "query"):
        here, there = (json.loads((tmp_path / m / folder / "plan.json").read_text())
                       for m in ("here", "cluster"))
        for record in (here, there):
            # Times differ between runs: the *_s keys and the anytime progress (t_s, length).
            record["stats"] = {k: v for k, v in record["stats"].items()
                               if not k.endswith("_s") and k != "progress"}
        assert here == there and here["status"] == "exact"
    assert (tmp_path / "cluster" / "summary.csv").is_file()


def _closed_port() -> int:
    """A loopback port nothing listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_scheduler_that_does_not_answer_is_one_line_exit_2_and_no_table(cfg, tmp_path,
                                                                          capsys, monkeypatch):
    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 2.0)
    address = f"tcp://127.0.0.1:{_closed_port()}"
    out = tmp_path / "out"
    assert stepzoo(["sweep", str(cfg.source), "--out", str(out), "--scheduler", address]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and address in err[0] and "dask scheduler" in err[0], err
    assert not list(out.glob("*.parquet")) and not list(out.rglob("*.tmp*"))


@pytest.mark.parametrize("command", [["sweep", "{config}"], ["plan", "--all"]])
def test_scheduler_without_dask_installed_is_one_line_exit_2(cfg, tmp_path, capsys,
                                                              monkeypatch, command):
    monkeypatch.setitem(sys.modules, "dask.distributed", None)      # as if not installed
    argv = [a.format(config=cfg.source) for a in command]
    assert stepzoo([*argv, "--out", str(tmp_path / "out"), "--scheduler", "local:2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "stepzoo[distributed]" in err[0], err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("address", ["local:0", "local:two"])
def test_a_bad_local_worker_count_is_one_line_exit_2(cfg, tmp_path, capsys, address):
    assert stepzoo(["sweep", str(cfg.source), "--out", str(tmp_path), "--scheduler",
                    address]) == 2
    assert "local:N" in capsys.readouterr().err
