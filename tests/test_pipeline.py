"""`stepzoo run`: the real pipeline writes every artefact it promises (sweep tables, tuned
config, a plan per built-in scenario made with the tuned step, the report), keeps stdout for
the report's path, finishes a run killed in its sweep from the chunks on disk to the tables
of an undisturbed sweep, and a bad config is one line, exit 2."""
import json
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pandas as pd
import pytest
from helpers import (TABLES, TIMED, TINY_SWEEP, check_provenance, check_report, read_tables,
                     without_timings)

from stepzoo.cli import main as stepzoo
from stepzoo.integrators import METHODS
from stepzoo.search.world.scenarios import builtin_names

pytestmark = pytest.mark.slow      # run first: see tests/conftest.py

ROOT = Path(__file__).resolve().parents[1]
SWEEP_FILES = ["config.toml", "manifest.json", "runs.parquet", "limits.parquet", "limits.csv",
               "summary.csv", "eigenvalues.parquet", "trajectories.parquet"]
POS_TOL = "1"   # [m] what the tiny sweep's coarse steps can meet


@pytest.fixture(scope="module")
def ran(tiny_sweep, tmp_path_factory):
    """(config, results folder, the finished process) of `stepzoo run` on the tiny sweep,
    killed once its sweep has a chunk on disk (its lock dies with it) and run again, the
    same command: every test of the pipeline reads the resumed run. A whole run, twice: the
    tests that read it are end-to-end (pytest.mark.e2e, `make test-e2e`)."""
    config, _ = tiny_sweep
    out = tmp_path_factory.mktemp("run") / "results"
    argv = [sys.executable, "-m", "stepzoo", "run", "--config", str(config), "--out", str(out),
            "--pos-tol", POS_TOL]
    killed = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not any((out / "sweep" / "chunks").glob("euler-*")) and time.monotonic() < deadline:
        time.sleep(0.05)
    killed.send_signal(signal.SIGKILL)
    killed.wait()
    assert not (out / "sweep" / "runs.parquet").exists()
    return config, out, subprocess.run(argv, capture_output=True, text=True, cwd=ROOT,
                                       timeout=600)


@pytest.mark.e2e
def test_a_killed_run_resumes_to_the_tables_of_an_undisturbed_sweep(ran, tiny_sweep,
                                                                    tmp_path):
    _, out, proc = ran
    _, whole = tiny_sweep
    assert proc.returncode == 0, proc.stderr[-2000:]
    a, b = read_tables(whole), read_tables(out / "sweep")
    for name in TABLES:
        pd.testing.assert_frame_equal(a[name], b[name], check_exact=True, obj=name)
    # Ranked by evaluations, both choices are the tables' alone: in time (run's ranking),
    # two calibrations on a loaded machine chose euler once and heun the other time.
    chosen = []
    for sweep in (out / "sweep", whole):
        target = tmp_path / f"{len(chosen)}.toml"
        assert stepzoo(["tune", str(sweep), "--pos-tol", POS_TOL, "--cost", "evals",
                        "--rounds", "1", "--out", str(target)]) == 0
        t = tomllib.loads(target.read_text())
        chosen.append([(t["method"], t["h"])]
                      + [(r["method"], r.get("h")) for r in t["runners_up"]])
    assert chosen[0] == chosen[1]


@pytest.mark.e2e
def test_run_ends_by_printing_the_report_path(ran):
    _, out, proc = ran
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip().splitlines()[-1] == str(out / "report" / "index.html")
    for stage in ("[1/4] sweep", "[2/4] tune", "[3/4] plan", "[4/4] report"):
        assert stage in proc.stderr


@pytest.mark.e2e
def test_run_writes_sweep_tables_and_a_tuned_config_from_them(ran):
    _, out, proc = ran
    assert proc.returncode == 0, proc.stderr[-2000:]
    for name in SWEEP_FILES:
        assert (out / "sweep" / name).is_file(), name
    assert len(pd.read_parquet(out / "sweep" / "runs.parquet")) > 0
    tuned = tomllib.loads((out / "tuned.toml").read_text())
    manifest = json.loads((out / "sweep" / "manifest.json").read_text())
    assert tuned["method"] in METHODS and tuned["h"] > 0
    assert tuned["sweep_config_sha256"] == manifest["config_sha256"]


