"""`make bench`: run the pytest-benchmark modules of bench/perf in one process, then write
bench/results/latest.json ({"ratios", "figures", "machine"}), latest.md and the tables of
docs/benchmarks.md (tables.py), and name every figure more than 20% worse than in the
previous latest.json.

Usage: python -m bench.perf.run [--all] [-k EXPR]   (-k selects benchmarks, as in pytest)

Without --all the benchmarks of LONG are left out, to keep the run near a quarter of an hour
on a shared 2-core machine."""
import json
import os
import platform
import subprocess
import sys
import tempfile
from datetime import datetime, timezone
from pathlib import Path
from statistics import median

from stepzoo.bench.perf import tables
from stepzoo.bench.perf.workloads.implicit import IMPLICIT, IMPLICIT_BATCHES

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "bench" / "results"
WORSE = 0.20   # a figure this much worse than the previous run is named
# The state counts of bench_implicit_models.py's vehicle models, and those issue 35 sets a
# target on against Kvaerno5.
MODEL_STATES = (5, 9, 29)
KVAERNO_TARGET_STATES = (9, 29)
TARGETS = {# Issue 26: rk4 (generic model) at batch 1e5 against Numba prange+fastmath doing
           # the same work: the final state only, and every state stored.
           "rk4_b1e5_vs_numba_fastmath_final": (">=", 0.8),
           "rk4_b1e5_vs_numba_fastmath_stored": (">=", 1.0),
           "generic_vs_fast_trig_b1e5": (">=", 0.9),
           # ... the library as fast as the command without its XLA option.
           "api_vs_command_rk4_b1e4": (">=", 0.9),
           # ... the whole `make run` in 20 s with the compilation cache warm, 35 s cold.
           "make_run_warm_wall_s": ("<=", 20.0), "make_run_cold_wall_s": ("<=", 35.0),
           # ... one stability or verdict answer in 2 s with the cache warm.
           "stability_one_point_s": ("<=", 2.0), "stability_user_model_s": ("<=", 2.0),
           "verdict_one_point_s": ("<=", 2.0),
           # Issue 35 (raised from issue 26's 0.25): an implicit step at batch 1e4 at most
           # 1/0.35 rk4 steps (Radau IIA 5: 10), for those of the methods it names that
           # implicit.py has make bench measure ...
           **{f"{name}_b1e4_vs_rk4_per_step": (">=", 0.1 if name == "radau_iia5" else 0.35)
              for name in ("trapezoidal", "backward_euler", "bdf2", "bdf3", "bdf4", "bdf5",
                           "radau_iia5") if name in IMPLICIT},
           # ... and on the 9- and 29-state vehicle models, each at least twice diffrax's
           # Kvaerno5 per step on the same work.
           **{f"{name}_d{d}_vs_diffrax_kvaerno5": (">=", 2.0)
              for name in IMPLICIT for d in KVAERNO_TARGET_STATES},
           # Issue 14: implicit steps at batch 1e4, per right-hand-side evaluation.
           "trapezoidal_b1e4_vs_rk4_per_eval": (">=", 0.25),
           "backward_euler_b1e4_vs_rk4_per_eval": (">=", 0.25),
           "sweep_vs_driver": ("<=", 1.5),
           # Issue 33: a stiff sweep's wall time, estimated before it starts, within 30%.
           "sweep_estimate_error": ("<=", 0.3),
           # Issues 33 and 35: the 9-state stiff sweep (10 methods x 36 points) likewise, and
           # within 5 minutes.
           "stiff9_sweep_estimate_error": ("<=", 0.3), "stiff9_sweep_wall_s": ("<=", 300.0),
           "plan_first_solution_s_median": ("<=", 0.1), "plan_connect_s_median": ("<=", 0.02),
           # Issue 15: a repeated `stepzoo plan` starts its search well under a second.
           "plan_warm_before_search_s": ("<=", 1.0),
           # ... and one sent to a warm `stepzoo serve` well under it.
           "plan_served_before_search_s": ("<=", 0.5)}
