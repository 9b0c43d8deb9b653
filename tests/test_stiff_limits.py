"""Stability limits measured where they happen, on stiff saturating models (issue 33): the
wheel models of dynamics/wheel.py against an independent onset search in plain NumPy (its
own model code, its own Runge-Kutta steps, SciPy's Radau for the truth) and the exact
stability polynomials; a point whose eigenmodes cancel in the error norm is not unstable at
every step; a run past the stability horizon decides nothing."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from stepzoo.bench.sweep import engine as sweep
from stepzoo.bench.sweep import config as sweep_config
from stepzoo.bench.sweep.block import Block
from stepzoo.bench.sweep.runs.stability_runs import directions, state_scales

G = 9.81
P = dict(m=400.0, J=1.2, R=0.31, B=10.0, C=1.9, D=1.0, E=0.97, v_min=1.0)
# Explicit RK tableaus written out here (A, b), not stepzoo's; any 3-stage third-order
# method has rk3's stability polynomial.
TABLEAUS = {
    "euler": ([[0.0]], [1.0]),
    "heun": ([[0, 0], [1, 0]], [0.5, 0.5]),
    "rk3": ([[0, 0, 0], [0.5, 0, 0], [-1, 2, 0]], [1 / 6, 2 / 3, 1 / 6]),
    "rk4": ([[0, 0, 0, 0], [0.5, 0, 0, 0], [0, 0.5, 0, 0], [0, 0, 1, 0]],
            [1 / 6, 1 / 3, 1 / 3, 1 / 6]),
}
# Stability polynomials: the Taylor polynomial of e^z of the method's order (s = p <= 4).
ORDER = {"euler": 1, "heun": 2, "rk3": 3, "rk4": 4}
GROWTH = 100.0


def tyre_force(kappa):
    """Pacejka's magic formula at slip kappa, times the quarter car's load [N]."""
    Bk = P["B"] * kappa
    return P["m"] * G * P["D"] * np.sin(P["C"] * np.arctan(Bk - P["E"] * (Bk - np.arctan(Bk))))


def quarter_car(x, T):
    """The quarter car in NumPy (wheel dynamics in slip velocity)."""
    _, v, slip = x
    fx = tyre_force(slip / max(v, P["v_min"]))
    dv = fx / P["m"]
    return np.array([v, dv, P["R"] * (T - P["R"] * fx) / P["J"] - dv])


def quarter_car_relax(x, T):
    """The quarter car with transient slip in NumPy: sigma dkappa_t/dt = v_slip - v kappa_t."""
    _, v, slip, kappa = x
    fx = tyre_force(kappa)
    dv = fx / P["m"]
    return np.array([v, dv, P["R"] * (T - P["R"] * fx) / P["J"] - dv,
                     (slip - max(v, P["v_min"]) * kappa) / 0.25])


def rk_run(name, f, x0, h, n):
    A, b = (np.array(a, float) for a in TABLEAUS[name])
    xs = [np.array(x0, float)]
    with np.errstate(all="ignore"):
        for _ in range(n):
            x, K = xs[-1], []
            for i in range(len(b)):
                K.append(f(x + h * sum(A[i, j] * K[j] for j in range(i))))
            xs.append(x + h * sum(bi * ki for bi, ki in zip(b, K)))
    return np.array(xs)


def real_axis_limit(order):
    """|lambda| h where the stability polynomial sum z^k/k! leaves |P| <= 1 on the negative
    real axis: its largest real root of P(z) = -1 (or +1), found by numpy.roots."""
    from math import factorial
    c = [1 / factorial(k) for k in range(order + 1)][::-1]
    roots = []
    for rhs in (-1.0, 1.0):
        r = np.roots(np.array(c) - np.r_[np.zeros(order), rhs])
        roots += [-z.real for z in r if abs(z.imag) < 1e-9 and z.real < -1e-9]
    return min(roots)


def onset(name, x0, T, horizon, h_pred, model=quarter_car):
    """The smallest multiple c of h_pred (0.5 to 8, 2% apart) where a perturbation of one
    state (1e-6 of its scale), run by the method, grows GROWTH times more than the same
    perturbation in SciPy's Radau solution; per state alone, the worst kept."""
    f = lambda x: model(x, T)
    ts = np.linspace(0, horizon, 51)
    ref = lambda y0: solve_ivp(lambda t, x: f(x), (0, horizon), y0, method="Radau", t_eval=ts,
                               rtol=1e-10, atol=1e-12).y.T
    base_ref = ref(x0)
    scale = np.maximum(np.abs(base_ref).max(axis=0), 1.0)
    d = len(x0)
    dirs = [1e-6 * scale[i] * np.eye(d)[i] for i in range(d)]
    allow = [np.fmax.accumulate(np.max(np.abs(ref(x0 + d) - base_ref) / scale, axis=1)
                                / 1e-6) for d in dirs]
    for c in 0.5 * 1.02 ** np.arange(141):
        h = c * h_pred
        n = int(np.ceil(horizon / h - 1e-9))
        base = rk_run(name, f, x0, h, n)
        for d, a in zip(dirs, allow):
            dev = np.max(np.abs(rk_run(name, f, x0 + d, h, n) - base) / scale, axis=1) / 1e-6
            slot = np.minimum(np.searchsorted(ts, h * np.arange(n + 1)), len(ts) - 1)
            if not np.all(dev <= GROWTH * np.fmax(1.0, a[slot])):
                return h
    return np.inf


