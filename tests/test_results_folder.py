"""A results folder is never silently lost: one writer at a time (a second one is refused in
one line, exit 2, while a killed writer's lock is taken over), a folder of another command's
results is refused, the sweep's tables are written only when every chunk its config implies
is there, tune and report refuse a sweep folder that is incomplete or inconsistent, and a
report stopped or killed midway leaves the old report whole."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from stepzoo.bench.sweep import tables as schema
from stepzoo.cli import main as stepzoo
from stepzoo.bench.sweep.engine import chunk_ids, run_sweep
from stepzoo.bench.sweep.config import load
from stepzoo.errors import UsageError
from stepzoo.results_folder import LOCK, claim, replacing
from helpers import CTRL_C_REACHES, TABLES, read_tables, write_sweep, write_tuned

ROOT = Path(__file__).resolve().parents[1]


def cli(*args, timeout=120):
    """`stepzoo ARGS` in a new process: (status, stdout, stderr)."""
    proc = subprocess.run([sys.executable, "-m", "stepzoo", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    return proc.returncode, proc.stdout, proc.stderr


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_a_second_writer_is_refused_in_one_line_while_the_first_holds_the_folder(tmp_path):
    out = tmp_path / "out"
    with claim(out, "sweep"):
        code, _, err = cli("sweep", ROOT / "bench" / "configs" / "small.toml", "--out", out,
                           "--resume")
    assert code == 2 and "in use by another stepzoo command" in one_line(err)
    assert {p.name for p in out.iterdir()} == {LOCK}        # it wrote nothing


def test_a_killed_writers_lock_is_taken_over(tmp_path):
    out = tmp_path / "out"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom stepzoo.results_folder import claim\n"
         f"with claim({str(out)!r}, 'sweep'):\n    print('held', flush=True)\n"
         "    time.sleep(120)"], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(UsageError, match="in use"), claim(out, "sweep"):
            pass
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert (out / LOCK).exists()          # the lock file stays; its lock died with the holder
    with claim(out, "sweep"):
        pass


def test_a_folder_is_the_commands_own_by_its_manifest_or_its_lock(tmp_path):
    """A sweep stopped before its manifest (its config.toml written) goes on in its folder,
    which its lock file names as a sweep's; a plan is refused there. The same file without
    stepzoo's lock is the user's: refused, unless the command's --overwrite says so."""
    out = tmp_path / "out"
    with claim(out, "sweep", overwrite=False):
        (out / "config.toml").write_text("the sweep's")
    with claim(out, "sweep", overwrite=False):
        pass
    with pytest.raises(UsageError, match=r"holds the results of `stepzoo sweep` \(\.stepzoo"), \
            claim(out, "plan"):
        pass
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "config.toml").write_text("the user's")
    with pytest.raises(UsageError, match=r"did not write \(config.toml\); .* --overwrite"), \
            claim(mine, "sweep", overwrite=False):
        pass
    assert sorted(p.name for p in mine.iterdir()) == ["config.toml"]
    with claim(mine, "sweep", overwrite=True) as folder:
        assert (folder / "config.toml").read_text() == "the user's"


def test_racing_sweeps_leave_the_first_ones_tables_whole(tiny_sweep, tmp_path):
    """While a sweep runs, an --overwrite and a --resume of the same folder are refused, and
    a second writer killed at once cannot touch it: the first ends with every table whole,
    equal to an undisturbed sweep's."""
    path, whole = tiny_sweep
    out = tmp_path / "out"
    seen = []

    def intrude(chunk_id):
        if seen:
            return
        seen.append(chunk_id)
        for flag in ("--overwrite", "--resume"):
            code, _, err = cli("sweep", path, "--out", out, flag, "--no-progress")
            assert code == 2 and "in use" in one_line(err)
        killed = subprocess.Popen([sys.executable, "-m", "stepzoo", "sweep", str(path),
                                   "--out", str(out), "--overwrite"], cwd=ROOT)
        time.sleep(1.0)
        killed.send_signal(signal.SIGKILL)
        killed.wait()
        assert (out / "chunks" / chunk_id).is_dir()

    manifest = run_sweep(load(path), out, progress=False, on_chunk=intrude)
    assert manifest["complete"] and manifest["chunks"] == chunk_ids(load(path))
    a, b = read_tables(whole), read_tables(out)
    for name in TABLES:
        pd.testing.assert_frame_equal(a[name], b[name], check_exact=True, obj=name)


