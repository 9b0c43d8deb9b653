"""The bad-input battery: every number out of its physical or numerical range, every request
too large to fit or finish, every unusable file (unreadable, read-only, a full disk or
stdout) is one line on stderr with exit status 2, never a traceback or a hang, and leaves
what was already written as it was. Exit status 1 means a correct run found no answer."""
import hashlib
import json
import shlex
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stepzoo.cli import main as stepzoo
from stepzoo.validate import describe
from helpers import as_user, each_command, needs_modes, private_tmpfs

ROOT = Path(__file__).resolve().parents[1]
SMALL = ROOT / "bench" / "configs" / "small.toml"
BERLIN = ROOT / "search" / "world" / "mapdata" / "Berlin_1_256.map"
TINY = """name = "tiny"
horizon = 0.5
methods = ["euler"]
[envelope]
vx = [20.0]
delta = [0.3]
[steps]
h = [0.05, 0.1]
[stability]
rule = "blowup"
steps = 100
"""


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def refused(capsys, *argv) -> str:
    """The one line `stepzoo ARGV` prints when it refuses with exit status 2."""
    assert stepzoo(list(map(str, argv))) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    return one_line(captured.err)


def digest(folder: Path) -> dict:
    """{relative path: sha256} of every file under `folder`, lock files aside."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != ".stepzoo.lock"}


@pytest.fixture(scope="module")
def finished(tiny_sweep, tmp_path_factory):
    """(config file, a finished sweep folder of it, a tuned config from it)."""
    config, sweep = tiny_sweep
    tuned = tmp_path_factory.mktemp("finished") / "tuned.toml"
    assert stepzoo(["tune", str(sweep), "--pos-tol", "10", "--out", str(tuned)]) == 0
    return config, sweep, tuned


SIMULATE = ["simulate", "--method", "rk4", "--h", "0.01", "--T", "1", "--vx", "10",
            "--delta", "0.1"]


def with_flags(argv, **flags):
    argv = list(argv)
    for flag, value in flags.items():
        flag = "--" + flag.replace("_", "-")
        if flag in argv:
            argv[argv.index(flag) + 1] = value
        else:
            argv += [flag, value]
    return argv


@pytest.mark.parametrize("flags, words", [
    ({"h": "1", "T": "1e308"}, "--T must be a horizon"),
    ({"h": "0.01", "T": "1e12"}, "--T must be a horizon"),
    ({"h": "1e-12", "T": "1"}, "--h must be a step size"),
    ({"vx": "1e308"}, "--vx must be a speed"),
    ({"delta": "10"}, "--delta must be a steer angle"),
    ({"method": "reference", "rtol": "1e-300"}, "--rtol must be a relative tolerance"),
    ({"h": "1e-6", "T": "1e5"}, "would hold"),
    ({"h": "1e-5", "T": "10", "max_memory": "0.001"}, "past the limit of 0.001 GiB"),
    ({"h": "1e-5", "T": "10", "max_steps": "1000"}, "past the limit of 1e+03"),
    ({"max_memory": "-1"}, "--max-memory must be a number > 0"),
])
def test_simulate_refuses_what_is_out_of_range_or_too_large(capsys, flags, words):
    assert words in refused(capsys, *with_flags(SIMULATE, **flags))


def config_with(tmp_path, section, key, value) -> Path:
    """TINY with `key` of `section` (None: top level) set to `value`, as a file."""
    import tomllib

    import tomli_w
    raw = tomllib.loads(TINY)
    (raw.setdefault(section, {}) if section else raw)[key] = value
    path = tmp_path / "bad.toml"
    path.write_text(tomli_w.dumps(raw))
    return path


@pytest.mark.parametrize("kind, section, key, flag, value", [
    ("speed", "envelope", "vx", "--vx", 1e308),
    ("steer", "envelope", "delta", "--delta", 10.0),
])
def test_every_command_checks_a_number_against_the_same_range(tmp_path, capsys, kind,
                                                               section, key, flag, value):
    rule = describe(kind)
    for argv in (with_flags(SIMULATE, **{flag[2:]: str(value)}),
                 with_flags(["stability", "--vx", "10", "--delta", "0.1"],
                            **{flag[2:]: str(value)}),
                 ["sweep", config_with(tmp_path, section, key, [value]), "--out",
                  tmp_path / "out"]):
        assert rule in refused(capsys, *argv), argv


@pytest.mark.parametrize("section, key, value, words", [
    (None, "horizon", 1e308, "horizon must be a horizon"),
    ("steps", "h", [1e-300, 0.1], "every steps.h must be a step size"),
    ("envelope", "vx", [5.0, 1e308], "every envelope.vx must be a speed"),
    ("reference", "rtol", 1e-300, "reference.rtol must be a relative tolerance"),
    ("stability", "growth", 1e308, "stability.growth must be a blow-up growth factor"),
    ("steps", "h", {"min": 0.01, "max": 0.1, "num": 1_000_000_000},
     "steps.h.num must be a number of grid values: a whole number in [1, 10000]"),
    ("steps", "h", {"min": 1e-9, "max": 0.1, "num": 3}, "past the limit"),
    ("limits", "memory_gib", 1e-6, "past the limit of 1e-06 GiB"),
    ("limits", "steps", 10, "past the limit of 10"),
])
def test_a_sweep_config_out_of_range_or_too_large_is_refused_before_any_work(
        tmp_path, capsys, section, key, value, words):
    out = tmp_path / "out"
    assert words in refused(capsys, "sweep", config_with(tmp_path, section, key, value),
                            "--out", out)
    assert not out.exists()


def test_an_envelope_of_too_many_points_is_refused_before_they_are_made(tmp_path, capsys):
    config_with(tmp_path, "envelope", "delta", [0.1, 0.3])
    config = tmp_path / "wide.toml"
    config.write_text((tmp_path / "bad.toml").read_text().replace(
        "[envelope]", "[envelope]\nvx = { min = 1.0, max = 100.0, num = 10000 }").replace(
        "vx = [\n    20.0,\n]\n", ""))
    # --max-steps 1: were the points let through, the work estimate would stop the sweep.
    assert "10000 x 2 operating points; at most 10000" in refused(
        capsys, "sweep", config, "--out", tmp_path / "out", "--max-steps", "1")


def test_plan_refuses_speeds_poses_maps_and_steps_out_of_range(tmp_path, capsys):
    out = tmp_path / "out"
    query = ["--map", BERLIN, "--cell-size", "1.5", "--goal", "213.75,16.5,-1.68"]
    assert "--speed must be a speed" in refused(capsys, "plan", "street", "--speed", "1e308",
                                                "--out", out)
    assert "X must be a coordinate" in refused(capsys, "plan", *query, "--start",
                                               "1e308,56.25,0", "--out", out)
    assert "PSI must be a heading" in refused(capsys, "plan", *query, "--start",
                                              "218.25,56.25,1e308", "--out", out)
    (tmp_path / "big.toml").write_text(
        'map = { size = [1e7, 1e7], resolution = 0.5, obstacles = [] }\n'
        "start = [1, 1, 0]\ngoal = [5, 5, 0]\nspeed = 5\n")
    assert "4e+14 cells" in refused(capsys, "plan", tmp_path / "big.toml", "--out", out)
    (tmp_path / "h.toml").write_text('method = "rk4"\nh = 1e-12\n')
    assert "h.toml: h must be a step size" in refused(
        capsys, "plan", "street", "--config", tmp_path / "h.toml", "--out", out)
    (tmp_path / "h9.toml").write_text('method = "rk4"\nh = 1e-9\n')
    assert "the planner at h = 1e-09 s would hold" in refused(
        capsys, "plan", "street", "--config", tmp_path / "h9.toml", "--out", out)
    (tmp_path / "bad.png").write_bytes(b"not an image")
    assert "cannot read map image" in refused(capsys, "plan", "--map", tmp_path / "bad.png",
                                              "--cell-size", "1", "--start", "1,1,0",
                                              "--goal", "2,2,0", "--out", out)
    (tmp_path / "m.yaml").write_text("image: missing.png\nresolution: 0.05\norigin: [0, 0, 0]\n"
                                     "occupied_thresh: 0.65\nfree_thresh: 0.2\nnegate: 0\n")
    assert "missing.png" in refused(capsys, "plan", "--map", tmp_path / "m.yaml", "--start",
                                    "1,1,0", "--goal", "2,2,0", "--out", out)
    (tmp_path / "file").write_text("kept")
    assert "is not a folder" in refused(capsys, "plan", "street", "--out", tmp_path / "file")
    assert not out.exists() and (tmp_path / "file").read_text() == "kept"


def test_a_start_equal_to_the_goal_is_refused(tmp_path, capsys):
    pose = "218.25,56.25,-1.68"
    assert "the start is the goal" in refused(
        capsys, "plan", "--map", BERLIN, "--cell-size", "1.5", "--start", pose, "--goal", pose,
        "--out", tmp_path / "out")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args, words", [
    (["--margin", "2"], "--margin must be a stability margin"),
    (["--pos-tol=-1"], "--pos-tol must be a position tolerance"),
    (["--seed=-1"], "--seed must be a seed"),
])
def test_run_refuses_bad_arguments_before_it_starts(tmp_path, capsys, args, words):
    out = tmp_path / "results"
    assert words in refused(capsys, "run", "--config", SMALL, "--out", out, *args)
    assert not out.exists()


def test_run_of_a_model_without_a_position_is_refused_before_its_sweep(tmp_path, capsys):
    """The third battery's case: `run` tunes to a position tolerance, and with the chain of
    springs (no X, Y) it failed at the tune stage, after the sweep had run."""
    config = ROOT / "tests" / "user_model" / "chain.toml"
    out = tmp_path / "results"
    assert refused(capsys, "run", "--config", config, "--out", out) == (
        f"stepzoo run: error: {config}: its model springs:chain has no position (X, Y), and "
        "`stepzoo run` tunes to a position tolerance (--pos-tol) for the planner's car; run "
        f"`stepzoo sweep {config} --out DIR`, then `stepzoo tune DIR --tol E --out tuned.toml`")
    assert not out.exists()


def test_tune_finding_nothing_is_exit_1_and_keeps_the_old_file(finished, tmp_path, capsys):
    _, sweep, tuned = finished
    before = tuned.read_bytes()
    assert stepzoo(["tune", str(sweep), "--pos-tol", "1e-12", "--out", str(tuned)]) == 1
    assert "no answer" in one_line(capsys.readouterr().err)
    assert tuned.read_bytes() == before


def test_an_output_that_is_an_input_or_not_of_its_kind_is_refused_and_kept(finished, tmp_path,
                                                                           capsys):
    """The third battery's data lost: `verdict --csv` naming the config file itself, and
    `tune --out` naming the user's model module (springs.py for springs.toml), replaced them.
    A file output replaces only a file of the kind its command writes, never one it reads."""
    from stepzoo.results_folder import TUNED_FILE, VERDICT_CSV
    config, sweep, tuned = finished
    mine = Path(shutil.copy(config, tmp_path / "tiny.toml"))
    module = Path(shutil.copy(ROOT / "tests" / "user_model" / "springs.py", tmp_path))
    before = digest(tmp_path)
    verdict = ["verdict", mine, "--method", "euler", "--h", "0.05", "--pos-tol", "10"]
    assert refused(capsys, *verdict, "--csv", mine) == (
        f"stepzoo verdict: error: --csv {mine} is {mine}, which this command reads; give a new "
        "file name, such as verdict.csv")
    assert refused(capsys, *verdict, "--csv", module) == (
        f"stepzoo verdict: error: --csv {module} is not a verdict table (a CSV file of columns "
        "method, h, point, ...), which this command writes, and would be lost; give a new "
        "file name, such as verdict.csv")
    for target in (module, mine):
        assert refused(capsys, "tune", sweep, "--pos-tol", "10", "--out", target) == (
            f"stepzoo tune: error: --out {target} is not a tuned config (a TOML file with "
            "method and h), which this command writes, and would be lost; give a new file "
            "name, such as tuned.toml")
    assert digest(tmp_path) == before
    assert TUNED_FILE.holds(tuned)                 # what they write, they may write again
    assert stepzoo([*map(str, verdict), "--csv", str(tmp_path / "v.csv")]) == 0
    assert VERDICT_CSV.holds(tmp_path / "v.csv")


@pytest.mark.parametrize("table, change, words", [
    ("runs", "plan-bench", "runs.parquet is not a sweep's runs table (it lacks point; its "
     "columns are query, map, cell_size, run and "),
    ("runs", "stable", "runs.parquet lacks column(s) stable: it was written by another "
     "version of `stepzoo sweep`, or changed since"),
    ("runs", "vx", "runs.parquet lacks column(s) vx: it was written by another version"),
    ("runs", "err_pos", "runs.parquet lacks column(s) err_pos: it was written by another "
     "version"),
    ("limits", "h_meas", "limits.parquet lacks column(s) h_meas: it was written by another "
     "version"),
    ("limits", "method", "limits.parquet is not a sweep's limits table (it lacks method"),
])
def test_a_sweep_table_of_another_command_or_version_is_one_line(finished, tmp_path, capsys,
                                                                 table, change, words):
    """The second battery's plan-bench runs.parquet in a sweep folder (tune tuned anyway),
    and the third's tables lacking a column (tune, export: KeyError tracebacks): tune, export
    and report check a sweep's tables by one contract before they read them."""
    from stepzoo.search.plans.schema import RUN_COLUMNS
    _, sweep, tuned = finished
    folder = tmp_path / "sweep"
    shutil.copytree(sweep, folder)
    path = folder / f"{table}.parquet"
    if change == "plan-bench":
        pd.DataFrame([dict.fromkeys(RUN_COLUMNS, 1.0)]).to_parquet(path)
    else:
        pd.read_parquet(path).drop(columns=[change]).to_parquet(path)
    out = tmp_path / "out"
    for argv in (["tune", folder, "--pos-tol", "10", "--out", tmp_path / "t.toml"],
                 ["export", tuned, "--to", "json", "--sweep", folder, "--out", out],
                 ["report", folder, "--out", out, "-q"]):
        if argv[0] == "report" and change == "err_pos":
            continue                                # the report draws the --tol error then
        assert words in refused(capsys, *argv), argv
    assert not out.exists() and not (tmp_path / "t.toml").exists()


