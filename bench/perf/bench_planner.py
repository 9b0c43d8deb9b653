"""The planner on every built-in scenario through `stepzoo plan --all` (which warms each
scenario up before timing it): search and connection time per scenario."""
import json
import subprocess
import sys
from pathlib import Path


def test_plan_all(benchmark, tmp_path):
    stepzoo = Path(sys.executable).with_name("stepzoo")
    out = tmp_path / "plans"
    benchmark.pedantic(lambda: subprocess.run([str(stepzoo), "plan", "--all", "--out", str(out)],
                                              check=True, capture_output=True), rounds=1)
    rows = json.loads((out / "summary.json").read_text())
    benchmark.extra_info.update(kind="planner", scenarios={
        r["scenario"]: {k: r[k] for k in ("status", "search_s", "connect_s")} for r in rows})
