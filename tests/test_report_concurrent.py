"""The report's figures drawn side by side give what drawing them one after another gives:
each job's result in the jobs' order, from worker processes where there are cores for them,
a job's error raised to the caller; and Figure 7's interactive tree is single precision."""
import os

import numpy as np
import pytest

from stepzoo.errors import UsageError
from stepzoo.reports import concurrent, interactive
from stepzoo.reports.load import load_plans
from test_report import write_plan


def _where(i):
    return i * i, os.getpid()


def test_drawing_yields_each_result_in_order_from_worker_processes():
    drawing = concurrent.Drawing([lambda i=i: _where(i) for i in range(5)])
    got = [r for r, took in drawing.results()]
    assert [v for v, _ in got] == [0, 1, 4, 9, 16]
    elsewhere = {pid for _, pid in got} - {os.getpid()}
    assert bool(elsewhere) == (concurrent.workers() >= 2)


def _bad():
    raise UsageError("disk full: give another --out")


def test_a_jobs_error_reaches_the_caller():
    drawing = concurrent.Drawing([lambda: 1, _bad, lambda: 3])
    with pytest.raises(UsageError, match="disk full"):
        list(drawing.results())


def test_the_interactive_tree_is_every_edge_in_single_precision(tmp_path):
    write_plan(tmp_path)
    fig = interactive.plans(load_plans(tmp_path))[0]
    tree = next(t for t in fig.data if t.name == "tree")
    x, y = np.asarray(tree.x), np.asarray(tree.y)
    assert x.dtype == np.float32 and y.dtype == np.float32
    want = np.array([2.0, 4.0, 6.0, np.nan, 2.0, 4.0, np.nan])
    np.testing.assert_array_equal(x, want.astype(np.float32))
    assert fig.to_json().count('"dtype":"f4"') == 2
