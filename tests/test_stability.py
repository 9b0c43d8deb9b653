"""Stability intervals by two routes, against published values; the predicted largest stable
step against a measured blow-up."""
import json
import math

import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.cli import main as stepzoo
from stepzoo.integrators import METHODS, integrate, method
from stepzoo.integrators.methods import Method, _rk
from stepzoo.integrators.multistep import bdf
from stepzoo.integrators.stability import (a_alpha, a_stable, amplification_empirical,
                                           max_stable_step, ray_exit, region_grid,
                                           stability_intervals)
from helpers import retrying

pytestmark = pytest.mark.slow      # run first: see tests/conftest.py

# Published (real, imaginary) intervals: Hairer & Wanner II; Butcher 2016; nodepy; the exact
# polynomial |R(iy)|^2 - 1 for Heun, RK6 (leading term +y^8/786: tangent, interval 0) and
# DOPRI5 (first positive root 0.99719); for BDF3-5 the first crossing of the imaginary axis
# by the root locus rho/sigma(e^{i theta}) away from 0 (BDF3 and BDF4's locus starts into
# Re z < 0, so their interval is 0). None = unbounded (A-stable, and BDF3-5 on the real axis).
PUBLISHED = {
    "euler": (2.0, 0.0), "heun": (2.0, 0.0), "midpoint": (2.0, 0.0),
    "rk3": (2.5127, 1.7321), "rk4": (2.7853, 2.8284), "rk6": (2.8561, 0.0),
    "dopri5": (3.3066, 0.9972), "ab2": (1.0, 0.0), "ab3": (0.5455, 0.7236),
    "ab4": (0.3, 0.4300), "am3": (6.0, 0.0), "am4": (3.0, 0.0),
    "backward_euler": (None, None), "trapezoidal": (None, None),
    "gauss_legendre4": (None, None), "radau_iia3": (None, None), "bdf2": (None, None),
    "radau_iia5": (None, None), "kvaerno3": (None, None),
    "ros2": (None, None), "ros3p": (None, None), "rodas3": (None, None),
    "bdf3": (None, 0.0), "bdf4": (None, 0.0), "bdf5": (None, 0.7108),
}


def test_every_method_has_a_published_interval():
    assert set(PUBLISHED) == set(METHODS)


@pytest.fixture(scope="module")
def methods_json():
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert stepzoo(["methods", "--format", "json"]) == 0
    return {row["name"]: row for row in json.loads(buf.getvalue())}


@pytest.mark.parametrize("name", list(PUBLISHED))
def test_methods_json_gives_published_intervals_by_both_routes(methods_json, name):
    real, imag = PUBLISHED[name]
    row = methods_json[name]
    for got, want in ((row["real_interval"], real), (row["imag_interval"], imag)):
        if want is None:
            assert got is None
        else:
            assert round(got, 3) == round(want, 3), (name, got, want)
    emp = stability_intervals(METHODS[name], "empirical")
    theory = stability_intervals(METHODS[name], "theory")
    for e, t in zip(emp, theory):
        assert (math.isinf(e) and math.isinf(t)) or round(e, 3) == round(t, 3)


@pytest.mark.parametrize("name", ["heun", "bdf2"])
def test_measured_amplification_of_any_length_runs_one_compiled_program(name):
    """Points in any number above one go through the same program in blocks of SCAN_CHUNK
    (an implicit method's program takes seconds to compile), and each value is the one the
    points give alone: padding and blocking change nothing."""
    from stepzoo.integrators import stability
    z = -np.geomspace(1e-3, 1e3, 1500) * np.exp(0.3j)
    amp = stability._empirical(METHODS[name])
    before = amp._cache_size()
    blocks = [amplification_empirical(METHODS[name], z[:n]) for n in (2, 513, 1500)]
    assert amp._cache_size() - before <= 1
    alone = np.array([amplification_empirical(METHODS[name], z[i:i + 1])[0]
                      for i in (0, 1, 511, 512, 1499)])
    np.testing.assert_array_equal(blocks[2][[0, 1, 511, 512, 1499]], alone)
    np.testing.assert_array_equal(blocks[1], blocks[2][:513])


def test_a_stable_methods_have_no_step_limit():
    for name in ("backward_euler", "trapezoidal", "gauss_legendre4", "radau_iia3", "bdf2"):
        assert max_stable_step(method(name), [-1e6 + 1e5j, -3.0]) == math.inf