# ---- files the operating system refuses ---------------------------------------------------



@needs_modes
def test_unreadable_inputs_are_one_line(finished, tmp_path):
    config, sweep, _ = finished
    secret = tmp_path / "secret.toml"
    shutil.copy(config, secret)
    secret.chmod(0)
    grid = tmp_path / "grid.npy"
    np.save(grid, np.zeros((40, 40), bool))
    grid.chmod(0)
    yaml = tmp_path / "m.yaml"
    yaml.write_text("image: grid.png\nresolution: 1\norigin: [0, 0, 0]\n")
    yaml.chmod(0)
    shutil.copytree(sweep, tmp_path / "sweep")
    (tmp_path / "sweep" / "runs.parquet").chmod(0)
    said = as_user(
        ["sweep", secret, "--out", tmp_path / "out"],
        ["plan", "--map", grid, "--cell-size", "1", "--start", "5,5,0", "--goal", "30,30,0",
         "--out", tmp_path / "plan", "-q"],
        ["plan", "--map", yaml, "--start", "5,5,0", "--goal", "30,30,0", "--out",
         tmp_path / "plan", "-q"],
        ["tune", tmp_path / "sweep", "--pos-tol", "10", "--out", tmp_path / "t.toml"],
        ["report", tmp_path / "sweep", "--out", tmp_path / "report", "-q"])
    for (code, err), named in zip(said, ["Permission denied", "grid.npy", "m.yaml",
                                         "runs.parquet", "runs.parquet"]):
        assert code == 2 and named in one_line(err), err
    for _, err in said[3:]:
        assert "Permission denied" in err, err
    assert not (tmp_path / "out").exists() and not (tmp_path / "plan").exists()


