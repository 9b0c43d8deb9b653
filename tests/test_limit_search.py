"""The limit search finds a known threshold: on a toy probe whose lanes are stable exactly
below their `limit`, the grid's bracket, the ladders and the narrowing end with the limit in
[h_meas, h_meas (1 + rel_tol)] wherever it lies (inside the grid, above it, below it, nowhere)
and whatever the prediction, with the cause of the failure above it; and it asks no probe
that cannot change that answer (counted: above the largest step worth one, past a point's
first failure on the h_pred ladder, a ladder for an unbounded prediction, a block's padding
lanes)."""
import math

import numpy as np
import pytest

from stepzoo.bench.sweep import limit_search
from stepzoo.bench.sweep.limit_search import Outcome, at_steps, bracket, candidates, measured_limit

HS = np.geomspace(0.001, 0.2, 5)
REL_TOL, H_PROBE_MAX = 1e-3, 2.0


class Threshold:
    """A probe whose lane b is stable exactly below limit[b] [s] (inf: always); above it the
    solver fails where `fails` says so. It records the steps of each call and counts calls of
    `slots` candidates."""

    def __init__(self, limit, slots=None, fails=None):
        self.limit = np.asarray(limit, float)
        self.fails = np.zeros(len(limit), bool) if fails is None else np.asarray(fails)
        self.slots, self.ran, self.calls = slots or len(limit), [], 0

    def __call__(self, lanes, h):
        self.ran.append(np.asarray(h))
        self.calls += -(-len(h) // self.slots)
        ok = np.asarray(h) < self.limit[lanes]
        return Outcome(ok, np.where(ok, np.nan, 1.0), ok | ~self.fails[lanes])


def _search(limit, pred, fails=None):
    probe = Threshold(limit, fails=fails)
    grid = at_steps(probe, np.arange(len(limit)), HS)
    return measured_limit(grid, probe, HS, np.asarray(pred, float), H_PROBE_MAX, REL_TOL,
                          len(limit)), probe


@pytest.mark.parametrize("off", [1.0, 0.9, math.inf, math.nan])
def test_a_known_threshold_is_found_to_the_narrowing_tolerance_wherever_it_lies(off):
    """Inside the grid, between its steps, above its largest step (the doubling ladder),
    below its smallest (the halving ladder): h_meas < limit <= h_meas (1 + rel_tol), with an
    exact, a 10% low, an unbounded or a missing prediction."""
    limit = np.array([0.0123, 0.05, 0.7, 1.5, 0.0004, 0.0001234])
    lim, _ = _search(limit, limit * off)
    assert np.all(lim.h_meas < limit) and np.all(limit <= lim.h_meas * (1 + REL_TOL) * (1 + 1e-9))
    assert list(lim.cause) == ["unstable"] * len(limit)


def test_no_failure_up_to_h_probe_max_is_an_unbounded_limit_and_none_stable_is_zero():
    lim, _ = _search([np.inf, 1e-9], [np.inf, 1.0])
    assert lim.h_meas[0] == np.inf and lim.cause[0] == "none"
    assert lim.h_meas[1] == 0.0 and lim.cause[1] == "unstable"


def test_a_failed_solve_above_the_limit_is_the_cause():
    lim, _ = _search([0.05, 0.05], [0.05, 0.05], fails=[True, False])
    assert list(lim.cause) == ["solver failed", "unstable"]
    assert np.all(lim.h_meas < 0.05) and np.all(0.05 <= lim.h_meas * (1 + REL_TOL) + 1e-15)


def test_the_grid_brackets_between_its_last_stable_step_and_its_first_failure():
    """A lane failing at the grid's first step, or at none, is left for the ladders (NaN)."""
    probe = Threshold([0.01, 0.0005, 1.0])
    br = bracket(at_steps(probe, np.arange(3), HS), HS)
    j = np.searchsorted(HS, 0.01)
    assert (br.lo[0], br.hi[0]) == (HS[j - 1], HS[j]) and br.cause[0] == "unstable"
    assert np.isnan(br.lo[1:]).all() and np.isnan(br.hi[1:]).all()


def test_an_unbounded_prediction_is_checked_by_one_probe_and_the_ladder_where_it_fails():
    """pred inf everywhere, grid stable everywhere: the lanes stable at h_probe_max are
    unbounded after that one call; the others, where the prediction is off, are bracketed
    by the doubling ladder and narrowed to rel_tol as before."""
    limit = np.array([np.inf, 0.7, 1.5, np.inf])
    probe = Threshold(limit)
    grid = Outcome(np.ones((4, 5), bool), np.full((4, 5), np.nan), np.ones((4, 5), bool))
    h_meas, cause = measured_limit(grid, probe, HS, np.full(4, np.inf), H_PROBE_MAX, REL_TOL, 4)
    assert np.isinf(h_meas[[0, 3]]).all() and list(cause[[0, 3]]) == ["none", "none"]
    assert np.all((h_meas[1:3] < limit[1:3]) & (h_meas[1:3] * 1.001 >= limit[1:3]))
    assert list(cause[1:3]) == ["unstable", "unstable"]
    first, ladder = probe.ran[0], probe.ran[1]
    assert np.all(first == 2.0) and np.all(ladder < 2.0 + 1e-12)   # only lanes 1, 2 climbed
    assert len(ladder) == 2 * len(np.unique(ladder))


@pytest.mark.parametrize("off", [1.0, 1.0004, 0.97, 1.2, math.nan])
def test_narrowing_brackets_each_limit_to_rel_tol_wherever_the_prediction_is(off):
    """From brackets of the grid's width (1.26), the limit ends within rel_tol above lo and
    at most hi, whether the prediction is exact, 0.04% or 3% off, outside the bracket, or
    missing; a prediction within rel_tol takes 2 calls, where bisection takes 8."""
    limit = np.geomspace(0.01, 0.5, 25)
    lo, hi = limit / 1.1, limit * 1.15
    probe = Threshold(limit)
    start = limit_search.Bracket(lo, hi, np.full(25, "unstable", object))
    lo, hi, _ = limit_search.narrow(start, probe, limit * off, 1e-3, 25)
    assert np.all(lo < limit) and np.all(hi >= limit) and np.all(hi / lo <= 1 + 1e-3 + 1e-12)
    assert np.array_equal(start.lo, limit / 1.1)            # the bracket given is not changed
    if off in (1.0, 1.0004):
        assert probe.calls == 2


def test_candidates_lie_strictly_inside_the_bracket():
    tau = math.log1p(REL_TOL)
    for guess in (math.nan, -2.0, -2.3, -1.7):
        for first in (True, False):
            c = candidates(-2.3, -1.7, guess, tau, 5, first, tau)
            assert len(c) and np.all((c > -2.3) & (c < -1.7)), (guess, first)


# ---- what the search does not probe (issue 35, item 3) -----------------------------------

def _ladder_search(limit, pred, top=H_PROBE_MAX):
    """The "modes" rule's search (with the predicted-limit ladder) of a Threshold probe, with
    `top` the largest step worth a probe; (h_meas, the probe)."""
    probe = Threshold(limit)
    grid = at_steps(probe, np.arange(len(limit)), HS)
    return measured_limit(grid, probe, HS, np.asarray(pred, float), top, REL_TOL,
                          len(limit), ladder=True).h_meas, probe


def test_an_unbounded_method_stable_at_the_top_takes_the_grid_and_one_probe():
    """pred inf (an A-stable method) and stable everywhere: the grid's probes, then one at
    the top, and nothing else: no ladder, no bisection."""
    h_meas, probe = _ladder_search([np.inf, np.inf], [np.inf, np.inf])
    assert np.isinf(h_meas).all()
    asked = np.concatenate(probe.ran)
    assert len(asked) == 2 * (len(HS) + 1) and np.sum(asked == H_PROBE_MAX) == 2


def test_the_ladder_stops_at_each_lanes_first_failure():
    """The predicted-limit ladder (PRED_LADDER times pred) climbs rung by rung: a lane whose
    limit lies between its rungs 1 and 2 (pred and sqrt 2 pred) probes rungs 0, 1 and 2 and
    none above, where the first failure already ends the bracket; the limit is found as
    before. A grid failure below every rung (limit under 0.7 pred, above the grid's step
    below it) leaves the ladder unprobed but its rungs below that failure."""
    pred = np.array([0.03, 0.0035])
    limit = np.array([0.032, 0.00136])        # 1.07 pred; between grid steps 0.00100, 0.00376
    h_meas, probe = _ladder_search(limit, pred)
    assert np.all(h_meas < limit) and np.all(limit <= h_meas * (1 + REL_TOL) * (1 + 1e-9))
    asked = set(np.round(np.concatenate(probe.ran), 12))
    lane0, lane1 = (np.round(p * limit_search.PRED_LADDER, 12) for p in pred)
    assert [r in asked for r in lane0] == [True] * 3 + [False] * (len(lane0) - 3)
    # Lane 1: the grid fails at 0.00376; its first rung (0.71 pred, 0.0025) lies below that
    # and is probed, and fails: every rung above it is left.
    assert [r in asked for r in lane1] == [True] + [False] * (len(lane1) - 1)


def test_no_probe_above_the_largest_step_worth_one():
    """With `top` (the stability horizon of the "modes" rule) below h_probe_max, neither the
    ladder nor the rising ladder probes past it, and a lane stable up to it is unbounded."""
    top = 0.5
    h_meas, probe = _ladder_search([np.inf, 0.3], [0.2, 0.2], top=top)
    asked = np.concatenate(probe.ran)
    assert asked.max() <= top and np.isinf(h_meas[0])
    assert h_meas[1] < 0.3 <= h_meas[1] * (1 + REL_TOL) * (1 + 1e-9)


def test_the_padding_lanes_of_a_block_are_not_probed(tmp_path, monkeypatch):
    """Three points in chunks of two: block 1 holds one point and a padding lane that
    repeats it. Its stability probes ask the real lane alone, and the padding lane's
    outcomes and limit are the real lane's; the real lane's limit is the one block 0's
    search finds for the same point (its lane 1 there)."""
    from helpers import TINY_SWEEP

    from stepzoo.bench.sweep.block import Block
    from stepzoo.bench.sweep.config import load
    from stepzoo.bench.sweep.runs.stability_runs import StabilityRuns
    from stepzoo.integrators import method
    path = tmp_path / "three.toml"
    path.write_text(TINY_SWEEP.replace("vx = [6.0, 20.0]", "vx = [6.0, 20.0, 20.0000001]")
                    .replace("points = 1", "points = 2"))
    cfg = load(path)
    asked = []
    plain = StabilityRuns.runs_at

    def recording(self, meth, lanes, h):
        asked.append(np.asarray(lanes))
        return plain(self, meth, lanes, h)

    monkeypatch.setattr(StabilityRuns, "runs_at", recording)
    euler = method("euler")
    limits = []
    for b in (0, 1):
        block = Block(cfg, b, {})
        grid = block.stable(euler, np.tile(np.asarray(cfg.hs), (2, 1)))
        pred = np.array([p.h for p in block.predicted(euler)])
        limits.append(block.measured_limits(euler, grid, pred).h_meas)
        if b == 1:
            assert block.points.n_real == 1 and all((a == 0).all() for a in asked)
            assert (grid.stable[0] == grid.stable[1]).all()
        asked.clear()
    assert limits[1][0] == limits[1][1]
    assert limits[1][0] == pytest.approx(limits[0][1], rel=REL_TOL)


WHEEL_MODES = """
name = "wheel-settle"
model = "quarter_car"
horizon = 0.5
methods = ["rk4", "backward_euler"]
envelope = { v = [10.0, 30.0], T = [-800.0, 0.0] }
error = { states = ["s"] }
steps = { h = { min = 0.0005, max = 0.05, num = 4 } }
timing = { rounds = 1 }
"""


@pytest.mark.parametrize("name", ["rk4", "backward_euler"])
def test_a_search_probe_settles_a_candidate_its_mode_runs_show_unstable(name):
    """The "modes" rule's search probe (settle) gives the whole test's outcome, stable and
    converged, at candidates below and above each lane's limit; an explicit method's
    unstable candidates run the unperturbed state and the modes alone (MODES + 1 runs, not
    MODES + d + 1); backward Euler, whose every run converges here, runs every direction."""
    import tomllib

    from stepzoo.bench.sweep import config as sweep_config
    from stepzoo.bench.sweep.block import Block
    from stepzoo.bench.sweep.runs import method_runs
    from stepzoo.bench.sweep.runs.stability_runs import MODES
    cfg = sweep_config.validate(tomllib.loads(WHEEL_MODES), "wheel-settle")
    block = Block(cfg, 0, {})
    runs, meth = block.stability_runs(), cfg.method(name)
    pred = np.array([p.h for p in block.predicted(meth)])
    lanes = np.repeat(np.arange(len(pred)), 4)
    base = np.where(np.isfinite(pred), pred, 0.01)
    h = np.repeat(base, 4) * np.tile([0.5, 1.5, 3.0, 8.0], len(pred))
    counted = []
    plain = method_runs.Runner.__call__

    def counting(self, meth, x0, u, p, hh, n):
        counted.append(len(x0))
        return plain(self, meth, x0, u, p, hh, n)

    whole = runs.runs_at(meth, lanes, h)
    method_runs.Runner.__call__ = counting
    try:
        settled = runs.runs_at(meth, lanes, h, settle=True)
    finally:
        method_runs.Runner.__call__ = plain
    assert np.array_equal(whole.stable, settled.stable)
    assert np.array_equal(whole.converged, settled.converged)
    d, B = len(cfg.spec.states), len(block.points)
    bad = int((~whole.stable).sum())
    if name == "rk4":
        assert 0 < bad < len(h)
        runs_made = len(h) * (MODES + 1) + (len(h) - bad) * d
    else:
        assert whole.converged.all()
        runs_made = len(h) * (MODES + d + 1)
    assert len(counted) == -(-len(h) * (MODES + 1) // B) + -(-(runs_made - len(h) * (MODES + 1)) // B)


@pytest.mark.parametrize("stability_horizon", [0.5, 0.3])
def test_the_grids_unperturbed_runs_are_its_accuracy_runs(stability_horizon):
    """Under the "modes" rule a grid step whose accuracy run is as long as its stability run
    takes that run as its unperturbed one: the same outcomes as running it again, one run
    fewer per lane. The grid divides the 0.5 s horizon: with the stability horizon 0.5 s
    every step's lengths agree; with 0.3 s none does, and each runs its own."""
    import tomllib

    from stepzoo.bench.sweep import chunk_tables
    from stepzoo.bench.sweep import config as sweep_config
    from stepzoo.bench.sweep.block import Block
    from stepzoo.bench.sweep.runs import method_runs
    raw = tomllib.loads(WHEEL_MODES)
    raw["stability"] = {"horizon": stability_horizon}
    cfg = sweep_config.validate(raw, "wheel-settle")
    block, meth = Block(cfg, 0, {}), cfg.method("rk4")
    _, _, made = chunk_tables._accuracy_runs(block, meth)
    H = np.tile(np.asarray(cfg.hs), (len(block.points), 1))
    lanes = []
    plain = method_runs.Runner.__call__

    def counting(self, meth, x0, u, p, h, n):
        lanes.append(len(x0))
        return plain(self, meth, x0, u, p, h, n)

    whole = block.stable(meth, H)
    method_runs.Runner.__call__ = counting
    try:
        reused = block.stable(meth, H, made)
    finally:
        method_runs.Runner.__call__ = plain
    for a, b in zip(whole, reused):
        np.testing.assert_array_equal(a, b)
    B, K = len(block.points), block.stability_runs().delta.shape[1]
    runs = len(cfg.hs) * B * (K + (stability_horizon != cfg.horizon))
    assert len(lanes) == -(-runs // B)
