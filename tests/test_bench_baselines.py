"""`make bench` compares like with like: every RK4 baseline of the final-state regime ends
where stepzoo's rk4 ends, to round-off, so its ratio is of the same work; and the tables of
docs/benchmarks.md are those latest.json holds."""
import json

import numpy as np
import pytest

from stepzoo.bench.perf import run, tables
from stepzoo.bench.perf.workloads import baselines
from stepzoo.bench.perf.workloads.bicycle import H_S, problem

# A batch over driver.SMALL_BATCH, so stepzoo runs in chunks as at the benchmark's batches.
BATCH, STEPS = 40, 20


@pytest.fixture(scope="module")
def final_states():
    args = problem(BATCH)
    return args, np.asarray(baselines.stepzoo_run(H_S, STEPS, "final")(*args))


def _numba(parallel):
    pytest.importorskip("numba", reason="numba is in the bench extra only")
    return baselines.numba_rk4(H_S, STEPS, "final", parallel)


@pytest.mark.parametrize("make", [
    lambda: baselines.numpy_rk4(H_S, STEPS, "final"),
    lambda: baselines.jax_rk4(H_S, STEPS, "final"),
    lambda: baselines.diffrax_run(H_S, STEPS, "final", "rk4"),
    lambda: _numba(False),
    lambda: _numba(True),
], ids=["numpy_loop", "jax_scan", "diffrax_rk4", "numba_serial", "numba_fastmath"])
def test_final_state_baselines_end_where_rk4_ends(final_states, make):
    args, expected = final_states
    got = np.asarray(make()(*args))
    assert got.shape == expected.shape == (BATCH, 5)
    scale = np.abs(expected).max(axis=1, keepdims=True)
    assert np.abs(got - expected).max() / scale.min() < 1e-13
    # Not trivially: the states moved well away from where they started.
    assert np.abs(expected - args[0]).max(axis=1).min() > 0.5


def test_docs_tables_are_those_of_latest_json():
    result = json.loads((run.RESULTS / "latest.json").read_text())
    page = tables.DOCS.read_text()
    assert tables.current(page) == tables.section(result, run.TARGETS)


def test_issue_targets_are_formed_from_the_figures_they_name():
    fig = {"rk4_final_b1e5_steps_per_s": 8.0, "numba_fastmath_final_b1e5_steps_per_s": 10.0,
           "rk4_stored_b1e5_steps_per_s": 6.0, "numba_fastmath_stored_b1e5_steps_per_s": 5.0,
           "interleaved_rk4_b1e5_generic_s": 2.0, "interleaved_rk4_b1e5_fast_trig_s": 1.8,
           "api_rk4_b1e4_steps_per_s": 3.0, "command_rk4_b1e4_steps_per_s": 4.0,
           "driver_trapezoidal_b1e4_steps_per_s": 1.0, "driver_rk4_b1e4_steps_per_s": 5.0}
    ratios = run.ratios_of(fig)
    assert ratios["rk4_b1e5_vs_numba_fastmath_final"] == pytest.approx(0.8)
    assert ratios["rk4_b1e5_vs_numba_fastmath_stored"] == pytest.approx(1.2)
    assert ratios["generic_vs_fast_trig_b1e5"] == pytest.approx(0.9)
    assert ratios["api_vs_command_rk4_b1e4"] == pytest.approx(0.75)
    assert ratios["trapezoidal_b1e4_vs_rk4_per_step"] == pytest.approx(0.2)
    # Every target that is a ratio is one run.py forms (the others are figures).
    assert {t for t in run.TARGETS if "_vs_" in t} <= set(ratios)
    assert tables.met(0.8, (">=", 0.8)) == "yes" and tables.met(20.5, ("<=", 20.0)) == "no"


def test_make_runs_warm_check_reads_the_tuned_choice_and_counts_new_cache_entries(tmp_path):
    """bench_make_run's warm-run check: the (method, h) each run's tuned.toml records, equal
    only where both are; the entries a run adds to the compilation cache folder."""
    from stepzoo.bench.perf.bench_make_run import _programs, tuned_choice
    for side, method in (("cold", "heun"), ("warm", "midpoint"), ("again", "heun")):
        (tmp_path / side).mkdir()
        (tmp_path / side / "tuned.toml").write_text(
            f'# written by stepzoo tune\nmethod = "{method}"\nh = 0.012578616352201259\n'
            'why = "a tie"\n')
    assert tuned_choice(tmp_path / "cold") == ("heun", 0.012578616352201259)
    assert tuned_choice(tmp_path / "cold") != tuned_choice(tmp_path / "warm")
    assert tuned_choice(tmp_path / "cold") == tuned_choice(tmp_path / "again")
    cache = tmp_path / "cache"
    assert _programs(cache) == 0
    cache.mkdir()
    for name in ("jit__batch-1", "jit__batch-2", "jit_run-3"):
        (cache / name).write_bytes(b"x")
    assert _programs(cache) == 3
    # A warm run that tuned another choice is named as worse; more new programs too.
    assert run.higher_is_better("make_run_warm_same_tuned")
    assert not run.higher_is_better("make_run_warm_new_programs")