WHEEL = """
name = "wheel-test"
model = "quarter_car"
horizon = 0.5
methods = ["euler", "heun", "rk3", "rk4"]
envelope = {{ v = [10.0, 30.0], T = [-800.0, 0.0] }}
error = {{ states = ["s"] }}
steps = {{ h = {{ min = 0.0005, max = 0.05, num = 4 }} }}
timing = {{ rounds = 1 }}
stability = {{ rule = "{rule}" }}
"""


@pytest.fixture(scope="module")
def wheel_limits():
    import tomllib
    cfg = sweep_config.validate(tomllib.loads(WHEEL.format(rule="modes")), "wheel-test")
    cache = {}
    tables = [sweep.compute_chunk(cfg, c, cache) for c in sweep.chunk_ids(cfg)]
    import pandas as pd
    return cfg, pd.concat([t["limits"] for t in tables if "limits" in t], ignore_index=True)


def test_predicted_limit_is_the_exact_stability_polynomials_root_at_free_rolling(wheel_limits):
    """Free rolling: the wheel mode is -(R^2/J + 1/m) Fz B C D / v, constant in time."""
    _, lim = wheel_limits
    free = lim[lim["T"] == 0.0]
    for _, row in free.iterrows():
        lam = (P["R"] ** 2 / P["J"] + 1 / P["m"]) * P["m"] * G * P["B"] * P["C"] * P["D"] \
            / row["v"]
        assert row["h_pred"] == pytest.approx(real_axis_limit(ORDER[row["method"]]) / lam,
                                              rel=1e-6)


def test_measured_limit_lies_within_the_independent_onset_or_says_why(wheel_limits):
    """Every explicit method at every point: h_meas within [0.85, 1.3] x the onset, or its
    limit_note says why; free rolling (the binding mode as fast all along) within. Where
    the onset search finds none (up to 8 h_pred) and the sweep nothing failing up to the
    stability horizon (which holds that range), the two agree."""
    cfg, lim = wheel_limits
    for _, row in lim.iterrows():
        x0 = np.array([0.0, row["v"], 0.0])
        h_on = onset(row["method"], x0, row["T"], cfg.horizon, row["h_pred"])
        within = 0.85 <= row["h_meas"] / h_on <= 1.3 or (
            np.isinf(h_on) and np.isinf(row["h_meas"]) and row["h_probe_max"] >= 8 * row["h_pred"])
        said = row["limit_note"] != "agrees" and row["unstable_state"] == "v_slip"
        assert within or said, (row["method"], row["v"], row["T"], row["h_meas"], h_on)
        assert within or row["T"] != 0.0, (row["method"], row["v"], row["h_meas"], h_on)


CANCEL = """
name = "cancel"
model = "two_axle"
horizon = 0.5
methods = ["euler", "backward_euler"]
envelope = {{ v = [20.0], v_slip_f = [-1.0], v_slip_r = [-1.0] }}
error = {{ states = ["s"] }}
steps = {{ h = {{ min = 0.0005, max = 0.05, num = 4 }} }}
timing = {{ rounds = 1 }}
stability = {{ rule = "{rule}" }}
"""