# Benchmarks that only --all runs: the sweep on Dask workers (three cold sweeps and two
# clusters), which would take as long as all the others together.
LONG = ("bench/perf/bench_distributed.py",)
LABEL = {1: "1", 100: "100", 1_000: "1e3", 10_000: "1e4", 100_000: "1e5"}
REGIMES = ("stored", "final")     # as baselines.REGIMES, which imports JAX
REGIME_BATCHES = ("1e3", "1e4", "1e5")
REGIME_CONTENDERS = ("rk4_fast_trig", "jax_scan", "diffrax_rk4", "diffrax_tsit5", "numpy_loop",
                     "numba_serial", "numba_fastmath")


def run_benchmarks(json_path: Path, select: list[str]) -> int:
    """pytest on bench/perf with one host device per core, so that the driver can share a
    batch among them, and the command's XLA loop option (XLA reads its flags when JAX
    starts, hence the subprocess)."""
    from stepzoo.cli import with_xla_option
    env = dict(os.environ)
    env["XLA_FLAGS"] = with_xla_option(
        (env.get("XLA_FLAGS", "") +
         f" --xla_force_host_platform_device_count={os.cpu_count()}").strip())
    if "--all" in select:
        select = [a for a in select if a != "--all"]
    else:
        select = [*select, *(f"--ignore={ROOT / name}" for name in LONG)]
    cmd = [sys.executable, "-m", "pytest", str(ROOT / "bench" / "perf"), "-p", "no:cacheprovider",
           "-o", "python_files=bench_*.py", "-o", "addopts=", "-q",
           f"--benchmark-json={json_path}", "--benchmark-columns=min,median,rounds",
           *select]
    return subprocess.run(cmd, cwd=ROOT, env=env).returncode


def figures_of(benchmarks: list[dict]) -> dict:
    """Flat figures: throughputs [trajectory-steps/s] from the best and the median round,
    times [s]; None where a benchmark did not run."""
    fig = {}
    for b in benchmarks:
        info, st = b["extra_info"], b["stats"]
        kind = info.get("kind")
        if kind in ("driver", "baseline"):
            who = (f"driver_{info['method']}" + ("_fast_trig" if info["rhs"] == "fast_trig"
                                                 else "")) if kind == "driver" else info["baseline"]
            key = f"{who}_b{LABEL[info['batch']]}_steps_per_s"
            fig[key] = info["work"] / st["min"]
            fig[key + "_median"] = info["work"] / st["median"]
            if "evals_per_step" in info:
                fig[key.replace("_steps_per_s", "_evals_per_step")] = info["evals_per_step"]
        elif kind == "compile":
            fig[f"compile_{info['method']}_s"] = max(st["min"] - info["run_s"], 0.0)
        elif kind == "connect":
            fig[f"connect_{info['shooting']}_s_median"] = st["median"] / info["problems"]
            fig[f"connect_{info['shooting']}_solved"] = info["solved"] / info["problems"]
        elif kind == "sweep":
            t = info["timing"]
            for name, s in t["compile_s"].items():
                fig[f"sweep_compile_{name}_s"] = s
            fig["sweep_compile_s"] = sum(t["compile_s"].values())
            for part in ("reference_s", "integration_s", "stability_s", "metrics_s", "total_s",
                         "wall_s"):
                fig[f"sweep_{part}"] = t[part]
            fig["sweep_driver_replay_s"] = info["driver_s"]
        elif kind == "sweep_cache":
            for run in ("cold", "warm"):
                t = info[run]
                fig[f"sweep_{run}_command_s"] = t["command_s"]
                fig[f"sweep_{run}_wall_s"] = t["wall_s"]
                fig[f"sweep_{run}_compile_s"] = sum(t["compile_s"].values())
        elif kind == "planner":
            rows = info["scenarios"]
            for name, r in rows.items():
                fig[f"plan_{name}_search_s"] = r["search_s"]
                fig[f"plan_{name}_connect_s"] = r["connect_s"]
            fig["plan_search_s_median"] = median(r["search_s"] for r in rows.values())
            fig["plan_connect_s_median"] = median(r["connect_s"] for r in rows.values())
            fig["plan_exact"] = sum(r["status"] == "exact" for r in rows.values()) / len(rows)
            # search_s includes the anytime improvement; the paper's planner stopped at the
            # first path, which is what first_solution_s times.
            fig["plan_first_solution_s_median"] = median(
                r["first_solution_s"] for r in rows.values() if r["first_solution_s"] is not None)
        elif kind == "plan_start_up":
            fig.update(info["figures"])
        elif kind == "interleaved":
            for name, s in info["best_s"].items():
                fig[f"interleaved_{info['method']}_b{LABEL[info['batch']]}_{name}_s"] = s
        elif kind in ("distributed", "api_vs_command", "one_point", "regimes", "make_run",
                      "sweep_estimate"):
            fig.update(info["figures"])
    return fig