def test_max_stable_step_on_the_real_axis_is_interval_over_lambda():
    assert max_stable_step(method("rk4"), [-10.0]) == pytest.approx(0.27853, abs=1e-5)
    assert max_stable_step(method("euler"), [-4.0, -1.0, 0.0]) == pytest.approx(0.5)


@pytest.mark.parametrize("name", ["euler", "rk4", "ab4"])
def test_measured_blow_up_step_matches_prediction_on_a_linear_system(name):
    """y' = M y with eigenvalues -5 +- 8i: stable at 0.98 h_max, growing at 1.02 h_max."""
    mat = jnp.array([[-5.0, -8.0], [8.0, -5.0]])
    f = lambda t, y, u, p: mat @ y
    h_max = max_stable_step(method(name), [-5 + 8j, -5 - 8j])
    y0 = jnp.array([1.0, 0.0])
    for factor, grows in ((0.98, False), (1.02, True)):
        tr = integrate(method(name), f, y0, jnp.zeros(1), {}, factor * h_max, 3000)
        final = float(jnp.linalg.norm(tr.x[-1]))
        assert (final > 1.0) == grows, (name, factor, final)


def test_region_grid_marks_the_origin_side_stable():
    x, y, amp = region_grid(method("rk4"), n=81)
    assert amp[40, np.argmin(np.abs(x + 1.0))] < 1.0       # z = -1 is inside
    assert amp[40, -1] > 1.0                                  # z = +2 is outside


def test_region_grid_through_bdf2_s_pole_is_unstable_there_not_an_error():
    """z = 1/beta_2 = 1.5 zeroes BDF2's leading coefficient: a root at infinity. A report's
    grid ends there (re up to 1.5, im through 0)."""
    x, y, amp = region_grid(method("bdf2"), re=(-4.0, 1.5), im=(-1.0, 1.0), n=81)
    assert np.isinf(amp[40, -1]) and np.isfinite(amp).sum() == amp.size - 1
    assert amp[40, 0] < 1.0


