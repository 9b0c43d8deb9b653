"""Faults from outside: a process short of memory (ulimit -v), SIGINT and SIGKILL at seeded
random moments of the newer commands, truncated and corrupted files, read-only and full disks,
two writers at once. Each refusal is one line and exit status 2, and nothing already written
is lost."""
import json
import os
import random
import resource
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers import (CTRL_C_REACHES, as_user, block_query, each_command, files,
                     needs_modes, private_tmpfs, two_state_config, until_line)

ROOT = Path(__file__).resolve().parents[1]
GIB = 2 ** 30


def limited(gib: float):
    """preexec_fn: the child's address space limited to `gib` GiB (ulimit -v)."""
    def apply():
        resource.setrlimit(resource.RLIMIT_AS, (int(gib * GIB), int(gib * GIB)))
    return apply


def stepzoo(*argv, gib=None, timeout=300, **kw) -> subprocess.CompletedProcess:
    """`python -m stepzoo ARGV` in a new process, under an address-space limit of `gib`."""
    return subprocess.run([sys.executable, "-m", "stepzoo", *map(str, argv)],
                          capture_output=True, text=True, cwd=ROOT, timeout=timeout,
                          preexec_fn=limited(gib) if gib else None, **kw)


def one_line(proc) -> str:
    """The one line of a refusal (exit status 2)."""
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, (proc.returncode, proc.stderr[-2000:])
    return lines[0]


def test_an_address_space_too_small_for_jax_is_one_line_not_an_abort():
    # JAX's CPU runtime aborts in C++ (std::bad_alloc) under 1 GiB: refused before it starts.
    said = one_line(stepzoo("stability", "--vx", "10", "--delta", "0.05", gib=1))
    assert "address-space limit of 1 GiB (ulimit -v)" in said and "raise it" in said


def test_a_run_past_the_address_space_left_is_refused_not_a_deadlock():
    # 1e8 steps x 5 states of float64 are 3.7 GiB, under half this machine's memory, past
    # the 3 GiB the process may map: XLA's allocation would wait forever at 0% CPU.
    said = one_line(stepzoo("simulate", "--method", "rk4", "--h", "1e-6", "--T", "100",
                            "--vx", "10", "--delta", "0.05", gib=3))
    assert "a run of 1e+08 steps would hold 3.73 GiB" in said and "ulimit -v" in said


LIBRARY_BATCH = """
import numpy as np
from stepzoo.integrators import integrate_batch
try:
    integrate_batch("rk4", lambda t, x, u, p: -x, np.ones((1000, 2), np.float32), h=1e-3,
                    n_steps=int(__import__("sys").argv[1]))
except MemoryError as err:
    print("MemoryError:", err)
else:
    print("ran")
"""


def test_a_library_batch_past_the_address_space_left_is_a_memory_error():
    """integrate_batch raises MemoryError, naming the limit, for an output that cannot be
    held under ulimit -v (it waited forever without), and runs one that can."""
    run = lambda n: subprocess.run([sys.executable, "-c", LIBRARY_BATCH, str(n)],
                                   capture_output=True, text=True, timeout=300,
                                   preexec_fn=limited(3))
    big = run(200_000)              # 1.5 GiB of float32 trajectories
    assert big.returncode == 0 and big.stdout.startswith("MemoryError:"), big.stderr[-2000:]
    assert "ulimit -v" in big.stdout and "200001 rows" in big.stdout
    small = run(20_000)
    assert small.returncode == 0 and small.stdout.strip() == "ran", small.stderr[-2000:]


# --- SIGINT and SIGKILL at seeded random moments -------------------------------------------

# --- truncated and corrupted files ----------------------------------------------------------

@pytest.fixture(scope="module")
def tuned(tiny_sweep, tmp_path_factory):
    """(the tiny sweep's config, a copy of its folder, a tuned config of it)."""
    import shutil
    from stepzoo.cli import main
    config, whole = tiny_sweep
    folder = tmp_path_factory.mktemp("faults")
    shutil.copytree(whole, folder / "sweep")
    # By RHS evaluations: the same file on every machine, so the seeded cuts fall alike.
    assert main(["tune", str(folder / "sweep"), "--pos-tol", "1", "--cost", "evals", "--out",
                 str(folder / "tuned.toml")]) == 0
    return config, folder / "sweep", folder / "tuned.toml"


def refused_in_process(capsys, *argv) -> str:
    from stepzoo.cli import main
    capsys.readouterr()
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, (argv, code, err)
    return lines[0]


