"""[newton] in sweep configs: the implicit methods' Newton tolerances are a sweep setting.
Where the default tolerance is a floor above a method's own error (radau_iia5 on Robertson at
coarse steps), the config's tighter one takes the error down to the method's; a suite merges
the table key by key; explicit and Rosenbrock methods are the zoo's own (no new compilation)."""
import tomllib

import numpy as np
import pytest

from stepzoo.bench.sweep import suite as suite_mod
from stepzoo.bench.sweep.config import Newton, validate
from stepzoo.integrators import METHODS, integrate

# Robertson at t = 40 s from (1, 0, 0): SciPy's Radau at rtol 1e-13, atol 1e-18 on the
# equations in NumPy with their Jacobian (at rtol 1e-12 it agrees within 1e-15; LSODA and
# BDF at 1e-13 within 1e-12, scaled: far below the errors compared here).
ROBERTSON_40 = np.array([0.7158270687194066, 9.185534764557795e-06, 0.28416374574582987])
SUITE = """
methods = ["rk4", "ros2", "radau_iia5", "bdf4"]
[newton]
rtol = 1e-12
[[problem]]
model = "robertson"
horizon = 40.0
steps.h = [0.625]
error = { scales = [1.0, 1e-4, 1.0], estimate = "final" }
newton = { atol = 1e-14 }
[[problem]]
model = "detest_a1"
steps.h = [0.5]
newton = { rtol = 1e-10 }
"""


@pytest.fixture(scope="module")
def problems(tmp_path_factory):
    path = tmp_path_factory.mktemp("newton") / "suite.toml"
    path.write_text(SUITE)
    return suite_mod.load(path).problems


def test_a_suite_merges_newton_key_by_key_and_the_sha256_follows_the_options(problems):
    (_, rob, rob_raw), (_, a1, a1_raw) = problems
    assert rob.newton == Newton(atol=1e-14, rtol=1e-12)
    assert rob.newton_options == dict(rtol=1e-12, atol=1e-14, res_tol=1.0, max_iter=10,
                                      max_iter_full=40)     # the manifest's "newton"
    # rtol = 1e-10 is NewtonOptions' default: the same results, so the same sha256 as no table.
    assert a1.newton == Newton()
    raw = tomllib.loads(suite_mod._toml(a1_raw))
    del raw["newton"]
    assert validate(raw, "a1").sha256 == a1.sha256
    # The problem's config copy (its folder's config.toml) reads back to the same sweep.
    assert validate(tomllib.loads(suite_mod._toml(rob_raw)), "copy").sha256 == rob.sha256
    raw = tomllib.loads(suite_mod._toml(rob_raw))
    raw["newton"]["atol"] = 1e-13
    assert validate(raw, "other").sha256 != rob.sha256
    radau = rob.method("radau_iia5")
    assert radau is rob.method("radau_iia5")          # one Method: one compilation
    assert (radau.newton.rtol, radau.newton.atol) == (1e-12, 1e-14)
    assert rob.method("bdf4").starter.newton == radau.newton
    for name in ("rk4", "ros2"):                      # no Newton solve: the zoo's own Method
        assert rob.method(name) is METHODS[name]
        assert METHODS[name].with_newton(atol=1e-14) is METHODS[name]
    assert a1.method("radau_iia5") is METHODS["radau_iia5"]


def test_tight_newton_options_take_radau_iia5_below_the_default_floor(problems):
    """Robertson at h = 0.625 s (64 steps to t = 40 s), end-point error in the config's norm:
    with the config's 1e-12 / 1e-14 it is the method's own (4.5e-10, the same at 1e-14 / 1e-14
    and 1e-14 / 1e-18). With the default solve tolerances (1e-10) it was the solves' (8.7e-9)
    until the Jacobians were kept across steps: the kept iteration matrix's solves now stop
    at the method's own error too, within 10% of it."""
    (_, rob, _), _ = problems
    x0, u, p = rob.spec.arrays(rob.points)
    p = {k: float(v[0]) for k, v in p.items()}
    n = round(40.0 / rob.hs[0])
    err = {}
    for label, meth in (("default", METHODS["radau_iia5"]), ("config", rob.method("radau_iia5"))):
        tr = integrate(meth, rob.spec.rhs, x0[0], u[0], p, rob.hs[0], n)
        assert bool(tr.converged)
        err[label] = float(rob.spec.scaled(np.asarray(tr.x)[-1] - ROBERTSON_40))
    # The method's own error: what tighter solves give too (measured, 4.52e-10 at both).
    assert err["config"] == pytest.approx(4.52e-10, rel=0.02)
    assert err["default"] == pytest.approx(err["config"], rel=0.1)