@pytest.mark.e2e
def test_run_plans_every_builtin_scenario_with_the_tuned_step(ran):
    _, out, proc = ran
    assert proc.returncode == 0, proc.stderr[-2000:]
    tuned = tomllib.loads((out / "tuned.toml").read_text())
    assert (out / "plans" / "summary.csv").is_file()
    for name in builtin_names():
        stats = json.loads((out / "plans" / name / "plan.json").read_text())["stats"]
        assert stats["method"] == tuned["method"] and stats["h"] == pytest.approx(tuned["h"])


@pytest.mark.e2e
def test_run_builds_the_full_report(ran):
    _, out, proc = ran
    assert proc.returncode == 0, proc.stderr[-2000:]
    text = check_report(out / "report", n_plans=len(builtin_names()))
    assert f"{tomllib.loads((out / 'tuned.toml').read_text())['method']} at h" in text


def test_run_with_a_missing_config_is_one_line_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "results"
    assert stepzoo(["run", "--config", str(tmp_path / "nope.toml"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope.toml" in err
    assert not out.exists()


def test_run_default_config_is_the_shipped_envelope():
    from stepzoo.workflows.pipeline import config_path
    assert config_path(None).resolve() == (ROOT / "bench" / "configs" / "envelope.toml")


@pytest.mark.e2e
def test_every_results_folder_of_a_run_records_its_environment_and_progress(ran):
    _, out, proc = ran
    assert proc.returncode == 0, proc.stderr[-2000:]
    for folder, kind in ((out, "run"), (out / "sweep", "sweep"), (out / "plans", "plan"),
                         (out / "report", "report")):
        manifest = json.loads((folder / "manifest.json").read_text())
        check_provenance(manifest, kind)
        assert manifest["command_line"].startswith("python -m stepzoo run --config")
    # A line per planned scenario and per figure, so no stage is silent for long.
    names = builtin_names()
    for i, name in enumerate(names, 1):
        assert f"stepzoo plan: [{i}/{len(names)}] {name}: " in proc.stderr
    for i in range(1, 8):
        assert f"stepzoo report: [{i}/7] Figure {i}. " in proc.stderr


@pytest.mark.e2e
def test_a_stage_that_finds_nothing_is_one_line_naming_it_and_keeps_what_was_written(ran,
                                                                                      capsys):
    # Last: it runs again in the shared folder, as a second `make run` does, and reuses the
    # finished sweep (its manifest is not rewritten); no (method, h) meets a tolerance of a
    # nanometre, so tune finds no answer (exit 1).
    config, out, proc = ran
    assert proc.returncode == 0, proc.stderr[-2000:]
    before = (out / "tuned.toml").read_text()
    created = json.loads((out / "sweep" / "manifest.json").read_text())["created"]
    assert stepzoo(["run", "--config", str(config), "--out", str(out), "--pos-tol", "1e-9",
                    "-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("stepzoo run: no answer: stopped at tune: "), err
    assert (out / "tuned.toml").read_text() == before
    assert json.loads((out / "sweep" / "manifest.json").read_text())["created"] == created


@pytest.mark.e2e
def test_figures_drawn_while_planning_are_the_report_s_own(ran):
    """Figures 1-6, drawn in the second process while the run plans, are byte for byte what
    the report draws from the run's folder: the same PNGs and the same Plotly fragments."""
    from stepzoo.workflows.report import sweep_figures
    from stepzoo.reports.drawing import draw_apart
    from stepzoo.reports.load import load_sweep, load_tuned
    _, out, proc = ran
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stderr.splitlines()
    for i in range(1, 8):
        assert any(f"] Figure {i}. " in line and line.endswith("drawn ahead") == (i < 7)
                   for line in lines), i
    page = (out / "report" / "index.html").read_text()
    here = draw_apart(sweep_figures(load_sweep(out / "sweep"), load_tuned(out / "tuned.toml"),
                                    lambda line: None))
    assert [d.shown.number for d in here] == [1, 2, 3, 4, 5, 6]
    for drawn in here:
        assert drawn.divs and all(div in page for div in drawn.divs)
        for name, png in drawn.files.items():
            assert (out / "report" / name).read_bytes() == png, name


def test_a_report_process_that_fails_leaves_the_report_to_the_pipeline(tmp_path):
    from stepzoo.workflows.second_process import Ahead
    ahead = Ahead()
    try:
        ahead.figures(tmp_path / "no-sweep", tmp_path / "no-tuned.toml")
        assert ahead.report(tmp_path / "no-sweep", tmp_path / "report", None, None, False) is None
    finally:
        ahead.close()


def test_a_second_process_that_died_is_told_by_its_pipe_not_by_sigpipe():
    """The `stepzoo` command leaves SIGPIPE at its default (for `stepzoo ... | head`): a job
    sent to a second process that has died (killed, out of memory) is refused (False, the
    pipeline then does the work) instead of ending this process by SIGPIPE (exit 141)."""
    from stepzoo.search.world.scenarios import builtin_names, load_scenario
    from stepzoo.workflows.second_process import Ahead
    ahead = Ahead()
    before = signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    try:
        ahead._proc.kill()
        ahead._proc.join()
        scenario = load_scenario(builtin_names()[0])
        assert [ahead.start(scenario, None, 0) for _ in range(3)] == [False] * 3
        assert signal.getsignal(signal.SIGPIPE) == signal.SIG_DFL
    finally:
        signal.signal(signal.SIGPIPE, before)
        ahead.close()


def test_the_second_process_computes_the_chunks_the_sweep_would(tmp_path):
    """The run's sweep shares its chunks with the second process (an implicit method's go
    there): every table of every chunk equals the chunk computed here, bit for bit."""

    from stepzoo.bench.sweep.suite import load
    from stepzoo.bench.sweep.engine import chunk_ids, compute_chunk
    from stepzoo.workflows.second_process import Ahead
    path = tmp_path / "implicit.toml"
    path.write_text(TINY_SWEEP.replace('"heun"', '"backward_euler"'))
    cfg = load(path)
    ahead = Ahead()
    try:
        shared = list(ahead.sweep_runner(path)(cfg, chunk_ids(cfg)))
    finally:
        ahead.close()
    assert sorted(cid for cid, _ in shared) == sorted(chunk_ids(cfg))
    assert [cid for cid, _ in shared][-2:] == ["backward_euler-b000", "backward_euler-b001"]
    cache = {}
    for cid, chunk in shared:
        here = compute_chunk(cfg, cid, cache)
        assert set(chunk) == set(here)
        for name in set(here) - {"timing"}:
            timed = [c for c in here[name].columns if c in TIMED]     # measured wall times
            pd.testing.assert_frame_equal(chunk[name].drop(columns=timed),
                                          here[name].drop(columns=timed), check_exact=True,
                                          obj=name)


class _Fails:
    """A `beside` (plan.plan_all's) that takes a scenario and then fails, as a process that
    died does (`start` True), or cannot take it (`start` False)."""

    def __init__(self, takes: bool):
        self.takes, self.asked = takes, 0

    def start(self, *job):
        self.asked += 1
        return self.takes

    def ready(self):
        return True

    def answer(self):
        return None


class _Spy:
    """A `beside` passing the jobs on to `inner` and noting whether each answer came."""

    def __init__(self, inner):
        self.inner, self.answered = inner, []

    def start(self, *job):
        return self.inner.start(*job)

    def ready(self):
        return self.inner.ready()

    def answer(self):
        got = self.inner.answer()
        self.answered.append(got is not None)
        return got


def test_scenarios_planned_beside_are_the_plans_made_here():
    """The run shares its scenarios with the second process (plan.plan_all, no thread): each
    plan, in the scenarios' order, equals the one planned here but for its wall times, and so
    does the plan.png each process draws of its own; a scenario the second process does not
    plan (it answers None, as when it has died, or cannot take it) is planned here."""
    from stepzoo.search.planner.config import load_config
    from stepzoo.search.world.scenarios import load_scenario
    from stepzoo.workflows.plan import plan_all
    from stepzoo.workflows.second_process import Ahead
    # The regression plans' config: no clock budget, so a plan is the same however loaded.
    config = load_config(ROOT / "tests" / "data" / "plan_regression" / "config.toml")
    scenario = load_scenario("wall_between")
    ahead = Ahead()
    try:
        spy = _Spy(ahead)
        shared = plan_all([scenario, scenario], config, 0, False, spy)
    finally:
        ahead.close()
    assert spy.answered == [True]       # the second process planned the second one
    here, there = [(without_timings(r), png) for r, png in shared]
    assert here[1].startswith(b"\x89PNG") and there == here
    for takes in (True, False):
        fails = _Fails(takes)
        (record, png), = plan_all([scenario], config, 0, False, fails)
        assert fails.asked == 1 and (without_timings(record), png) == here
