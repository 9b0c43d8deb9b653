"""The planner on every built-in scenario through `stepzoo plan --all` (which warms each
scenario up before timing it): search, first-solution and connection time per scenario; and
the start-up of `stepzoo plan` with JAX's compilation cache empty (cold) and filled (warm)."""
import json
import os
import subprocess
import sys
from pathlib import Path
from time import perf_counter

STEPZOO = Path(sys.executable).with_name("stepzoo")


def test_plan_all(benchmark, tmp_path):
    out = tmp_path / "plans"
    benchmark.pedantic(lambda: subprocess.run([str(STEPZOO), "plan", "--all", "--out", str(out)],
                                              check=True, capture_output=True), rounds=1)
    rows = json.loads((out / "summary.json").read_text())
    first = {r["scenario"]: json.loads((out / r["scenario"] / "plan.json").read_text())
             ["stats"]["first_solution_s"] for r in rows}
    benchmark.extra_info.update(kind="planner", scenarios={
        r["scenario"]: {**{k: r[k] for k in ("status", "search_s", "connect_s")},
                        "first_solution_s": first[r["scenario"]]} for r in rows})


def test_plan_start_up(benchmark, tmp_path):
    """Wall time of `stepzoo plan open_field`, that less its search and connections (start-up,
    warm-up and writing), and its warm-up
    (compilation and the OCP's build), with a new cache folder, then again with it filled."""
    env = dict(os.environ, STEPZOO_CACHE_DIR=str(tmp_path / "cache"))
    figures = {}

    def plan(label):
        out = tmp_path / label
        t0 = perf_counter()
        subprocess.run([str(STEPZOO), "plan", "open_field", "--out", str(out)], check=True,
                       capture_output=True, env=env)
        wall = perf_counter() - t0
        stats = json.loads((out / "plan.json").read_text())["stats"]
        figures[f"plan_{label}_wall_s"] = wall
        figures[f"plan_{label}_outside_search_s"] = wall - stats["search_s"] - stats["connect_s"]
        figures[f"plan_{label}_warmup_s"] = stats["warmup_s"]
    plan("cold")
    benchmark.pedantic(lambda: plan("warm"), rounds=1)
    figures["plan_warm_vs_cold_warmup"] = figures["plan_warm_warmup_s"] / figures["plan_cold_warmup_s"]
    benchmark.extra_info.update(kind="plan_start_up", figures=figures)
