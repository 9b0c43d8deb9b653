"""The faster sweep gives the tables of the sweep before it (issue 26): on bench/configs/
small.toml every measured limit within the narrowing tolerance rel_tol of the one recorded
from the earlier code, with the same cause, and every run's stability, blow-up time and error
the same to round-off."""
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stepzoo.bench.timing import rounds as timing
from stepzoo.bench.sweep.config import load

SMALL = Path(__file__).resolve().parents[1] / "bench" / "configs" / "small.toml"
INF = float("inf")
# Recorded from the sweep of small.toml at commit edfaba4 (the bracket ladder, 5 timing
# rounds of every run): h_meas [s] per point, in point order.
H_MEAS = {
    "ab2": [0.0193745, 0.01864375, 0.0193745, 0.06914429, 0.06525317, 0.06914429,
            0.1104505, 0.1118628, 0.1104505],
    "euler": [0.03863299, 0.03717586, 0.03863299, 0.1340749, 0.1301156, 0.1340749, 0.2025017,
              0.2230557, 0.2025017],
    "heun": [0.03863299, 0.03717586, 0.03863299, 0.1422567, 0.1301156, 0.1422567, 0.2373898,
             0.2230557, 0.2373898],
    "rk4": [0.05374836, 0.05172112, 0.05374836, 0.1953182, 0.1810241, 0.1953182, 0.3170234,
            0.3103275, 0.3170234],
    "trapezoidal": [INF] * 9,
}
# Per method over its 90 runs: stable runs, sum of blow-up times [s], sum of log10 err (err > 0),
# and
# right-hand-side evaluations (explicit methods only: an implicit method's count is Newton's,
# which may change without changing an error beyond its tolerance).
RUNS = {
    "ab2": (74, 22.9533783784, -12.5385469758, 13059),
    "euler": (81, 6.25, -11.3810248156, 12609),
    "heun": (81, 5.18333333333, -54.3994691363, 25218),
    "rk4": (84, 1.73333333333, -196.755145349, 50436),
    "trapezoidal": (90, 0.0, -116.09843113, None),
}


@pytest.fixture(scope="module")
def small(small_toml_sweep):
    out = small_toml_sweep
    return load(SMALL), pd.read_parquet(out / "runs.parquet"), \
        pd.read_parquet(out / "limits.parquet")


def test_measured_limits_agree_with_the_recorded_ones_to_rel_tol(small):
    cfg, _, limits = small
    for name, recorded in H_MEAS.items():
        lim = limits[limits["method"] == name].sort_values("point")
        h = lim["h_meas"].to_numpy(float)
        old = np.array(recorded)
        assert np.array_equal(np.isinf(h), np.isinf(old)), name
        fin = np.isfinite(old)
        # Both brackets hold the limit and are rel_tol wide (the recorded ones to 7 digits).
        assert np.all(np.abs(np.log(h[fin] / old[fin])) <= np.log1p(cfg.stability.rel_tol) + 1e-6), name
        assert set(lim["limit_cause"]) == {"none" if not fin.any() else "unstable"}, name


def test_runs_are_stable_and_accurate_as_recorded(small):
    _, runs, _ = small
    assert len(runs) == 5 * 10 * 9
    for name, (stable, blowup, log_err, evals) in RUNS.items():
        r = runs[runs["method"] == name]
        err = r["err"].to_numpy(float)
        # Straight ahead (delta = 0) the lateral states stay at rest: error 0, exactly.
        assert np.isfinite(err).all() and (err == 0).sum() == 30, name
        assert int(r["stable"].sum()) == stable, name
        assert np.nansum(r["blowup_t"]) == pytest.approx(blowup, rel=1e-9, abs=1e-12), name
        assert np.log10(err[err > 0]).sum() == pytest.approx(log_err, abs=1e-6), name
        if evals is not None:
            assert int(r["evals"].sum()) == evals, name


def test_every_run_is_priced_by_its_methods_calibrated_run(small):
    """One run per method (the grid's nearest CALIBRATION_STEPS steps) is timed in rounds;
    every other run's time per step is its, scaled by the busiest lane's evaluations per
    step: equal across an explicit method's steps, Newton's ratio for trapezoidal."""
    _, runs, _ = small
    for name, r in runs.groupby("method"):
        by_h = r.groupby("h").agg(t=("time_per_step_s", "first"),
                                  spread=("time_per_step_max_s", "nunique"),
                                  work=("evals", "max"), n=("n_steps", "first"))
        assert (by_h["spread"] == 1).all(), name            # one price per run
        work = by_h["work"] / by_h["n"]
        j = int(np.argmin(np.abs(by_h["n"].to_numpy() - timing.CALIBRATION_STEPS)))
        np.testing.assert_allclose(by_h["t"] / by_h["t"].iloc[j], work / work.iloc[j],
                                   rtol=1e-12, err_msg=name)
        np.testing.assert_allclose(r["time_s"], r["time_per_step_s"] * r["n_steps"])
        assert (r["timing_rounds"] == 5).all()
    rk4 = runs[runs["method"] == "rk4"].groupby("h")["time_per_step_s"].first()
    assert np.ptp(rk4) <= 1e-12 * rk4.max()
    trap = runs[runs["method"] == "trapezoidal"].groupby("h")["time_per_step_s"].first()
    assert trap.iloc[-1] > trap.iloc[0]        # more Newton iterations at the largest step


def test_calibrated_scales_every_wall_clock_column_by_the_work():
    cols = timing.calibrated([0.2, 0.4, 0.3, 0.5, 0.6], 10, 2.0)
    assert cols["time_per_step_s"] == pytest.approx(0.04)
    assert cols["time_per_step_median_s"] == pytest.approx(0.08)
    assert cols["time_per_step_max_s"] == pytest.approx(0.12)
    assert cols["time_per_step_iqr_s"] == pytest.approx(0.04)   # (0.5 - 0.3) / 10 x 2
    assert cols["timing_rounds"] == 5
    assert timing.busiest_per_step([8, 12, 10], 4) == 3.0
