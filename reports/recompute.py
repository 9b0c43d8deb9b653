"""What the report computes beyond the sweep's tables, by the sweep's own code on the config
the sweep folder keeps (config.toml): the per-point verdicts of `--verdict`, and Figures 1-2's
runs at the operating point where the tuned choice binds."""
from __future__ import annotations

import dataclasses
import tomllib

import numpy as np

from stepzoo.bench.sweep.runs.figure_rerun import trajectories_at
from stepzoo.bench.sweep.config import load
from stepzoo.bench.tune.verdict import verdicts as judge_all
from stepzoo.errors import UsageError
from stepzoo.reports import figure_data, tables
from stepzoo.safe_parse import toml_loads


def verdict_tables(sweep, verdicts, view, tol: float, margin: float) -> list:
    """A table per (method, h [s]) of `verdicts`: `stepzoo verdict`'s rows on the sweep's own
    config (its config.toml), judged on the report's error (`view`), tolerance and margin."""
    if not verdicts:
        return []
    unit = f" {view.error_unit}" if view.error_unit else ""
    cfg = load(sweep.folder / "config.toml")
    out = []
    for summary, table in judge_all(cfg, verdicts, view.error, tol, margin, unit):
        out.append(tables.verdict_table(summary, table, view.variables, tol, unit))
    return out


def figure_point(sweep, tuned, margin):
    """(sweep whose trajectories Figures 1-2 draw, why that point): the config's own
    [trajectories] point when it names one; else, with a tuned config, the point where the
    tuned (method, h) binds (figure_data.binding_point), its figure runs computed by the sweep's
    code when the sweep ran them elsewhere (the sweep's own runs when its config no longer
    loads); else the sweep's."""
    try:
        raw = toml_loads((sweep.folder / "config.toml").read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        raw = {}
    named = set(raw.get("trajectories", {})) & set(sweep.view.variables)
    if named:
        return sweep, "the point the config's [trajectories] table names"
    found = figure_data.binding_point(sweep, tuned, margin) if tuned else None
    if found is None:
        return sweep, ("the envelope's first point; name another in the config's "
                       "[trajectories] table, or give a tuned config to see where it binds")
    point, why = found
    ran = sweep.manifest.get("trajectory_point") or {}
    if all(np.isclose(ran.get(v, np.nan), x) for v, x in point.items()):
        return sweep, why
    try:
        cfg = load(sweep.folder / "config.toml")
    except UsageError:
        # The model's module is gone from where it was swept: the figures keep the sweep's
        # own runs, and say why.
        return sweep, f"not where the tuned choice binds ({why}): the sweep's config no " \
            "longer loads, so its runs there cannot be made"
    traj = trajectories_at(cfg, [point[v] for v in cfg.spec.variables])
    manifest = {**sweep.manifest, "trajectory_point": point}
    return dataclasses.replace(sweep, trajectories=traj, manifest=manifest), why
