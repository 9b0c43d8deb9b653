"""One stability or verdict answer as a user waits for it: the whole `stepzoo stability` and
`stepzoo verdict` command for one operating point, in a fresh process with JAX's compilation
cache warm (a first call fills it), as a user's second call. The models: the dynamic bicycle
by name, the user model of tests/user_model (chain.toml), and a verdict for one (method, h)
at one point of it."""
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from stepzoo.bench.perf.bench_api import as_user

USER_MODEL = Path(__file__).resolve().parents[2] / "tests" / "user_model"
ROUNDS = 3          # timed calls of each command, after one that fills the cache


def one_point_config(folder: Path) -> Path:
    """chain.toml with its envelope cut to one point and its model's folder made absolute."""
    text = (USER_MODEL / "chain.toml").read_text()
    text = re.sub(r'(?m)^path = "\."', f'path = "{USER_MODEL.as_posix()}"', text)
    text = re.sub(r"(?m)^k = \{.*\}$", "k = { values = [400.0] }", text)
    text = re.sub(r"(?m)^F = \{.*\}$", "F = { values = [1.0] }", text)
    path = folder / "one_point.toml"
    path.write_text(text)
    return path


def commands(config: Path) -> dict:
    return {"stability_one_point_s": ["stability", "--vx", "5", "--delta", "0.3"],
            "stability_user_model_s": ["stability", str(USER_MODEL / "chain.toml"),
                                       "--at", "k=400", "--at", "F=1"],
            "verdict_one_point_s": ["verdict", str(config), "--method", "rk4", "--h", "0.01"]}


def figures() -> dict:
    """The best wall time [s] of each command, and of `stepzoo --version` (the start-up)."""
    env = dict(os.environ, XLA_FLAGS=as_user(os.environ.get("XLA_FLAGS", "")))
    run = lambda args: subprocess.run([sys.executable, "-m", "stepzoo", *args], env=env,
                                      capture_output=True, text=True, check=True)
    fig = {}
    with tempfile.TemporaryDirectory() as tmp:
        cmds = dict(commands(one_point_config(Path(tmp))), cli_start_up_s=["--version"])
        for name, args in cmds.items():
            run(args)
            times = []
            for _ in range(ROUNDS):
                t0 = time.perf_counter()
                run(args)
                times.append(time.perf_counter() - t0)
            fig[name] = min(times)
    return fig


def test_one_point_answers(benchmark):
    fig = benchmark.pedantic(figures, rounds=1)
    benchmark.extra_info.update(kind="one_point", figures=fig)
