"""The limit search finds a known threshold: on a toy probe whose lanes are stable exactly
below their `limit`, the grid's bracket, the ladders and the narrowing end with the limit in
[h_meas, h_meas (1 + rel_tol)] wherever it lies (inside the grid, above it, below it, nowhere)
and whatever the prediction, with the cause of the failure above it."""
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