def test_a_point_whose_modes_cancel_in_the_error_norm_is_measured_in_every_state():
    """Both wheels slipping alike: the two wheel modes' position parts cancel, so the summed
    perturbation of the "blowup" rule holds the position alone and sees no wheel mode (its
    limit: nothing failed). Each mode alone, in every state, measures a finite explicit
    limit that says why it is above the prediction, and the A-stable method stays stable."""
    import tomllib

    import pandas as pd
    from stepzoo.bench.sweep.runs.stability_runs import perturbation
    old = sweep_config.validate(tomllib.loads(CANCEL.format(rule="blowup")), "cancel")
    work = Block(old, 0, {})
    delta = perturbation(old.spec, work.along().jac[:, 0], old.stability.perturbation)
    assert np.count_nonzero(delta[0]) == 1 and delta[0, 0] != 0      # position only
    cfg = old.changed(stability={"rule": "modes"})
    cache = {}
    lim = pd.concat([sweep.compute_chunk(cfg, c, cache)["limits"]
                     for c in sweep.chunk_ids(cfg) if not c.startswith("reference")])
    euler = lim[lim["method"] == "euler"].iloc[0]
    assert 1.0 <= euler["ratio"] <= 2.0 and euler["unstable_state"].startswith("v_slip")
    assert euler["limit_note"].startswith("measured above the prediction")
    implicit = lim[lim["method"] == "backward_euler"].iloc[0]
    assert np.isinf(implicit["h_meas"]) and implicit["limit_note"] == "agrees"


def test_directions_are_single_modes_sized_in_every_state():
    """No direction can cancel: each is one eigenmode (or a seeded random direction), or one
    state alone, whose largest state, over its own scale, is the perturbation."""
    jac = np.array([[[0.0, 1.0, 0.0], [0.0, -5.0, 4.0], [0.0, 300.0, -600.0]]])
    scales = np.array([[10.0, 20.0, 0.5]])
    d = directions(jac, scales, 1e-6, [0])
    np.testing.assert_allclose(np.max(np.abs(d) / scales[:, None], axis=-1), 1e-6)
    w, V = np.linalg.eig(jac[0])
    fast = V[:, np.argmin(w.real)]
    assert abs(abs(np.dot(d[0, 0], fast)) / np.linalg.norm(d[0, 0]) - 1) < 1e-12
    np.testing.assert_array_equal(directions(jac, scales, 1e-6, [0]), d)     # seeded
    np.testing.assert_allclose(d[0, 3:], 1e-6 * np.diag(scales[0]))
    assert state_scales(sweep_config.validate(__import__("tomllib").loads(
        CANCEL.format(rule="modes")), "c").spec, np.zeros((1, 3, 4)))[0].tolist() == \
        [1.0, 1.0, 1.0, 1.0]


class _Runs:
    """A runner that returns given trajectories: the unperturbed run `base` (n+1,) of one
    state and, for a perturbed one, base + `dev` (n+1,); `failed_from` NaNs every row from
    that step on with converged False (a failed Newton solve, as the driver leaves it)."""

    def __init__(self, base, dev, failed_from=None):
        from stepzoo.bench.timing.chunk_stopwatch import Stopwatch
        self.base, self.dev, self.failed_from = base, dev, failed_from
        self.max_steps, self.watch = len(base) - 1, Stopwatch()

    def __call__(self, meth, x0, u, p, h, n):
        from stepzoo.bench.sweep.runs.method_runs import Run
        x = np.where(x0[:, :1] != 0, self.base + self.dev, self.base)[:, : n + 1, None]
        conv = np.ones(len(x0), bool)
        if self.failed_from is not None:
            x[:, self.failed_from:] = np.nan
            conv[:] = False
        return Run(x, np.zeros(len(x0)), conv, 0.0)


def _judge(dev, ref_growth=1.0, failed_from=None, horizon=1.0, h=0.01):
    """The "modes" rule's verdict on one lane whose perturbed run deviates by dev (steps,)."""
    from types import SimpleNamespace

    from stepzoo.bench.sweep.points import Points
    from stepzoo.bench.sweep.runs.stability_runs import ModalRuns
    n = len(dev) - 1
    runner = _Runs(np.ones(n + 1), np.asarray(dev, float), failed_from)
    pts = Points((0,), (0,), np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 0)), {}, ("y",))
    runs = ModalRuns(runner, pts, np.full((1, 1, 1), 1e-6), np.ones((1, 1)),
                     np.linspace(0, horizon, 11), np.full((1, 1, 11), ref_growth), horizon,
                     GROWTH)
    out, diag = runs.judge(SimpleNamespace(solves=False), np.array([0]), np.array([h]))
    return bool(out.stable[0]), bool(out.converged[0]), float(diag.growth_ratio[0])


