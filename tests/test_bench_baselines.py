"""`make bench` compares like with like: every RK4 baseline of the final-state regime ends
where stepzoo's rk4 ends, to round-off, so its ratio is of the same work; and the tables of
docs/benchmarks.md are those latest.json holds."""
import json

import numpy as np
import pytest

from stepzoo.bench.perf import baselines, run, tables
from stepzoo.bench.perf.workload import H_S, problem

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