def ratios_of(fig: dict) -> dict:
    """Driver over baseline throughput (higher is better), both from their best rounds of
    the same run; sweep integration time over raw driver time (lower is better)."""
    def ratio(a, b):
        return fig[a] / fig[b] if a in fig and b in fig else None

    out = {}
    # Both regimes: stepzoo's rk4 (generic model) over each baseline doing the same work.
    for regime in REGIMES:
        for batch in REGIME_BATCHES:
            for who in REGIME_CONTENDERS:
                out[f"rk4_b{batch}_vs_{who}_{regime}"] = ratio(
                    f"rk4_{regime}_b{batch}_steps_per_s", f"{who}_{regime}_b{batch}_steps_per_s")
    # What keeping every state costs stepzoo's rk4 (1: nothing).
    out["rk4_b1e5_final_vs_stored"] = ratio("rk4_final_b1e5_steps_per_s",
                                            "rk4_stored_b1e5_steps_per_s")
    # stepzoo's implicit methods over diffrax's Kvaerno5, each at a constant step.
    for name in IMPLICIT:
        out[f"{name}_b1e4_vs_diffrax_kvaerno5"] = ratio(
            f"{name}_final_b1e4_steps_per_s", "diffrax_kvaerno5_final_b1e4_steps_per_s")
    # ... and on the vehicle models of MODEL_STATES states, over Kvaerno5 and SciPy's Radau.
    for d in MODEL_STATES:
        for name in IMPLICIT:
            mine = f"{name}_d{d}_final_b1e3_steps_per_s"
            out[f"{name}_d{d}_vs_diffrax_kvaerno5"] = ratio(
                mine, f"diffrax_kvaerno5_d{d}_final_b1e3_steps_per_s")
            out[f"{name}_d{d}_vs_scipy_radau"] = ratio(mine, f"scipy_radau_d{d}_steps_per_s")
    # Throughput of the generic model over fast_trig's (500 steps, every state kept): their
    # times the other way round.
    out["generic_vs_fast_trig_b1e5"] = ratio("interleaved_rk4_b1e5_fast_trig_s",
                                             "interleaved_rk4_b1e5_generic_s")
    # Implicit over rk4 throughput: in steps, and in right-hand-side evaluations (steps/s
    # times the evaluations per step each run counted, Jacobians as d evaluations).
    for name in IMPLICIT:
        for batch in (LABEL[b] for b in IMPLICIT_BATCHES):
            steps = ratio(f"driver_{name}_b{batch}_steps_per_s",
                          f"driver_rk4_b{batch}_steps_per_s")
            evals = ratio(f"driver_{name}_b{batch}_evals_per_step",
                          f"driver_rk4_b{batch}_evals_per_step")
            out[f"{name}_b{batch}_vs_rk4_per_step"] = steps
            out[f"{name}_b{batch}_vs_rk4_per_eval"] = (None if steps is None or evals is None
                                                       else steps * evals)
    out["sweep_vs_driver"] = ratio("sweep_integration_s", "sweep_driver_replay_s")
    # The Python API (no XLA option set) over the command, in throughput: 1 is as fast.
    out["api_vs_command_rk4_b1e4"] = ratio("api_rk4_b1e4_steps_per_s",
                                           "command_rk4_b1e4_steps_per_s")
    # Shares of the envelope sweep's wall time, and the persistent cache's effect on it.
    out["sweep_compile_share"] = ratio("sweep_compile_s", "sweep_wall_s")
    out["sweep_stability_share"] = ratio("sweep_stability_s", "sweep_wall_s")
    out["sweep_warm_vs_cold"] = ratio("sweep_warm_command_s", "sweep_cold_command_s")
    out["connect_single_vs_multiple"] = ratio("connect_single_s_median",
                                              "connect_multiple_s_median")
    return out


LOWER_RATIOS = ("sweep_vs_driver", "sweep_warm_vs_cold")    # times over times