def test_truncated_or_corrupted_inputs_of_the_newer_commands_are_one_line(tuned, tmp_path,
                                                                          capsys):
    """Each input cut at seeded random lengths (a TOML file also with a seeded byte replaced
    by a NUL): the tuned file of export, the config of verdict, the sweep tables report
    --verdict reads, a saved CasADi function. One line each, exit 2, and nothing written."""
    import casadi as ca
    import shutil
    config, sweep, tuned_file = tuned
    rng = random.Random(36)
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u", 1)
    ca.Function("f", [x, u], [ca.vertcat(x[1], -x[0] + u)]).save(str(tmp_path / "f.casadi"))
    casadi_config = two_state_config(tmp_path, "f.casadi", tmp_path)
    whole = {name: path.read_bytes() for name, path in (
        ("tuned", tuned_file), ("config", config), ("limits", sweep / "limits.parquet"),
        ("runs", sweep / "runs.parquet"), ("casadi", tmp_path / "f.casadi"))}
    for trial in range(3):
        damaged = {}
        for name, data in whole.items():
            text = name in ("tuned", "config")
            if trial < 2 or not text:
                # Cut short; a TOML file within its first half, before the keys a command
                # needs (cut later, what is left may be a whole file of fewer keys).
                damaged[name] = data[:rng.randrange(1, len(data) // 2 if text else
                                                    len(data) - 1)]
            else:               # a byte replaced by a NUL, which no TOML text may hold
                k = rng.randrange(len(data))
                damaged[name] = data[:k] + b"\0" + data[k + 1:]
        (tmp_path / "tuned.toml").write_bytes(damaged["tuned"])
        refused_in_process(capsys, "export", tmp_path / "tuned.toml", "--to", "json",
                           "--sweep", sweep, "--out", tmp_path / "export")
        (tmp_path / "config.toml").write_bytes(damaged["config"])
        refused_in_process(capsys, "verdict", tmp_path / "config.toml", "--method", "euler",
                           "--h", "0.05", "--csv", tmp_path / "v.csv")
        for table in ("limits", "runs"):
            shutil.rmtree(tmp_path / "sweep", ignore_errors=True)
            shutil.copytree(sweep, tmp_path / "sweep")
            (tmp_path / "sweep" / f"{table}.parquet").write_bytes(damaged[table])
            refused_in_process(capsys, "report", tmp_path / "sweep", "--verdict",
                               "euler:0.05", "--out", tmp_path / "report", "-q")
        (tmp_path / "f.casadi").write_bytes(damaged["casadi"])
        refused_in_process(capsys, "stability", casadi_config)
        for made in ("export", "v.csv", "report"):
            assert not (tmp_path / made).exists(), (trial, made)


# --- read-only and full disks ---------------------------------------------------------------

@needs_modes
def test_a_read_only_folder_is_one_line_and_keeps_what_it_holds(tuned, tmp_path):
    """export --out and verdict --csv into a folder no one may write: one line each naming
    the permission, and the files already there unchanged."""
    config, sweep, tuned_file = tuned
    ro = tmp_path / "ro"
    (ro / "export").mkdir(parents=True)
    (ro / "export" / "schedule.csv").write_text("an older export\n")
    # An older verdict table: a file verdict --csv may replace (its columns begin so).
    (ro / "v.csv").write_text("method,h,point\neuler,0.05,0\n")
    before = files(ro)
    for folder in (ro / "export", ro):
        folder.chmod(0o555)
    try:
        said = as_user(["export", tuned_file, "--to", "json", "--sweep", sweep, "--out",
                        ro / "export"],
                       ["verdict", config, "--method", "euler", "--h", "0.05", "--csv",
                        ro / "v.csv"])
    finally:
        for folder in (ro / "export", ro):
            folder.chmod(0o755)
    for code, err in said:
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert "Permission denied" in err, err
    assert files(ro) == before


def test_a_full_disk_is_one_line_and_keeps_what_it_holds(tuned, tmp_path):
    """export --out and verdict --csv onto a 64 kB tmpfs filled to its last byte (a private
    mount) or, where none can be mounted, under a file-size limit of 256 bytes: one line each
    saying so, and the files already there unchanged."""
    config, sweep, tuned_file = tuned
    disk = tmp_path / "disk"
    disk.mkdir()
    argvs = [["export", tuned_file, "--to", "json", "--sweep", sweep, "--out", disk / "export"],
             ["verdict", config, "--method", "euler", "--h", "0.05", "--csv", disk / "v.csv"]]
    env = dict(os.environ, STEPZOO_CACHE_DIR="")      # JAX's cache writes nothing there
    if private_tmpfs() is None:
        script = f"""set -eu
mount -t tmpfs -o size=64k tmpfs {disk}
printf 'method,h,point\\neuler,0.05,0\\n' > {disk}/v.csv
dd if=/dev/zero of={disk}/fill bs=4096 2>/dev/null || true
sha256sum {disk}/v.csv > {tmp_path}/before
{shlex.join(map(str, each_command(*argvs)))} > {tmp_path}/said.json
sha256sum {disk}/v.csv > {tmp_path}/after
"""
        subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c", script],
                       cwd=ROOT, timeout=600, check=True, env=env)
        said = json.loads((tmp_path / "said.json").read_text())
        assert (tmp_path / "before").read_text() == (tmp_path / "after").read_text()
        words = "No space left on device"
    else:
        (disk / "v.csv").write_text("method,h,point\neuler,0.05,0\n")
        def small_files():
            resource.setrlimit(resource.RLIMIT_FSIZE, (256, 256))
        proc = subprocess.run(each_command(*argvs), capture_output=True, text=True, cwd=ROOT,
                              timeout=600, env=env, preexec_fn=small_files)
        assert proc.returncode == 0, proc.stderr[-2000:]
        said = json.loads(proc.stdout)
        assert (disk / "v.csv").read_text() == "method,h,point\neuler,0.05,0\n"
        words = "ulimit -f"
    for code, err in said:
        assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
    assert not any(p.name.endswith(".tmp") for p in disk.rglob("*"))


