"""The suite's float comparisons survive rounding: a quantity that is zero in exact arithmetic
is rounding alone, which no relative tolerance bounds, so a comparison whose absolute tolerance
is zero fails on the last bit of another machine (issue 36: a stored -1.7956e-12 rad against a
fresh -1.7956e-12 rad at rtol 1e-9, atol 0). Checked over the source of every test module:
no comparison passes an absolute tolerance of zero, and the regression tests (those comparing
with stored records, tests/data/) give every comparison an absolute tolerance, as
np.testing.assert_allclose and math.isclose default to none."""
import ast
import re
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
# The comparisons and the name of their absolute tolerance; True: it defaults to zero.
COMPARISONS = {"assert_allclose": ("atol", True), "isclose": ("abs_tol", True),
               "allclose": ("atol", False), "approx": ("abs", False)}


def _constants(tree: ast.Module) -> dict[str, object]:
    """The module's names bound to literal numbers (`RTOL, ATOL = 1e-9, 1e-9` included)."""
    found = {}
    for node in tree.body:
        if not isinstance(node, ast.Assign):
            continue
        for target in node.targets:
            pairs = [(target, node.value)]
            if isinstance(target, ast.Tuple) and isinstance(node.value, ast.Tuple):
                pairs = list(zip(target.elts, node.value.elts))
            for name, value in pairs:
                if isinstance(name, ast.Name) and isinstance(value, ast.Constant):
                    found[name.id] = value.value
    return found


def _may_be_zero(node: ast.expr, constants: dict) -> bool:
    """Whether the tolerance expression `node` can be a literal zero (either branch of an if)."""
    if isinstance(node, ast.IfExp):
        return _may_be_zero(node.body, constants) or _may_be_zero(node.orelse, constants)
    if isinstance(node, ast.Name):
        return constants.get(node.id, 1) == 0
    return isinstance(node, ast.Constant) and node.value == 0


def rounding_traps(source: str, regression: bool) -> list[str]:
    """The comparisons in `source` that cannot survive rounding, as 'line: call': an
    absolute tolerance that may be zero, or (`regression`) one left to a default of zero."""
    tree = ast.parse(source)
    constants = _constants(tree)
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = getattr(node.func, "attr", getattr(node.func, "id", None))
        if name not in COMPARISONS:
            continue
        key, zero_default = COMPARISONS[name]
        given = {k.arg: k.value for k in node.keywords}
        if (key in given and _may_be_zero(given[key], constants)) or \
                (regression and zero_default and key not in given):
            found.append(f"{node.lineno}: {ast.unparse(node)[:80]}")
    return found


def _regression(path: Path) -> bool:
    """A module of regression tests: it reads records stored under tests/data/ (the word
    "regression" alone also names a fitted slope, or a table another test holds)."""
    return re.search(r'tests/data|"tests" / "data"', path.read_text()) is not None


@pytest.mark.parametrize("path", sorted(TESTS.glob("test_*.py")), ids=lambda p: p.name)
def test_no_comparison_lets_rounding_fail_it(path):
    found = rounding_traps(path.read_text(), _regression(path))
    assert not found, f"{path.name}: absolute tolerance zero at {found}"


def test_the_check_finds_the_comparisons_that_rounding_fails():
    """The comparisons of issue 36's failure and of the sweep's regression test before it,
    and none of their fixed forms."""
    traps = """import math
import numpy as np
OFF = 0.0
math.isclose(a, b, rel_tol=1e-9, abs_tol=0.0)
np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12 if err else OFF)
np.testing.assert_allclose(a, b, rtol=1e-6, equal_nan=True)
pytest.approx(a, abs=0)
"""
    assert [t.split(":")[0] for t in rounding_traps(traps, True)] == ["4", "5", "6", "7"]
    assert [t.split(":")[0] for t in rounding_traps(traps, False)] == ["4", "5", "7"]
    fixed = """import math
RTOL, ATOL = 1e-9, 1e-9
math.isclose(a, b, rel_tol=RTOL, abs_tol=ATOL)
np.testing.assert_allclose(a, b, rtol=1e-6, atol=ATOL)
np.allclose(a, b)
"""
    assert rounding_traps(fixed, True) == []