def test_stability_command_json(capsys):
    assert stepzoo(["stability", "--vx", "15", "--delta", "0.785", "--format", "json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["eigenvalues"]) == 2 and out["methods"]["trapezoidal"]["max_stable_step"] is None
    re = out["eigenvalues"][0][0]
    assert re < 0 and out["methods"]["euler"]["max_stable_step"] > 0


# (A-stable, L-stable, |R(-inf)|): Hairer & Wanner II, IV.3 and V.1; am3's and am4's are the
# largest roots of sigma, 5z^2 + 8z - 1 and 9z^3 + 19z^2 - 5z + 1; ROS2, ROS3P and Rodas3:
# Verwer et al. 1999, Lang & Verwer 2001 (|R(-inf)| = 0.73), Sandu et al. 1997.
STIFF = {"backward_euler": (True, True, 0.0), "trapezoidal": (True, False, 1.0),
         "gauss_legendre4": (True, False, 1.0), "radau_iia3": (True, True, 0.0),
         "radau_iia5": (True, True, 0.0), "kvaerno3": (True, True, 0.0),
         "bdf2": (True, True, 0.0), "bdf3": (False, False, 0.0), "bdf4": (False, False, 0.0),
         "bdf5": (False, False, 0.0), "ros2": (True, True, 0.0),
         "ros3p": (True, False, math.sqrt(3) - 1), "rodas3": (True, True, 0.0),
         "am3": (False, False, (8 + math.sqrt(84)) / 10),
         "am4": (False, False, 2.36579), "rk4": (False, False, None), "ab2": (False, False, None)}


@pytest.mark.parametrize("name", list(STIFF))
def test_methods_json_gives_a_and_l_stability_and_stiff_decay(methods_json, name):
    a, l_stable, decay = STIFF[name]
    row = methods_json[name]
    assert (row["a_stable"], row["l_stable"]) == (a, l_stable)
    assert (row["stiff_decay"] is None) if decay is None else \
        row["stiff_decay"] == pytest.approx(decay, abs=1e-4)


@pytest.mark.parametrize("name", [n for n in METHODS if METHODS[n].implicit])
def test_a_and_l_stability_hold_numerically_with_the_method_s_own_step(methods_json, name):
    """|amplification(iy)| <= 1 on a dense imaginary grid, and small at -1e6, measured by
    stepping y' = z y: the flags agree with what the step does."""
    y = np.concatenate([np.linspace(0.0, 50.0, 2001), np.geomspace(50.0, 1e6, 400)])
    # One call, in the blocks that the intervals' scans compiled: a point alone is another
    # program, and a point's value does not depend on its block's other points.
    amp = amplification_empirical(METHODS[name], np.r_[1j * y, -1e6])
    on_axis, far = amp[:-1], amp[-1]
    row = methods_json[name]
    assert row["a_stable"] == bool(np.all(on_axis <= 1 + 1e-12) and far <= 1 + 1e-12)
    if row["l_stable"]:
        assert far <= 1e-3      # BDF2: roots shrink like |z|^(-1/2)
    else:
        assert far >= 0.5 or not row["a_stable"]


# A(alpha) angles [deg] of BDF3-6, Hairer & Wanner II, V.2, Table 2.1.
A_ALPHA = {"bdf3": 86.03, "bdf4": 73.35, "bdf5": 51.84}
BDF6 = 17.84


def _sector_ray(degrees):
    """The ray angle [rad] of z at `degrees` from the negative real axis."""
    return float(np.pi - np.radians(degrees))


@pytest.mark.parametrize("name", list(A_ALPHA))
def test_a_alpha_of_bdf_by_root_locus_is_published_and_the_own_steps_agree(methods_json,
                                                                             name):
    """The root locus gives Hairer-Wanner's angle to 0.05 deg; the method's own step keeps
    the ray 0.05 deg inside the sector stable out to |z| = 1e8, and leaves on the ray 0.05
    deg outside it."""
    alpha = methods_json[name]["a_alpha_deg"]
    assert alpha == pytest.approx(A_ALPHA[name], abs=0.05)
    m = METHODS[name]
    assert math.isinf(ray_exit(m, _sector_ray(alpha - 0.05), "empirical"))
    assert math.isfinite(ray_exit(m, _sector_ray(alpha + 0.05), "empirical"))


def test_a_alpha_of_bdf6_and_of_the_other_methods():
    assert a_alpha(Method("bdf6", "BDF", 6, bdf(6), "")) == pytest.approx(BDF6, abs=0.05)
    for name, m in METHODS.items():
        if name not in A_ALPHA:
            assert a_alpha(m) == (90.0 if a_stable(m) else None), name


def test_a_alpha_of_a_tableau_that_is_not_a_stable_by_its_rays():
    """A 2-stage DIRK (gamma = 0.3, order 1) whose R(z) = (1 + 0.4 z - 0.045 z^2) / (1 -
    0.3 z)^2 is bounded by 1 on the negative real axis but exceeds it on the imaginary
    axis near 0 (|R(iy)|^2 = 1 + 0.07 y^2 + O(y^4)): an angle below 90 deg, confirmed by its
    own step on rays 0.05 deg either side."""
    m = Method("dirk", "DIRK", 1, _rk([[0.3, 0.0], [0.33, 0.3]], [0.5, 0.5]), "")
    alpha = a_alpha(m)
    assert not a_stable(m) and 45.0 < alpha < 90.0
    assert math.isinf(ray_exit(m, _sector_ray(alpha - 0.05), "empirical"))
    assert math.isfinite(ray_exit(m, _sector_ray(alpha + 0.05), "empirical"))


@pytest.mark.parametrize("name", list(A_ALPHA))
def test_bdf_blows_up_just_past_the_predicted_step_beyond_its_sector_and_not_far_past(name):
    """y' = M y with eigenvalues 10 e^{+-i(pi - alpha - 2 deg)}, just outside the sector:
    stable at 0.98 h_max, growing at 1.02 h_max, and stable again at |h lambda| = 100, past
    the bounded set where BDF is unstable."""
    lam = 10.0 * np.exp(1j * _sector_ray(A_ALPHA[name] + 2.0))
    mat = jnp.array([[lam.real, -lam.imag], [lam.imag, lam.real]])
    f = lambda t, y, u, p: mat @ y
    h_max = max_stable_step(method(name), [lam, lam.conjugate()])
    y0 = jnp.array([1.0, 0.0])
    m = retrying(name)      # the simplified iteration fails at h = 10
    # Every h a NumPy float64, as h_max is: a Python float is weakly typed in JAX, so h = 10.0
    # was a second program to compile (seconds, for an implicit method), the same steps.
    for h, grows in ((0.98 * h_max, False), (1.02 * h_max, True), (np.float64(10.0), False)):
        tr = integrate(m, f, y0, None, None, h, 3000)
        assert bool(tr.converged)
        final = float(jnp.linalg.norm(tr.x[-1]))
        assert (final > 1.0) == grows, (name, h / h_max, final)