# --- killed, interrupted and concurrent writers ---------------------------------------------

BUDGETED = 'method = "rk4"\nh = 0.05\n[planner]\nmax_expansions = 60\n'


@pytest.fixture(scope="module")
def queries(tmp_path_factory):
    """A folder with a 40 x 20 m map (a 4 x 10 m block between start and goal), one query
    around it, and a planner config whose budget is expansions, not seconds."""
    folder = tmp_path_factory.mktemp("queries")
    block_query(folder)
    (folder / "planner.toml").write_text(BUDGETED)
    return folder


def test_plan_bench_killed_after_a_seeded_number_of_runs_resumes_and_keeps_them(queries,
                                                                               tmp_path):
    """SIGKILL once k runs are saved (k seeded): --resume keeps those k parts byte for byte
    and ends with every run in the table."""
    from stepzoo.cli import main
    out = tmp_path / "bench"
    argv = ["plan-bench", str(queries / "q.json"), "--config", str(queries / "planner.toml"),
            "--integrator", "rk4:0.05", "--integrator", "euler:0.02", "--runs", "2",
            "--out", str(out), "--no-progress"]
    k = random.Random(36).randint(1, 3)
    proc = subprocess.Popen([sys.executable, "-m", "stepzoo", *argv], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        end = time.monotonic() + 300
        while len(list(out.glob("parts/*.json"))) < k and time.monotonic() < end:
            assert proc.poll() is None, "plan-bench ended before it was killed"
            time.sleep(0.02)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        proc.kill()
    saved = {p.name: p.read_bytes() for p in out.glob("parts/*.json")}
    assert len(saved) >= k and not (out / "runs.parquet").exists()
    assert main([*argv, "--resume"]) == 0
    import pandas as pd
    assert len(pd.read_parquet(out / "runs.parquet")) == 4
    assert {p.name: p.read_bytes() for p in out.glob("parts/*.json")
            if p.name in saved} == saved


def test_tune_for_plans_interrupted_while_planning_keeps_the_old_tuned_file(tuned, queries,
                                                                           tmp_path):
    _, sweep, tuned_file = tuned
    out = tmp_path / "tuned.toml"
    out.write_bytes(tuned_file.read_bytes())
    proc = subprocess.Popen([*CTRL_C_REACHES, "tune", str(sweep), "--pos-tol", "1", "--cost",
                             "evals", "--for-plans", str(queries / "q.json"), "--runs", "3",
                             "--planner-config", str(queries / "planner.toml"), "--out",
                             str(out)], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        until_line(proc, "stepzoo tune: plan [1/")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == 130 and err.strip() == "stepzoo tune: interrupted", err[-2000:]
    assert out.read_bytes() == tuned_file.read_bytes()


def test_verdict_killed_at_a_seeded_moment_leaves_the_old_csv_or_the_whole_new_one(tuned,
                                                                                 tmp_path):
    import pandas as pd
    config, _, _ = tuned
    csv = tmp_path / "v.csv"
    csv.write_text("an older verdict\n")
    argv = [sys.executable, "-m", "stepzoo", "verdict", str(config), "--method", "euler",
            "--h", "0.05", "--csv", str(csv)]
    for delay in random.Random(36).sample([0.5, 2.0, 4.0, 6.0, 8.0], 2):
        proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
        text = csv.read_text()
        if text != "an older verdict\n":
            assert len(pd.read_csv(csv)) == 2, text      # the tiny sweep's two points
        assert not [p for p in tmp_path.iterdir() if p.name != "v.csv"]


def test_two_exports_into_one_folder_at_once_leave_one_whole_export(tuned, tmp_path):
    """Started together: each writes the export or is refused in one line (the folder is
    busy), and the folder ends with one writer's export.json and schedule.csv, whole."""
    _, sweep, tuned_file = tuned
    argv = [sys.executable, "-m", "stepzoo", "export", str(tuned_file), "--to", "json",
            "--sweep", str(sweep), "--out", str(tmp_path / "export")]
    procs = [subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    done = [(p.wait(timeout=300), *p.communicate()) for p in procs]
    printed = []
    for code, stdout, stderr in done:
        if code == 2:
            assert len(stderr.strip().splitlines()) == 1, stderr
        else:
            assert code == 0, stderr
            printed.append(json.loads(stdout))
    assert printed
    assert json.loads((tmp_path / "export" / "export.json").read_text()) in printed
    assert (tmp_path / "export" / "schedule.csv").read_text().count("\n") > 1