def test_a_bounded_chatter_is_unstable_and_a_growth_the_reference_shares_is_not():
    k = np.arange(201)
    chatter = np.clip(1e-6 * (-3.0) ** k, -1e-2, 1e-2)      # saturates, never blows up
    assert _judge(chatter)[0] is False
    decaying = 1e-6 * 0.5 ** k
    assert _judge(decaying)[0] is True
    physical = 1e-6 * 1.05 ** k                             # 1.7e4-fold over the horizon
    assert _judge(physical, ref_growth=1e5)[0] is True
    assert _judge(physical, ref_growth=1.0)[0] is False


def test_what_happens_past_the_stability_horizon_decides_nothing():
    """Runs of 0.5 s at h = 0.01 s: a blow-up and a failed solve after step 50 count for
    nothing; a failed solve inside the horizon makes the step not stable."""
    k = np.arange(201)
    late = np.where(k > 60, 1e3, 1e-6)
    assert _judge(late, horizon=0.5)[0] is True
    assert _judge(late, horizon=2.0)[0] is False
    assert _judge(np.full(201, 1e-6), failed_from=80, horizon=0.5)[:2] == (True, True)
    assert _judge(np.full(201, 1e-6), failed_from=30, horizon=0.5)[:2] == (False, False)


def test_a_stability_horizon_without_the_modes_rule_is_one_clear_line():
    import tomllib

    from stepzoo.errors import UsageError
    raw = tomllib.loads(CANCEL.format(rule="blowup"))
    raw["stability"]["horizon"] = 0.3
    with pytest.raises(UsageError, match="stability.horizon is the length of the \"modes\""):
        sweep_config.validate(raw, "c")
    raw["stability"]["rule"] = "modes"
    assert sweep_config.validate(raw, "c").stability_horizon == 0.3


def ray_limit(order, lam):
    """The largest h with |P(h lambda)| <= 1 on [0, h] for the Taylor polynomial P of e^z of
    the method's order: a dense scan of the ray, refined by bisection."""
    from math import factorial
    P_abs = lambda h: abs(sum((h * lam) ** k / factorial(k) for k in range(order + 1)))
    hs = np.linspace(0, 10 / abs(lam), 200001)[1:]
    out = np.array([P_abs(h) for h in hs]) > 1 + 1e-12
    lo, hi = hs[np.argmax(out) - 1], hs[np.argmax(out)]
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if P_abs(mid) <= 1 else (lo, mid)
    return lo


RELAX = """
name = "relax-test"
model = "quarter_car_relax"
horizon = 0.5
methods = ["heun", "rk4"]
envelope = { v = [3.0, 5.0], T = [0.0] }
error = { states = ["s"] }
steps = { h = { min = 0.001, max = 0.05, num = 3 } }
timing = { rounds = 1 }
stability = { rule = "modes" }
"""


def test_a_lightly_damped_mode_is_predicted_on_its_ray_and_measured_at_its_onset():
    """The wheel-tyre mode of quarter_car_relax rolling freely, damping ratio v / 78 (0.038
    at 3 m/s): h_pred is where |P(h lambda)| leaves 1 on the mode's ray (lambda from a
    finite-difference Jacobian of the NumPy model), and h_meas lies within [0.85, 1.3] of
    the independent onset."""
    import tomllib

    import pandas as pd
    cfg = sweep_config.validate(tomllib.loads(RELAX), "relax-test")
    cache = {}
    lim = pd.concat([sweep.compute_chunk(cfg, c, cache)["limits"]
                     for c in sweep.chunk_ids(cfg) if not c.startswith("reference")])
    for _, row in lim.iterrows():
        x0 = np.array([0.0, row["v"], 0.0, 0.0])
        eps = 1e-7
        J = np.column_stack([(quarter_car_relax(x0 + eps * e, 0.0)
                              - quarter_car_relax(x0 - eps * e, 0.0)) / (2 * eps)
                             for e in np.eye(4)])
        lam = max(np.linalg.eigvals(J), key=abs)
        assert abs(lam.imag) > 5 * abs(lam.real)                       # lightly damped
        assert row["h_pred"] == pytest.approx(ray_limit(ORDER[row["method"]], lam), rel=1e-5)
        h_on = onset(row["method"], x0, 0.0, cfg.horizon, row["h_pred"],
                     model=quarter_car_relax)
        assert 0.85 <= row["h_meas"] / h_on <= 1.3, (row["method"], row["v"], row["h_meas"],
                                                     h_on)
