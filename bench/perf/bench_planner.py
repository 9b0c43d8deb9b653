"""The planner on every built-in scenario through `stepzoo plan --all` (which warms each
scenario up before timing it): search, first-solution and connection time per scenario; and
the start-up of `stepzoo plan` with JAX's compilation cache empty (cold) and filled (warm):
the whole call, and the time and CPU time before its search starts, beside what importing
the libraries it needs costs on its own, with the split of a call's wall time into start-up,
warm-up, search, connections and what follows; and the same call sent to a warm `stepzoo serve`."""
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

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


# `stepzoo plan ARGS` in a child that reports on stderr, as the search starts (PathFinder.plan
# is entered after the map, the config, the compilation and the OCP's build), the clock and
# its CPU time so far. Patched from inside plan_scenario, once the command has configured
# JAX: importing cmd_plan first imports no JAX. As `stepzoo serve`, the server writes the
# line to the stderr of the plan it serves, the asking process's, with a third figure: its CPU
# time since the request arrived.
SEARCH_STARTS = """
import json, sys, time
from stepzoo.cli import serve as cmd_serve
from stepzoo.workflows import plan as cmd_plan
answer, arrived = cmd_serve._answer, [0.0]
def timed_answer(connection, *rest):
    arrived[0] = time.process_time()
    return answer(connection, *rest)
cmd_serve._answer = timed_answer
plan_scenario = cmd_plan.plan_scenario
def timed_plan_scenario(*args):
    from stepzoo.search.planner.pathfinder import PathFinder
    search = PathFinder.plan
    def plan(self, *a, **k):
        cpu = time.process_time()
        sys.stderr.write("SEARCH_STARTS " + json.dumps([time.time(), cpu, cpu - arrived[0]])
                         + "\\n")
        return search(self, *a, **k)
    if not hasattr(search, "timed"):     # a server plans many times: patched once
        plan.timed = True
        PathFinder.plan = plan
    return plan_scenario(*args)
cmd_plan.plan_scenario = timed_plan_scenario
from stepzoo.cli import main
sys.argv[0] = "stepzoo"
sys.exit(main())
"""
# What `stepzoo plan` imports before its search that is not ours: JAX, and JAX with SciPy's
# image and graph modules and CasADi.
IMPORTS = {"import_jax": "import jax",
           "import_libraries": "import jax, scipy.ndimage, scipy.sparse.csgraph, casadi"}
CLOCKS = "import json, sys, time; sys.stderr.write(json.dumps([time.time(), time.process_time()]))"


def _child(args, env, marker=None) -> tuple[float, float, float]:
    """(wall from launch to the child's report, its CPU time then, its whole wall) [s] of a
    Python child `args`, which writes [time.time(), time.process_time()] on stderr (after
    `marker` if given)."""
    t0 = time.time()
    proc = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env,
                          check=True)
    wall = time.time() - t0
    line = proc.stderr if marker is None else next(
        ln for ln in proc.stderr.splitlines() if ln.startswith(marker))[len(marker):]
    at, cpu = json.loads(line)[:2]
    return at - t0, cpu, wall


