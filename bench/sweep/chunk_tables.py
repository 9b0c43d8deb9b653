"""A sweep chunk's tables from a block (bench.sweep.block.Block): the reference chunk's eigenvalues
and reference trajectory, and a method's runs (accuracy, stability, calibrated timing),
limits (measured against predicted, fitted order) and figure runs."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from stepzoo.bench.model import frozen_jacobian as frozen
from stepzoo.bench.sweep import metrics
from stepzoo.bench.model import nonfinite as model_nan
from stepzoo.bench.sweep import tables as schema
from stepzoo.bench.sweep.runs import figure_runs as trajectory_runs
from stepzoo.bench.sweep.runs.method_runs import accuracy_run
from stepzoo.bench.timing.rounds import CALIBRATION_STEPS, busiest_per_step, calibrated


def reference_chunk(block) -> dict:
    """The eigenvalues at each point's initial state that bound or matter, and (block 0) the
    reference's figure trajectory."""
    lam, points = block.along().lam, block.points
    rows = []
    for lane, i in enumerate(points.ids):
        ev = lam[lane, 0]
        keep = frozen.constraining(ev) | (np.abs(ev) > frozen.REL_ZERO
                                          * np.nanmax(np.abs(ev), initial=0.0))
        for z in sorted(ev[keep], key=lambda z: (z.real, z.imag)):
            rows.append(dict(point=i, **{v: points.values[lane, j] for j, v in
                                         enumerate(points.variables)},
                             lam_re=float(z.real), lam_im=float(z.imag)))
    traj = trajectory_runs.reference_rows(block) if block.block == 0 else pd.DataFrame()
    return {"eigenvalues": pd.DataFrame(rows, columns=schema.eigen_columns(points.variables)),
            "trajectories": traj}


def method_chunk(block, name: str) -> dict:
    cfg, meth, points = block.cfg, block.cfg.method(name), block.points
    # Compiles the one program of the chunk's runs, accuracy and stability alike, so that
    # the timed accuracy rounds below time the computation alone.
    block.run(meth, points.x0, points.u, points.p, cfg.hs[0], 1)
    runs, err_scale, made = _accuracy_runs(block, meth)
    # The accuracy runs are the grid's unperturbed stability runs where they are as long.
    grid = block.stable(meth, np.tile(np.asarray(cfg.hs), (len(points), 1)), made)
    for j, col in enumerate(runs):
        # The order fit reads the accuracy run alone: a step the stability test calls
        # unstable (the perturbation grew, as it does in a growing exact solution) still
        # has a meaningful error when its own solves converged against a good reference.
        col["fit"] = col["converged"] & col["ref_ok"]
        col["stable"], col["blowup_t"] = grid.stable[:, j], grid.blowup_t[:, j]
        col["converged"] = col["converged"] & grid.converged[:, j]
        col["stable"] &= col["converged"]
    predicted = block.predicted(meth)
    measured = block.measured_limits(meth, grid, np.array([p.h for p in predicted]))
    diagnosis = block.diagnose(meth, measured.h_meas)
    along = block.along()
    events = block.nonsmooth()
    with block.watch.clock("metrics_s"):
        columns = schema.run_columns(block.spec.variables, block.spec.states,
                                     block.spec.vehicle)
        every = pd.concat([pd.DataFrame(r) for r in runs], ignore_index=True)
        every = every.drop_duplicates(["h", "point"])             # padded lanes repeat
        limits = []
        for lane, i in enumerate(points.ids):
            rows = every[(every["point"] == i) & every["fit"]]
            fit = metrics.order_fit(rows["h"], rows["err"], cfg.reference.rtol, cfg.reference.atol,
                                    err_scale[lane])
            limits.append(_limit_row(block, meth, lane, i, predicted[lane], fit, along,
                                     measured.h_meas[lane], measured.cause[lane])
                          | events[lane].columns() | _diagnosis(block, diagnosis, lane))
    model_nan.record(limits, model_nan.lane_times(block))
    for row in limits:
        # The "blowup" rule's runs last stability.steps steps of the step probed.
        horizon = cfg.stability_horizon if cfg.stability.rule == "modes" else \
            cfg.stability.steps * row["h_meas"]
        row["limit_note"] = metrics.limit_note(row, cfg.stability.growth, horizon)
    traj = trajectory_runs.method_rows(block, meth) if block.block == 0 else pd.DataFrame()
    limits_df = pd.DataFrame(limits, columns=schema.limit_columns(block.spec.variables,
                                                                  block.spec.states))
    return {"runs": every[columns], "limits": limits_df, "trajectories": traj}


