"""The report's page stays small: Figure 7's interactive tree is single precision."""
import numpy as np

from stepzoo.reports import figure_data, interactive
from stepzoo.reports.load import load_plans
from helpers import write_plan


def test_the_interactive_tree_is_every_edge_in_single_precision(tmp_path):
    write_plan(tmp_path)
    fig = interactive.draw(figure_data.plans(load_plans(tmp_path)))[0]
    tree = next(t for t in fig.data if t.name == "tree")
    x, y = np.asarray(tree.x), np.asarray(tree.y)
    assert x.dtype == np.float32 and y.dtype == np.float32
    want = np.array([2.0, 4.0, 6.0, np.nan, 2.0, 4.0, np.nan])
    np.testing.assert_array_equal(x, want.astype(np.float32))
    assert fig.to_json().count('"dtype":"f4"') == 2
