"""`make run` as a new user waits for it: `stepzoo run` into a new folder in a fresh process,
first with an empty compilation cache (cold: STEPZOO_CACHE_DIR a new folder), then again into
another new folder with the cache the first filled (warm). Each side's wall time, split as
the run reports it: its stages (the run's manifest.json, stage_s) and the sweep's own parts
(the sweep's manifest.json, timing), and its processor time (both of its processes): the
run does work side by side on two cores, so its wall time is near the processor time over
two only where nothing else keeps a core busy. Whether the warm run was warm: the programs
each run added to the compilation cache (none, where the cache served every one), and
whether the warm run's tune chose the cold run's method and step (its plans are then the
cold run's; where its choice differs, it compiles the planner's programs for it)."""
import json
import os
import resource
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path
from time import perf_counter

from stepzoo.bench.perf.bench_api import as_user

SWEEP_PARTS = ("reference_s", "integration_s", "stability_s", "metrics_s")


def _cpu_s() -> float:
    """Processor time [s], user and system, of this process's finished children."""
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    return used.ru_utime + used.ru_stime


def _programs(cache: Path) -> int:
    """The entries (files) of a JAX compilation cache folder (0 where it is not there); the
    folder of the driver's traced programs in it is not one."""
    return sum(entry.is_file() for entry in cache.iterdir()) if cache.is_dir() else 0


def tuned_choice(out: Path) -> tuple:
    """(method, h [s]) of the tuned config a `stepzoo run` wrote into the folder `out`."""
    tuned = tomllib.loads((out / "tuned.toml").read_text())
    return tuned["method"], tuned["h"]


def run_once(out: Path, cache: Path) -> dict:
    """{wall_s, cpu_s, stage_s: {stage: s}, sweep: {part: s, compile_s: s}, exact,
    new_programs} of one `stepzoo run`; exact: every plan reached its goal (exit status 0);
    new_programs: the entries it added to the compilation cache."""
    before = _programs(cache)
    env = dict(os.environ, STEPZOO_CACHE_DIR=str(cache),
               XLA_FLAGS=as_user(os.environ.get("XLA_FLAGS", "")))
    t0, cpu0 = perf_counter(), _cpu_s()
    done = subprocess.run([sys.executable, "-m", "stepzoo", "run", "--out", str(out)], env=env,
                          capture_output=True, text=True)
    wall, cpu = perf_counter() - t0, _cpu_s() - cpu0
    # Exit status 1: the run finished, but not every plan reached its goal exactly.
    if done.returncode not in (0, 1):
        raise RuntimeError(f"stepzoo run failed ({done.returncode}): {done.stderr[-2000:]}")
    stages = json.loads((out / "manifest.json").read_text())["stage_s"]
    timing = json.loads((out / "sweep" / "manifest.json").read_text())["timing"]
    sweep = {part: timing[part] for part in SWEEP_PARTS}
    sweep["compile_s"] = sum(timing["compile_s"].values())
    return {"wall_s": wall, "cpu_s": cpu, "stage_s": stages, "sweep": sweep,
            "exact": done.returncode == 0, "new_programs": _programs(cache) - before}


def figures() -> dict:
    """make_run_{cold,warm}_wall_s, _cpu_s, _{stage}_s and _sweep_{part}_s [s], _exact
    (1: every plan reached its goal) and _new_programs (cache entries added), and
    make_run_warm_same_tuned (1: the warm run tuned the cold run's method and step)."""
    fig = {}
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "cache"
        for side in ("cold", "warm"):
            got = run_once(Path(tmp) / side, cache)
            fig[f"make_run_{side}_wall_s"] = got["wall_s"]
            fig[f"make_run_{side}_cpu_s"] = got["cpu_s"]
            fig.update({f"make_run_{side}_{name}_s": s for name, s in got["stage_s"].items()})
            fig.update({f"make_run_{side}_sweep_{part}": s for part, s in got["sweep"].items()})
            fig[f"make_run_{side}_exact"] = float(got["exact"])
            fig[f"make_run_{side}_new_programs"] = float(got["new_programs"])
        fig["make_run_warm_same_tuned"] = float(tuned_choice(Path(tmp) / "cold")
                                                == tuned_choice(Path(tmp) / "warm"))
    return fig


def test_make_run(benchmark):
    fig = benchmark.pedantic(figures, rounds=1)
    benchmark.extra_info.update(kind="make_run", figures=fig)