def _limit_row(block, meth, lane, point, pred, fit, along, h_meas, cause) -> dict:
    """The limits table's row of one lane, but for its nonsmooth and model_nan columns."""
    spec, k = block.spec, pred.k
    rho = float(np.nanmax(np.abs(along.lam[lane]), initial=0.0))
    bind = along.lam[lane, k, pred.j] if k >= 0 else complex(np.nan, np.nan)
    return dict(
        method=meth.name, point=point, **{v: block.points.values[lane, c] for c, v in
                                          enumerate(spec.variables)},
        h_pred=pred.h, h_meas=h_meas, ratio=_ratio(h_meas, pred.h),
        order_declared=meth.order,
        **fit.columns(), rho_max=rho, order_h_rho=fit.h_min * rho,
        h_probe_max=block.h_top, t_bind=along.ts[k] if k >= 0 else np.nan,
        lam_re_bind=bind.real, lam_im_bind=bind.imag, limit_cause=cause,
        **{f"bind_{s}": along.xs[lane, k, c] if k >= 0 else np.nan
           for c, s in enumerate(spec.states)})


def _diagnosis(block, diag, lane) -> dict:
    """The limits row's stability diagnosis columns of one lane (block.diagnose)."""
    j = int(diag.state[lane])
    return {"unstable_state": block.spec.states[j] if j >= 0 else "",
            "unstable_t": float(diag.t[lane]), "growth_ratio": float(diag.growth_ratio[lane]),
            "ref_growth": float(diag.ref_growth[lane]),
            "newton_retried": bool(diag.retried[lane])}


def _accuracy_runs(block, meth) -> tuple[list[dict], np.ndarray, dict]:
    """Per grid step, the columns of `runs` for every lane (stability columns to come),
    per lane the largest scaled size of the reference's error states, and the runs made
    ({(meth, h): (states (B, n+1, d), converged (B,))}). Each run is integrated once; its
    timing columns are the method's calibration (`_calibrate`)."""
    cfg, spec, points, out, made = block.cfg, block.spec, block.points, [], {}
    scale = np.zeros(len(points))
    walls, work = [], []
    for h in cfg.hs:
        n = round(cfg.horizon / h)
        ref = block.accuracy_reference(h)
        # Compiled already (method_chunk): the wall time is the computation's alone.
        acc = accuracy_run(block.run, meth, points, h, n, ref.x, cfg.error.estimate)
        walls.append(acc.run_s)
        made[meth, h] = (acc.x, acc.converged)
        with block.watch.clock("metrics_s"):
            scale = np.maximum(scale, spec.scaled(ref.x).max(axis=1))
        out.append({"method": meth.name, "h": h, "point": list(points.lanes),
                    **points.columns(), **acc.errors, "evals_per_s": acc.evals / (n * h),
                    "n_steps": n, "ref_ok": ref.ok, "converged": acc.converged,
                    "evals": acc.evals})
        work.append(busiest_per_step(acc.evals, n))
    cal, j = _calibrate(block, meth, walls)
    for col, w in zip(out, work):
        col.update(calibrated(cal, out[j]["n_steps"] * len(points), w / work[j]))
        col["time_s"] = col["time_per_step_s"] * col["n_steps"]
    return out, scale, made


def _calibrate(block, meth, walls) -> tuple[list[float], int]:
    """(wall times [s] of timing_rounds calls, index of the grid step timed): the grid's
    run nearest CALIBRATION_STEPS steps, its first call (`walls`: one per grid step) and
    timing_rounds - 1 more. One run prices the method: repeating every run would cost
    the rounds over again, an implicit method's runs most of all."""
    cfg, points = block.cfg, block.points
    steps = np.array([round(cfg.horizon / h) for h in cfg.hs])
    j = int(np.argmin(np.abs(steps - CALIBRATION_STEPS)))
    more = [block.run(meth, points.x0, points.u, points.p, cfg.hs[j], int(steps[j])).run_s
            for _ in range(cfg.timing.rounds - 1)]
    block.watch.add("integration_s", sum(more))
    return [walls[j], *more], j


def _ratio(meas, pred):
    if math.isinf(meas) and math.isinf(pred):
        return float("nan")                   # both unbounded: no ratio to speak of
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.float64(meas) / pred)
