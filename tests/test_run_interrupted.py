"""`stepzoo run` interrupted by Ctrl-C at each of its stages: each time one line and exit 130,
every file an earlier stage finished kept as it was, and the same command then finishes the
run, keeping the finished sweep and plans. Apart from test_faults.py, which it belongs with,
because it runs the whole pipeline five times: as a file of its own pytest-xdist runs it
beside the others."""
import random
import signal
import subprocess
import time
from pathlib import Path

import pytest

from helpers import CTRL_C_REACHES, TINY_SWEEP, files, until_line

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def test_run_interrupted_at_each_stage_keeps_what_it_wrote_and_the_same_command_finishes(
        tmp_path):
    """Ctrl-C at the start of each of `stepzoo run`'s stages in turn (and at a seeded moment
    inside it): each time one line, exit 130, every file an earlier stage finished left as it
    was; then the same command finishes the run."""
    config = tmp_path / "tiny.toml"
    config.write_text(TINY_SWEEP)
    out = tmp_path / "results"
    argv = [*CTRL_C_REACHES, "run", "--config", str(config), "--out", str(out), "--pos-tol",
            "1"]
    rng = random.Random(36)
    kept = {}
    for stage, earlier in (("[1/4] sweep", None), ("[2/4] tune", "sweep"),
                           ("[3/4] plan", "tuned.toml"), ("[4/4] report", "plans")):
        proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
        try:
            until_line(proc, stage, timeout=900)       # a loaded machine: minutes
            time.sleep(rng.uniform(0.0, 0.5))
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=300)
        finally:
            proc.kill()
        if earlier is not None:
            target = out / earlier
            kept[earlier] = files(target) if target.is_dir() else {"": target.read_bytes()}
        assert proc.returncode == 130, f"interrupted at {stage}: {err[-2000:]}"
        assert err.strip().splitlines()[-1] == ("stepzoo run: interrupted; resume: run it "
                                                "again, the same command (finished sweep "
                                                "chunks and plans are kept)"), err[-2000:]
        assert "Traceback" not in err
    sweep_before = kept["sweep"]
    done = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (out / "report" / "index.html").is_file()
    # The finished sweep's tables and the finished plans were kept, not computed again.
    now = files(out / "sweep")
    for name in ("runs.parquet", "limits.parquet", "config.toml"):
        assert now[Path(name)] == sweep_before[Path(name)], name
    assert (out / "tuned.toml").read_bytes() == kept["tuned.toml"][""]    # not chosen again
    assert files(out / "plans") == kept["plans"]
    assert "plans kept" in done.stderr