def higher_is_better(name: str) -> bool:
    return (name.endswith(("steps_per_s", "steps_per_s_median", "runs_per_s", "solved", "exact",
                           "same_tuned"))
            or ("_vs_" in name and name not in LOWER_RATIOS
                and not name.startswith(("connect_", "plan_"))))


def regressions(old: dict, new: dict) -> list[str]:
    """Names (with old -> new) of figures and ratios more than WORSE worse than before."""
    worse = []
    for section in ("ratios", "figures"):
        for name, v in new[section].items():
            before = old.get(section, {}).get(name)
            if v is None or before in (None, 0):
                continue
            change = v / before - 1
            if (-change if higher_is_better(name) else change) > WORSE:
                worse.append(f"{name}: {before:.4g} -> {v:.4g} ({change:+.0%})")
    return worse


def machine() -> dict:
    """The CPU, its cores, the versions of what was measured, the commit and the date."""
    from importlib import metadata
    cpu = next((line.split(":", 1)[1].strip() for line in
                Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("model name")),
               platform.processor()) if Path("/proc/cpuinfo").exists() else platform.processor()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    versions = {}
    for name in ("jax", "jaxlib", "numba", "diffrax", "numpy"):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            **versions, "platform": platform.platform(), "commit": commit,
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds")}


def _table(kind: str, values: dict) -> list[str]:
    """Markdown rows of name, value, target and whether it is met."""
    rows = [f"| {kind} | value | target | met |", "|---|---|---|---|"]
    for name, v in values.items():
        op, goal = TARGETS.get(name, ("", None))
        met = "" if goal is None or v is None else tables.met(v, (op, goal))
        rows.append(f"| {name} | {_fmt(v)} | {op} {goal if goal is not None else ''} | {met} |")
    return rows


def markdown(result: dict, worse: list[str]) -> str:
    m = result["machine"]
    lines = [f"# stepzoo benchmarks ({m['date']}, commit {m['commit']})", "",
             f"{m['cpu']}, {m['cores']} cores, load average {m['load_before']} before and "
             f"{m['load_after']} after: the machine is shared, so compare ratios (both sides "
             "measured in this run), not raw figures.", "",
             *_table("ratio", result["ratios"]), "", *_table("figure", result["figures"]),
             "", "## More than 20% worse than the previous run", ""]
    lines += [f"- {w}" for w in worse] or ["none"]
    return "\n".join(lines) + "\n"


def _fmt(v):
    return "null" if v is None else f"{v:.4g}"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    load_start = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "raw.json"
        code = run_benchmarks(raw, argv)
        if not raw.exists():
            print("benchmarks did not run; nothing written", file=sys.stderr)
            return code or 1
        benchmarks = json.loads(raw.read_text())["benchmarks"]
    fig = figures_of(benchmarks)
    measured = {k: v for b in benchmarks for k, v in b["extra_info"].get("machine", {}).items()}
    result = {"ratios": ratios_of(fig), "figures": fig,
              "machine": dict(machine(), **measured, load_before=round(load_start[0], 2),
                              load_average_start=[round(x, 2) for x in load_start],
                              load_after=round(os.getloadavg()[0], 2),
                              selection=argv or ["default"])}
    latest = RESULTS / "latest.json"
    old = json.loads(latest.read_text()) if latest.exists() else {}
    worse = regressions(old, result)
    RESULTS.mkdir(parents=True, exist_ok=True)
    for path, text in ((latest, json.dumps(result, indent=1) + "\n"),
                       (RESULTS / "latest.md", markdown(result, worse))):
        tmp_path = path.with_suffix(path.suffix + ".tmp")
        tmp_path.write_text(text)
        tmp_path.replace(path)
    tables.write_docs(result, TARGETS)
    for name, v in result["ratios"].items():
        print(f"{name:40s} {_fmt(v)}")
    for name, target in TARGETS.items():
        v = result["ratios"].get(name, fig.get(name))
        print(f"target {name}: {_fmt(v)} {target[0]} {target[1]}: {tables.met(v, target)}")
    print("more than 20% worse than the previous run: " + ("; ".join(worse) or "none"))
    print(f"wrote {latest}, {RESULTS / 'latest.md'} and {tables.DOCS}")
    return code


if __name__ == "__main__":
    sys.exit(main())
