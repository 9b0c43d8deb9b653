"""The default envelope sweep, split as its manifest reports it (JAX's compiling per method,
and running: references, accuracy runs, stability runs, metrics), and the raw driver time of
the same integrations: every accuracy call the sweep makes is recorded and replayed, compiled.
Then the same sweep as `stepzoo sweep` runs it, twice in fresh processes sharing a new
persistent compilation cache: cold (it fills the cache), then warm (it loads from it)."""
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from time import perf_counter

import jax

from stepzoo import integrators
from stepzoo.bench.sweep import engine as sweep
from stepzoo.bench.sweep import config as sweep_config

ENVELOPE = Path(sweep.__file__).parents[1] / "configs" / "envelope.toml"


def test_envelope_sweep(benchmark, tmp_path, monkeypatch):
    calls = []
    plain = integrators.integrate_batch

    def recording(*args, **kwargs):
        # Only the accuracy runs are charged to the sweep's integration_s: its first round
        # is called from _accuracy_runs, the other timed rounds from a comprehension in it.
        if "_accuracy_runs" in (sys._getframe(2).f_code.co_name,
                                sys._getframe(3).f_code.co_name):
            calls.append((args, kwargs))
        return plain(*args, **kwargs)

    monkeypatch.setattr(integrators, "integrate_batch", recording)
    cfg = sweep_config.load(ENVELOPE)
    manifest = benchmark.pedantic(
        lambda: sweep.run_sweep(cfg, tmp_path / "sweep", overwrite=True, progress=False),
        rounds=1)
    driver_s = 0.0
    for args, kwargs in calls:
        t0 = perf_counter()
        jax.block_until_ready(plain(*args, **kwargs).x)
        driver_s += perf_counter() - t0
    benchmark.extra_info.update(kind="sweep", timing=manifest["timing"], calls=len(calls),
                                driver_s=driver_s)


def _command_sweep(out: Path, cache: Path) -> dict:
    """The manifest's timing of one `stepzoo sweep` of the envelope in a fresh process, with
    its wall time [s] (imports included) as command_s."""
    env = dict(os.environ, STEPZOO_CACHE_DIR=str(cache))
    started = perf_counter()
    done = subprocess.run([sys.executable, "-m", "stepzoo", "sweep", str(ENVELOPE), "--out",
                           str(out), "--overwrite", "--no-progress", "--format", "json"],
                          capture_output=True, text=True, check=True, env=env)
    return dict(json.loads(done.stdout)["timing"], command_s=perf_counter() - started)


def test_envelope_sweep_compilation_cache(benchmark):
    with tempfile.TemporaryDirectory() as tmp:
        cold = benchmark.pedantic(lambda: _command_sweep(Path(tmp) / "cold", Path(tmp) / "jax"),
                                  rounds=1)
        warm = _command_sweep(Path(tmp) / "warm", Path(tmp) / "jax")
    benchmark.extra_info.update(kind="sweep_cache", cold=cold, warm=warm)


WHEEL = Path(sweep.__file__).parents[1] / "configs" / "wheel.toml"


def test_stiff_sweep_wall_time_estimate(benchmark, tmp_path):
    """The stiff wheel sweep (10 methods, 15 points): the wall time the sweep estimated
    before it started (bench/sweep/estimate.py) against the wall time it took, in one run."""
    cfg = sweep_config.load(WHEEL)
    manifest = benchmark.pedantic(
        lambda: sweep.run_sweep(cfg, tmp_path / "wheel", overwrite=True, progress=True),
        rounds=1)
    t = manifest["timing"]
    est = t["estimate"]["total_s"]
    benchmark.extra_info.update(kind="sweep_estimate", figures={
        "sweep_estimate_s": est, "sweep_estimate_wall_s": t["wall_s"],
        "sweep_estimate_calibration_s": t["estimate"]["calibration_s"],
        "sweep_estimate_error": abs(est / t["wall_s"] - 1.0)})


STIFF9 = Path(sweep.__file__).parents[1] / "configs" / "stiff9.toml"


def test_stiff9_sweep_wall_time_estimate(benchmark, tmp_path):
    """The 9-state stiff sweep (the CommonRoad single-track drift model, 10 methods x 36
    points, issues 33 and 35): the wall time it estimated before it started against the wall
    time it took and their ratio, with its CPU time (the machine is shared: CPU time over
    wall time says how much of it the sweep had) and the threads it computed its chunks on
    (one per core)."""
    cfg = sweep_config.load(STIFF9)
    cpu = os.times()
    manifest = benchmark.pedantic(
        lambda: sweep.run_sweep(cfg, tmp_path / "stiff9", overwrite=True, progress=True),
        rounds=1)
    after = os.times()
    t = manifest["timing"]
    est = t["estimate"]["total_s"]
    benchmark.extra_info.update(kind="sweep_estimate", figures={
        "stiff9_sweep_estimate_s": est, "stiff9_sweep_wall_s": t["wall_s"],
        "stiff9_sweep_cpu_s": (after.user + after.system) - (cpu.user + cpu.system),
        "stiff9_sweep_estimate_calibration_s": t["estimate"]["calibration_s"],
        "stiff9_sweep_estimate_over_wall": est / t["wall_s"],
        "stiff9_sweep_threads": t["estimate"]["workers"],
        "stiff9_sweep_estimate_error": abs(est / t["wall_s"] - 1.0)})
