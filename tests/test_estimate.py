"""The wall-time estimate a sweep prints before it starts (bench/sweep/estimate.py): its count of
the calls and steps a method's chunk makes is the sweep's own (counted in the sweep's
runner), and calibrating into the sweep's cache changes no result. Its accuracy in seconds is
a benchmark's (bench/perf/bench_sweep.py), not a test's."""

import pandas as pd
import pytest

from stepzoo.bench.sweep.runs import method_runs
from stepzoo.bench.sweep import tables as schema
from stepzoo.bench.sweep.estimate import estimate
from stepzoo.bench.sweep.engine import compute_chunk, run_sweep
from stepzoo.bench.sweep.config import load


# The "modes" rule's runs last the stability horizon: 5 s, long enough for growth to show at
# the tiny bicycle's limits (its 0.5 s accuracy horizon fits 5-50 steps).
MODES = {"blowup": lambda text: text,
         "modes": lambda text: text.replace('rule = "blowup"\nsteps = 200', "horizon = 5.0")}


@pytest.fixture(scope="module", params=sorted(MODES))
def counted(request, tiny_sweep):
    """(the estimate's record of each method, the calls and steps each method's chunk of
    block 0 made) on the tiny bicycle under each stability rule, with every call of the
    sweep's runner counted."""
    config, _ = tiny_sweep
    path = config.parent / f"tiny-{request.param}.toml"
    path.write_text(MODES[request.param](config.read_text()))
    cfg = load(path)
    assert cfg.stability.rule == request.param
    est = estimate(cfg, {}, 2)
    seen = {}
    plain = method_runs.Runner.__call__

    def counting(self, meth, x0, u, p, h, n):
        calls, steps = seen.setdefault(meth.name, [0, 0])
        seen[meth.name] = [calls + 1, steps + n]
        return plain(self, meth, x0, u, p, h, n)

    method_runs.Runner.__call__ = counting
    try:
        cache: dict = {}
        compute_chunk(cfg, "reference-b000", cache)
        for name in cfg.methods:
            compute_chunk(cfg, f"{name}-b000", cache)
    finally:
        method_runs.Runner.__call__ = plain
    return est.methods, seen


@pytest.mark.parametrize("name", ["euler", "heun"])
def test_the_estimate_counts_the_calls_and_steps_a_chunk_makes(counted, name):
    """Its dry run of the limit search answers from the predicted limits (stable up to 1%
    above them), which the tiny bicycle's measured ones match to about that: the same
    probes, but for the last narrowing rounds."""
    est, seen = counted
    calls, steps = seen[name]
    assert est[name]["calls"] == pytest.approx(calls, rel=0.15)
    assert est[name]["steps"] == pytest.approx(steps, rel=0.15)


def test_calibrating_into_the_sweeps_cache_changes_no_result(tiny_sweep, tmp_path):
    """The sweep that estimates itself first (progress on) writes the tables of the one that
    does not, to the bit, but for the wall-clock columns."""
    config, whole = tiny_sweep
    manifest = run_sweep(load(config), tmp_path / "again", progress=True)
    assert manifest["timing"]["estimate"]["total_s"] > 0
    for table in ("runs", "limits"):
        a, b = (pd.read_parquet(f / f"{table}.parquet") for f in (whole, tmp_path / "again"))
        keep = [c for c in a.columns if c not in schema.MEASURED]
        pd.testing.assert_frame_equal(a[keep], b[keep])


def test_no_call_is_timed_while_another_thread_compiles(tiny_sweep, monkeypatch):
    """On two threads the calibration compiles every method's programs before it times a
    call: a call timed beside another thread's tracing waited for it (on the 9-state sweep a
    one-step call of ab2 took 0.27 s and of the trapezoidal rule 0.74 s, and the estimate
    came out 2.5 times the sweep's wall time)."""
    from stepzoo.bench.sweep import estimate as calibration
    cfg = load(tiny_sweep[0])
    compiled: list[str] = []
    ready_when_timed: list[int] = []
    compile_, timed = calibration._compile, calibration._timed

    def compiling(block, meth, name):
        yield from compile_(block, meth, name)
        compiled.append(name)

    def timing(*args, **kwargs):
        ready_when_timed.append(len(compiled))
        return timed(*args, **kwargs)

    monkeypatch.setattr(calibration, "_compile", compiling)
    monkeypatch.setattr(calibration, "_timed", timing)
    estimate(cfg, {}, 1, workers=2)
    assert len(cfg.methods) == 2 and ready_when_timed
    assert min(ready_when_timed) == len(cfg.methods)