# `stepzoo` whose sweep waits after writing its first chunk, until Ctrl-C.
WAITS_AFTER_FIRST_CHUNK = """
import sys, time
from stepzoo.bench.sweep import engine
from stepzoo.cli import main
write = engine._write_chunk
def write_then_wait(*args):
    write(*args)
    time.sleep(300)
engine._write_chunk = write_then_wait
sys.argv[0] = "stepzoo"
sys.exit(main())
"""


def test_an_interrupted_sweep_says_how_to_resume_and_resumes_to_the_same_tables(tiny_sweep,
                                                                              tmp_path):
    """Ctrl-C lands while the sweep holds its first chunk on disk (the sweep waits there, so
    the tiny sweep cannot end before the signal on a fast machine)."""
    path, whole = tiny_sweep
    out = tmp_path / "out"
    proc = subprocess.Popen([*CTRL_C_REACHES[:-2], "-c", WAITS_AFTER_FIRST_CHUNK, "sweep",
                             str(path), "--out", str(out), "--no-progress"], cwd=ROOT,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not any((out / "chunks").glob("[!.]*")) and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert one_line(err) == "stepzoo sweep: interrupted; resume with --resume"
    assert not (out / "runs.parquet").exists()
    code, _, err = cli("sweep", path, "--out", out, "--resume", "--no-progress")
    assert code == 0, err
    a, b = read_tables(whole), read_tables(out)
    for name in TABLES:
        pd.testing.assert_frame_equal(a[name], b[name], check_exact=True, obj=name)


@pytest.mark.parametrize("stopped_at", [1, 2, 3])
def test_a_sweep_stopped_at_its_first_writes_resumes(tiny_sweep, tmp_path, monkeypatch,
                                                     stopped_at):
    """Ctrl-C at the sweep's first, second or third write (its config copy, its manifests): a
    --resume continues it to the whole sweep's tables. A folder left with chunks/ and no
    manifest was refused as "a sweep of a different config (sha256 None...)": the rerun of an
    interrupted `stepzoo run` ended at its sweep stage."""
    from stepzoo.bench.sweep import engine
    path, whole = tiny_sweep
    out, writes, write = tmp_path / "out", [], engine.atomic_write

    def interrupted(*args):
        writes.append(args[0])
        if len(writes) == stopped_at:
            raise KeyboardInterrupt
        return write(*args)

    monkeypatch.setattr(engine, "atomic_write", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(load(path), out, progress=False)
    monkeypatch.undo()
    assert not (out / "runs.parquet").exists()
    run_sweep(load(path), out, resume=True, progress=False)
    a, b = read_tables(whole), read_tables(out)
    for name in TABLES:
        pd.testing.assert_frame_equal(a[name], b[name], check_exact=True, obj=name)


def test_resume_with_overwrite_is_refused_and_writes_nothing(tiny_sweep, tmp_path):
    path, _ = tiny_sweep
    code = stepzoo(["sweep", str(path), "--out", str(tmp_path / "out"), "--resume",
                    "--overwrite"])
    assert code == 2 and not (tmp_path / "out").exists()


def test_a_sweep_that_lost_a_chunk_writes_no_tables(tiny_sweep, tmp_path):
    """A chunk removed behind the sweep's back (not by a stepzoo command: those wait for the
    lock) is found missing at assembly: no table is written and the manifest stays
    incomplete, so tune and report refuse the folder."""
    import shutil
    path, _ = tiny_sweep
    out = tmp_path / "out"
    lost = []

    def remove_the_first(chunk_id):
        if not lost:
            lost.append(chunk_id)
            shutil.rmtree(out / "chunks" / chunk_id)

    with pytest.raises(UsageError, match="lost 1 chunk"):
        run_sweep(load(path), out, progress=False, on_chunk=remove_the_first)
    assert not (out / "runs.parquet").exists()
    assert json.loads((out / "manifest.json").read_text())["complete"] is False
    run_sweep(load(path), out, resume=True, progress=False)     # --resume recomputes it
    assert (out / "chunks" / lost[0]).is_dir() and (out / "runs.parquet").is_file()


def test_a_chunk_cut_short_is_set_aside_and_computed_again_on_resume(tiny_sweep, tmp_path,
                                                                    capsys):
    """The second battery's case: a chunk file truncated in a finished sweep, then --resume,
    ended in a pyarrow traceback. The damaged chunk is named, kept aside as it was, computed
    again, and the tables are the whole sweep's."""
    import shutil
    path, whole = tiny_sweep
    out = tmp_path / "out"
    shutil.copytree(whole, out)
    cut = out / "chunks" / "euler-b000" / "runs.parquet"
    data = cut.read_bytes()[:-100]
    cut.write_bytes(data)
    assert stepzoo(["sweep", str(path), "--out", str(out), "--resume", "--no-progress"]) == 0
    err = capsys.readouterr().err
    aside = out / "chunks" / ".euler-b000.damaged"
    assert f"sweep: chunk euler-b000 is damaged (runs.parquet: ArrowInvalid); set aside as " \
        f"{aside}, computing it again" in err.splitlines()
    assert (aside / "runs.parquet").read_bytes() == data
    for name, df in read_tables(out).items():
        pd.testing.assert_frame_equal(df, read_tables(whole)[name], check_exact=False, rtol=1e-12,
                                      atol=1e-15)


@pytest.mark.parametrize("command", ["tune", "report"])
def test_tune_and_report_refuse_a_sweep_whose_tables_lack_rows(tiny_sweep, tmp_path, capsys,
                                                               command):
    """The issue's case: a manifest that says complete over tables that hold only some
    methods' runs."""
    import shutil
    _, whole = tiny_sweep
    cut = tmp_path / "cut"
    shutil.copytree(whole, cut)
    runs = pd.read_parquet(cut / "runs.parquet")
    runs[runs["method"] == "euler"].to_parquet(cut / "runs.parquet")
    out = tmp_path / ("t.toml" if command == "tune" else "report")
    args = ["--pos-tol", "0.1"] if command == "tune" else []
    assert stepzoo([command, str(cut), *args, "--out", str(out)]) == 2
    line = one_line(capsys.readouterr().err)
    assert "incomplete or inconsistent sweep" in line and "runs has" in line
    assert not out.exists()


def test_tune_accepts_the_whole_sweep(tiny_sweep, tmp_path):
    _, whole = tiny_sweep
    assert stepzoo(["tune", str(whole), "--pos-tol", "1", "--out",
                    str(tmp_path / "t.toml")]) == 0


@pytest.mark.parametrize("target", ["/dev/null", "folder", "link"])
def test_tune_writes_only_a_regular_file(tiny_sweep, tmp_path, capsys, target):
    _, whole = tiny_sweep
    if target == "folder":
        (tmp_path / "folder").mkdir()
    if target == "link":
        (tmp_path / "real.toml").write_text("kept")
        (tmp_path / "link").symlink_to(tmp_path / "real.toml")
    out = target if target.startswith("/") else str(tmp_path / target)
    before = os.stat(out, follow_symlinks=False)
    assert stepzoo(["tune", str(whole), "--pos-tol", "1", "--out", out]) == 2
    assert f"--out {out} is " in one_line(capsys.readouterr().err)
    after = os.stat(out, follow_symlinks=False)
    assert (after.st_ino, after.st_mode) == (before.st_ino, before.st_mode)


def test_a_folder_of_another_commands_results_is_refused(tiny_sweep, tmp_path, capsys):
    path, whole = tiny_sweep
    plans = tmp_path / "plans"
    plans.mkdir()
    (plans / "plan.json").write_text("{}")
    assert stepzoo(["sweep", str(path), "--out", str(plans)]) == 2
    assert "holds the results of `stepzoo plan` (plan.json)" in one_line(capsys.readouterr().err)
    assert {p.name for p in plans.iterdir()} == {"plan.json"}
    before = {p.name for p in whole.iterdir()}
    for argv in (["plan", "street"], ["report", str(whole)], ["run", "--config", str(path)]):
        assert stepzoo([*argv, "--out", str(whole)]) == 2
        assert "holds the results of `stepzoo sweep`" in one_line(capsys.readouterr().err)
    assert {p.name for p in whole.iterdir()} == before


def test_ctrl_c_stops_a_run_with_one_line_and_status_130(tiny_sweep, tmp_path):
    path, _ = tiny_sweep
    out = tmp_path / "results"
    proc = subprocess.Popen([*CTRL_C_REACHES, "run", "--config", str(path), "--out", str(out),
                             "-q"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    deadline = time.monotonic() + 120
    while not any((out / "sweep" / "chunks").glob("euler-*")) and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    stdout, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and stdout == ""
    assert one_line(err) == ("stepzoo run: interrupted; resume: run it again, the same "
                             "command (finished sweep chunks and plans are kept)")


def report_files(folder) -> dict:
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.name != LOCK}


def test_a_report_stopped_or_killed_midway_leaves_the_old_report_whole(tmp_path, monkeypatch):
    """A second report (with a tuned config, so its page and figures differ from the first's)
    stopped by Ctrl-C at Figure 6 of 7, then one killed (kill -9) at Figure 3: each time the
    folder holds the old report byte for byte, never new figures beside the old index.html.
    The stopped one leaves nothing beside it; the killed one's hidden folder is removed by
    the next report into that folder."""
    sweep = write_sweep(tmp_path / "sweep")
    tuned = write_tuned(tmp_path / "tuned.toml")
    out = tmp_path / "report"
    assert stepzoo(["report", str(sweep), "--out", str(out), "-q"]) == 0
    old = report_files(out)
    again = ["report", str(sweep), "--tuned", str(tuned), "--out", str(out)]
    from stepzoo.reports import figure_data

    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt
    with monkeypatch.context() as patch:
        patch.setattr(figure_data, "stable_step_vs_speed", ctrl_c)
        assert stepzoo([*again, "-q"]) == 130
    assert report_files(out) == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report", "sweep", "tuned.toml"]

    proc = subprocess.Popen([sys.executable, "-m", "stepzoo", *again], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for line in proc.stderr:                # bounded: the report ends by itself
            if line.startswith("stepzoo report: [3/7]"):
                proc.send_signal(signal.SIGKILL)
                break
    finally:
        proc.kill()
        proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert report_files(out) == old
    left = [p for p in tmp_path.iterdir() if p.name.startswith(".report.")]
    assert len(left) == 1 and {"index.html", "manifest.json"}.isdisjoint(
        p.name for p in left[0].iterdir())      # the killed one had drawn figures only
    with replacing(out, "report") as into:      # the next report: stale folder gone, the
        for name, data in old.items():          # new results swapped in whole
            (into / name).write_bytes(data)
        (into / "index.html").write_text("new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report", "sweep", "tuned.toml"]
    assert report_files(out) == {**old, "index.html": b"new"}


def test_every_column_of_a_finished_sweeps_tables_has_a_documented_meaning(tiny_sweep):
    """The results-tables page is made from schema.COLUMN_DOC: a column a table gains without
    a line there would appear in the reference with no meaning."""
    folder = tiny_sweep[1]
    model = json.loads((folder / "manifest.json").read_text())["model_spec"]
    placeholder = {**{v: schema.VARIABLE for v in model["variables"]},
                   **{s: schema.STATE for s in model["states"]},
                   **{f"err_{s}": f"err_{schema.STATE}" for s in model["states"]},
                   **{f"bind_{s}": f"bind_{schema.STATE}" for s in model["states"]}}
    seen = set()
    for table in schema.PARQUET:
        path = folder / f"{table}.parquet"
        if path.exists():
            seen |= {placeholder.get(c, c) for c in pd.read_parquet(path).columns}
    assert {"runs", "limits", "summary"} <= {p.stem for p in folder.glob("*.parquet")}
    undocumented = sorted(c for c in seen if not schema.COLUMN_DOC.get(c, "").strip())
    assert not undocumented, f"columns without a line in schema.COLUMN_DOC: {undocumented}"


def test_a_report_replaced_through_a_link_keeps_the_link(tmp_path):
    """A folder named by a link to the user's own empty folder: the results are swapped in
    whole where the link leads, and the link stays a link to them (the exchange is made on
    the folder, not on the link)."""
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    for text in ("first", "second"):
        with replacing(tmp_path / "link", "report") as into:
            (into / "index.html").write_text(text)
            (into / "manifest.json").write_text(json.dumps(
                {"written_by": "report", "files": ["index.html"]}))
        assert (tmp_path / "link").is_symlink()
        assert (tmp_path / "real" / "index.html").read_text() == text
