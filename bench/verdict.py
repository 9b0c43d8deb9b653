"""Verdicts on a fixed step that people ship: for one (method, h) and a config's model and
envelope, at every operating point, whether h is stable (measured by the sweep's blow-up
test, and predicted from the frozen Jacobians) and how large its error is against the tight
reference; the region of the envelope where it fails, and the worst error."""
from __future__ import annotations

import numpy as np
import pandas as pd

from stepzoo.bench import metrics, model_nan
from stepzoo.bench.sweep import _Work, n_blocks


def verdict(cfg, method_name: str, h: float) -> pd.DataFrame:
    """One row per operating point: its variables, h_pred [s], stable (measured), cause
    ('unstable', 'solver failed' or ''), err (the error norm, over the run or at its end as
    the config's [error] estimate says, as the sweep's), err_pos [m] for vehicle models.
    Implicit methods solve with the config's [newton] options."""
    import dataclasses

    meth = cfg.method(method_name)
    n = max(1, round(cfg.horizon / h))
    # The accuracy runs take n steps of h; the stability runs stab_steps.
    cfg = dataclasses.replace(cfg, hs=(cfg.horizon / n,))
    cache, rows = {}, []
    for block in range(n_blocks(cfg)):
        work = _Work(cfg, block, cache)
        work.max_steps = max(n, cfg.stab_steps)
        ok, _, conv = work.stable(meth, np.full((len(work.x0), 1), h))
        x, _, acc_conv, _ = work.integrate(meth, work.x0, work.u, work.p, h, n)
        ref, _ = work.reference(h, n)
        err = metrics.run_error(cfg.spec, x, ref, cfg.error_estimate)
        predicted = work.predicted(meth)
        nan_t = model_nan.lane_times(work)
        for lane, i in enumerate(work.ids):
            row = dict(point=i, **work.point_columns())
            row = {k: (v[lane] if k != "point" else i) for k, v in row.items()}
            stable = bool(ok[lane, 0] and acc_conv[lane])
            row.update(h_pred=predicted[lane][0], stable=stable,
                       cause="" if stable else ("unstable" if conv[lane, 0] and acc_conv[lane]
                                                else "solver failed"),
                       err=float(err[lane]) if stable else float("inf"))
            if cfg.spec.vehicle:
                ix, iy = cfg.spec.states.index("X"), cfg.spec.states.index("Y")
                d = np.hypot(x[lane, :, ix] - ref[lane, :, ix], x[lane, :, iy] - ref[lane, :, iy])
                row["err_pos"] = float(np.nanmax(d)) if stable else float("inf")
            if np.isfinite(nan_t[lane]):
                row.update(stable=False, cause=model_nan.cause(nan_t[lane]), h_pred=np.nan)
            rows.append(row)
    return pd.DataFrame(rows)


def region(table: pd.DataFrame, mask, variables) -> str:
    """The envelope's range over the rows of `mask`, per variable: 'vx 2..8, delta -0.8..0.8'."""
    sub = table[mask]
    if sub.empty:
        return "nowhere"
    return ", ".join(f"{v} {sub[v].min():.4g}..{sub[v].max():.4g}" if sub[v].nunique() > 1
                     else f"{v} = {sub[v].iloc[0]:.4g}" for v in variables)
