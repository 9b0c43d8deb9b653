"""The library through its Python API against the `stepzoo` command on the same work: rk4 on
the benchmark problem (workload.py) at batch BATCH, STEPS steps, each side in a fresh process
as a user runs it: one host device (run.py's device count taken out), and only the command
with its loop option (cli.XLA_OPTION), which the library never sets. `python -m
stepzoo.bench.perf.bench_api` is one side's worker: it prints its best and median time [s]
as JSON."""
import json
import os
import re
import subprocess
import sys

from stepzoo.cli import XLA_OPTION, with_xla_option

BATCH = 10_000
STEPS = 200
ROUNDS = 5          # timed calls per process, after one that compiles
PROCESSES = 2       # fresh processes per side, alternating API and command


def as_user(flags: str) -> str:
    """`flags` without the command's loop option (out of --xla_backend_extra_options) and
    without a forced host device count."""
    name = XLA_OPTION.split("=")[0]

    def strip(found):
        kept = [o for o in found.group(1).split(",") if not o.startswith(name + "=")]
        return f"--xla_backend_extra_options={','.join(kept)}" if kept else ""
    flags = re.sub(r"--xla_force_host_platform_device_count=\S+", "", flags)
    return " ".join(re.sub(r"--xla_backend_extra_options=(\S+)", strip, flags).split())


def side(command: bool) -> dict:
    """One worker process's {best_s, median_s}: as the command runs (its option set) or as
    the API runs (without it)."""
    flags = as_user(os.environ.get("XLA_FLAGS", ""))
    env = dict(os.environ, XLA_FLAGS=with_xla_option(flags) if command else flags)
    done = subprocess.run([sys.executable, "-m", "stepzoo.bench.perf.bench_api"], env=env,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout)


def figures() -> dict:
    """Throughputs [trajectory-steps/s] of both sides from their best rounds, and medians."""
    runs = {"api": [], "command": []}
    for _ in range(PROCESSES):
        for name in runs:
            runs[name].append(side(name == "command"))
    fig = {}
    for name, rs in runs.items():
        key = f"{name}_rk4_b1e4_steps_per_s"
        fig[key] = BATCH * STEPS / min(r["best_s"] for r in rs)
        fig[key + "_median"] = BATCH * STEPS / min(r["median_s"] for r in rs)
    return fig


def test_api_vs_command(benchmark):
    fig = benchmark.pedantic(figures, rounds=1)
    benchmark.extra_info.update(kind="api_vs_command", figures=fig, batch=BATCH,
                                n_steps=STEPS)


def _worker() -> None:
    from statistics import median
    from time import perf_counter

    import jax

    from stepzoo.bench.perf.workloads.bicycle import H_S, MODEL, problem
    from stepzoo.integrators import integrate_batch
    jax.config.update("jax_enable_x64", True)
    x0, u, p = problem(BATCH)
    times = []
    for _ in range(ROUNDS + 1):
        t0 = perf_counter()
        jax.block_until_ready(integrate_batch("rk4", MODEL.rhs, x0, u, p, H_S, STEPS))
        times.append(perf_counter() - t0)
    print(json.dumps({"best_s": min(times[1:]), "median_s": median(times[1:])}))


if __name__ == "__main__":
    _worker()