@needs_modes
def test_a_read_only_output_folder_is_one_line_and_keeps_what_it_holds(finished, tmp_path):
    config, sweep, tuned = finished
    shutil.copytree(sweep, tmp_path / "sweep")
    shutil.copy(tuned, tmp_path / "tuned.toml")
    (tmp_path / "plans").mkdir()
    before = digest(tmp_path)
    for folder in (tmp_path / "sweep", tmp_path / "plans", tmp_path):
        folder.chmod(0o555)
    try:
        said = as_user(["sweep", config, "--out", tmp_path / "sweep", "--resume"],
                       ["tune", tmp_path / "sweep", "--pos-tol", "10", "--out",
                        tmp_path / "tuned.toml"],
                       ["report", tmp_path / "sweep", "--out", tmp_path / "report", "-q"],
                       ["plan", "street", "--out", tmp_path / "plans", "-q"])
        for code, err in said:
            assert code == 2 and "Permission denied" in one_line(err), err
    finally:
        for folder in (tmp_path / "sweep", tmp_path / "plans", tmp_path):
            folder.chmod(0o755)
    assert digest(tmp_path) == before


@pytest.mark.skipif(private_tmpfs() is not None, reason=str(private_tmpfs()))
def test_a_full_disk_is_one_line_and_keeps_what_it_holds(finished, tmp_path):
    """On a tmpfs filled to the last byte (in a private mount namespace), sweep, tune,
    report and plan each say the disk is full, and the files there are unchanged."""
    config, sweep, tuned = finished
    disk = tmp_path / "disk"
    disk.mkdir()
    commands = shlex.join(each_command(
        ["sweep", config, "--out", disk / "sweep", "--resume", "--no-progress"],
        ["tune", disk / "sweep", "--pos-tol", "10", "--out", disk / "tuned.toml"],
        ["report", disk / "sweep", "--out", disk / "report", "-q"],
        ["plan", "street", "--out", disk / "plans", "-q"]))
    script = f"""set -eu
mount -t tmpfs -o size=4m tmpfs {disk}
cp -r {sweep} {disk}/sweep && cp {tuned} {disk}/tuned.toml && mkdir {disk}/plans
dd if=/dev/zero of={disk}/fill bs=4096 2>/dev/null || true
find {disk}/sweep {disk}/tuned.toml -type f ! -name .stepzoo.lock | sort | xargs sha256sum > {tmp_path}/before
{commands} > {tmp_path}/said.json 2> {tmp_path}/said.err
find {disk}/sweep {disk}/tuned.toml -type f ! -name .stepzoo.lock | sort | xargs sha256sum > {tmp_path}/after
"""
    subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c", script],
                   cwd=ROOT, timeout=600, check=True)
    said = json.loads((tmp_path / "said.json").read_text())
    for (code, err), name in zip(said, ("sweep", "tune", "report", "plan")):
        assert code == 2, (name, err)
        assert f"No space left on device: {disk}" in one_line(err), name
    assert len(said) == 4 and (tmp_path / "said.err").read_text() == ""
    assert (tmp_path / "before").read_text() == (tmp_path / "after").read_text()


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full on this system")
@pytest.mark.parametrize("argv", [["methods"], SIMULATE[:4] + ["0.0001"] + SIMULATE[5:]])
def test_a_full_stdout_is_one_line(argv):
    with open("/dev/full", "w") as full:
        proc = subprocess.run([sys.executable, "-m", "stepzoo", *argv], stdout=full,
                              stderr=subprocess.PIPE, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 2
    assert "cannot write the output to stdout: No space left on device" in one_line(proc.stderr)


def test_version_and_the_exit_statuses_are_documented(capsys):
    with pytest.raises(SystemExit) as stop:
        stepzoo(["--version"])
    assert stop.value.code == 0
    from stepzoo import __version__
    assert capsys.readouterr().out.strip() == f"stepzoo {__version__}"
    with pytest.raises(SystemExit):
        stepzoo(["tune", "--help"])
    helptext = capsys.readouterr().out
    for status in ("0 ", "1 ", "2 ", "130"):
        assert f"\n  {status}" in helptext


DEEP_TOML = "a = " + "[" * 50000 + "]" * 50000 + "\n"
DEEP_JSON = "[" * 50000 + "]" * 50000


def test_runaway_nesting_is_one_line_in_every_reader(finished, tmp_path, capsys):
    """TOML and JSON nested past Python's recursion limit, given to each reader of user files
    (a sweep config, a planner config, a scenario, plan-bench's queries, a tuned config, a
    sweep folder's manifest for report and tune, a served plan's request): each says so in one
    line, exit 2, or (the server) a ValueError it answers, and writes nothing."""
    from stepzoo.search.plans.request import Messages
    config, sweep, _ = finished
    deep_toml, deep_json = tmp_path / "deep.toml", tmp_path / "deep.json"
    deep_toml.write_text(DEEP_TOML)
    deep_json.write_text(DEEP_JSON)
    folder = tmp_path / "sweep"
    shutil.copytree(sweep, folder)
    (folder / "manifest.json").write_text(DEEP_JSON)
    out = tmp_path / "out"
    for argv in (["sweep", deep_toml, "--out", out], ["verdict", deep_toml, "--method", "rk4",
                                                       "--h", "0.01"],
                 ["plan", "street", "--config", deep_toml, "--out", out],
                 ["plan", deep_toml, "--out", out], ["plan-bench", deep_json, "--out", out],
                 ["report", sweep, "--tuned", deep_toml, "--out", out, "-q"],
                 ["report", folder, "--out", out, "-q"],
                 ["tune", folder, "--pos-tol", "10", "--out", tmp_path / "tuned.toml"]):
        line = refused(capsys, *argv)
        assert "nested deeper" in line or "damaged" in line, (argv, line)
        assert not out.exists() and not (tmp_path / "tuned.toml").exists()
    left, right = socket.socketpair()
    with left, right:
        left.sendall(DEEP_JSON.encode() + b"\n")
        with pytest.raises(ValueError, match="nested deeper"):
            Messages(right).next()


# ---- output folders that are not the command's to write -----------------------------------

def _folder_commands(finished):
    """The commands that write a folder, each with what --out follows and whether it has
    --overwrite."""
    config, sweep, _ = finished
    return [(["sweep", config], True), (["sweep", config, "--resume"], True),
            (["plan", "street"], False), (["report", sweep], False),
            (["run", "--config", config], False)]


def test_a_folder_of_the_users_own_files_is_refused_and_kept(finished, tmp_path, capsys):
    """The issue's case: a folder holding the user's manifest.json, config.toml and
    summary.csv (names stepzoo writes too) is named, never written into."""
    mine = tmp_path / "mine"
    mine.mkdir()
    for name in ("manifest.json", "config.toml", "summary.csv"):
        (mine / name).write_text(f"the user's own {name}\n")
    before = digest(mine)
    for argv, overwrite in _folder_commands(finished):
        line = refused(capsys, *argv, "--out", mine)
        assert line == (f"stepzoo {argv[0]}: error: --out {mine} holds files that `stepzoo "
                        f"{argv[0]}` did not write (config.toml, manifest.json, summary.csv); "
                        "give an empty or new --out"
                        + (", or pass --overwrite to write into it anyway" if overwrite else ""))
    assert digest(mine) == before and not (mine / ".stepzoo.lock").exists()


def test_an_empty_out_is_refused_and_nothing_is_written_here(finished, tmp_path, monkeypatch,
                                                              capsys):
    monkeypatch.chdir(tmp_path)
    for argv, _ in _folder_commands(finished):
        assert refused(capsys, *argv, "--out", "") == (
            f"stepzoo {argv[0]}: error: --out is empty; give the name of a folder, such as "
            "--out results")
    assert list(tmp_path.iterdir()) == []


def test_an_out_through_a_linked_parent_is_taken_and_a_link_exposing_other_files_refused(
        finished, tmp_path, capsys):
    """Links among --out's parents are the user's layout (macOS's /tmp and /var are links):
    the second battery's case, refused before, now writes there. A link as --out itself is
    followed only to a folder it may write (empty, or its own results): one of other files,
    or no folder, is refused even with --overwrite, naming where the link leads."""
    config, _, _ = finished
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (tmp_path / "link").symlink_to(elsewhere)
    assert stepzoo(["sweep", str(config), "--out", str(tmp_path / "link" / "sub"),
                    "--no-progress"]) == 0
    assert (elsewhere / "sub" / "runs.parquet").is_file()
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("kept")
    (tmp_path / "to_theirs").symlink_to(theirs)
    (tmp_path / "to_file").symlink_to(theirs / "notes.txt")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    capsys.readouterr()
    for argv, overwrite in _folder_commands(finished):
        extra = ["--overwrite"] if overwrite and "--resume" not in argv else []
        assert refused(capsys, *argv, "--out", tmp_path / "to_theirs", *extra) == (
            f"stepzoo {argv[0]}: error: --out {tmp_path / 'to_theirs'} (a symbolic link to "
            f"{theirs}) holds files that `stepzoo {argv[0]}` did not write (notes.txt); give "
            "an empty or new --out")
        for link, real in (("to_file", theirs / "notes.txt"), ("dangling", tmp_path / "nowhere")):
            assert refused(capsys, *argv, "--out", tmp_path / link) == (
                f"stepzoo {argv[0]}: error: --out {tmp_path / link} is a symbolic link to "
                f"{real}, which is not a folder; give a folder, such as --out results")
    assert digest(theirs) == {"notes.txt": digest(theirs)["notes.txt"]}
    assert not (tmp_path / "nowhere").exists()
    from stepzoo.results_folder import claim
    (tmp_path / "empty").mkdir()
    (tmp_path / "to_empty").symlink_to(tmp_path / "empty")
    with claim(tmp_path / "to_empty", "plan") as folder:   # an empty folder, through its link
        assert folder == tmp_path / "empty" and (tmp_path / "to_empty").is_symlink()