def test_plan_start_up(benchmark, tmp_path):
    """`stepzoo plan open_field` with a new compilation cache folder (cold), then 3 times with
    it filled (warm, the fastest kept): wall time of the call, that less its search and
    connections, its warm-up (compilation and the OCP's build), and the wall and CPU time
    from launch to the search's start; and the fastest of 3 bare imports of the libraries."""
    env = dict(os.environ, STEPZOO_CACHE_DIR=str(tmp_path / "cache"))
    figures = {}

    def plan(label, out):
        before, cpu, wall = _child(["-c", SEARCH_STARTS, "plan", "open_field", "--out",
                                    str(out)], env, "SEARCH_STARTS ")
        stats = json.loads((out / "plan.json").read_text())["stats"]
        # Where the wall time goes, in the order it passes: start-up (imports, config, map)
        # up to the warm-up, the warm-up (compilation and the OCP's build), the search, the
        # connections, and what follows them (writing the plan, exit).
        return {f"plan_{label}_wall_s": wall,
                f"plan_{label}_outside_search_s": wall - stats["search_s"] - stats["connect_s"],
                f"plan_{label}_warmup_s": stats["warmup_s"],
                f"plan_{label}_before_search_s": before,
                f"plan_{label}_before_search_cpu_s": cpu,
                f"plan_{label}_start_s": before - stats["warmup_s"],
                f"plan_{label}_search_s": stats["search_s"],
                f"plan_{label}_connect_s": stats["connect_s"],
                f"plan_{label}_after_search_s": (wall - before - stats["search_s"]
                                                 - stats["connect_s"])}

    figures.update(plan("cold", tmp_path / "cold"))
    warm = []
    benchmark.pedantic(lambda: warm.append(plan("warm", tmp_path / f"warm{len(warm)}")),
                       rounds=3)
    # Each figure's fastest of the warm calls: the least disturbed by other jobs.
    figures.update({k: min(w[k] for w in warm) for k in warm[0]})
    for name, code in IMPORTS.items():
        runs = [_child(["-c", f"{code}; {CLOCKS}"], env) for _ in range(3)]
        figures[f"{name}_s"] = min(r[0] for r in runs)
        figures[f"{name}_cpu_s"] = min(r[1] for r in runs)
    figures["plan_warm_vs_cold_warmup"] = (figures["plan_warm_warmup_s"]
                                           / figures["plan_cold_warmup_s"])
    figures["plan_warm_vs_cold_before_search"] = (figures["plan_warm_before_search_s"]
                                                  / figures["plan_cold_before_search_s"])
    figures.update(_served(env, tmp_path))
    figures["plan_served_vs_warm_before_search"] = (figures["plan_served_before_search_s"]
                                                    / figures["plan_warm_before_search_s"])
    figures["plan_served_vs_warm_before_search_cpu"] = (
        figures["plan_served_before_search_cpu_s"] / figures["plan_warm_before_search_cpu_s"])
    # What is ours of the warm start-up: all but the libraries' own import.
    figures["plan_warm_before_search_ours_s"] = (figures["plan_warm_before_search_s"]
                                                 - figures["import_libraries_s"])
    figures["plan_warm_before_search_ours_cpu_s"] = (figures["plan_warm_before_search_cpu_s"]
                                                     - figures["import_libraries_cpu_s"])
    benchmark.extra_info.update(kind="plan_start_up", figures=figures)


def _served(env, tmp_path) -> dict:
    """`stepzoo plan open_field --server` 3 times to a `stepzoo serve` that has warmed up,
    each figure's fastest: the whole call, from launch to the search's start (in the server),
    the CPU time of the asking process, and that plus the server's CPU time from the request
    to the search's start (what both processes spend before the search: the asker only
    waits once it has sent its request)."""
    sock = tmp_path / "plan.sock"
    server = subprocess.Popen([sys.executable, "-c", SEARCH_STARTS, "serve", "--socket",
                               str(sock)], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True)
    runs = []
    try:
        assert "planning" in server.stdout.readline()       # ready: warmed up
        for i in range(3):
            cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.time()
            proc = subprocess.run([str(STEPZOO), "plan", "open_field", "--out",
                                   str(tmp_path / f"served{i}"), "--server", str(sock)],
                                  capture_output=True, text=True, env=env, check=True)
            wall = time.time() - t0
            cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            line = next(ln for ln in proc.stderr.splitlines() if ln.startswith("SEARCH_STARTS "))
            at, _, server_cpu = json.loads(line.split(" ", 1)[1])
            asker_cpu = cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime
            runs.append({"plan_served_wall_s": wall, "plan_served_before_search_s": at - t0,
                         "plan_served_client_cpu_s": asker_cpu,
                         "plan_served_before_search_cpu_s": asker_cpu + server_cpu})
    finally:
        server.terminate()
        server.wait()
    return {k: min(r[k] for r in runs) for k in runs[0]}
