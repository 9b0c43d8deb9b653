"""Reading result folders for the report: a sweep folder, a tuned config and plan folders,
each checked against its contract so that a missing or damaged file is one UsageError line
naming it, not a traceback halfway through a figure."""
from __future__ import annotations

import json
import tomllib
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from stepzoo.bench.sweep import tables as schema
from stepzoo.bench.sweep.config import ESTIMATES
from stepzoo.bench.sweep.folder import check_columns, check_finished
from stepzoo.errors import UsageError
from stepzoo.safe_parse import json_loads, toml_loads

# Columns each sweep table must have, whatever the model (the schema's), plus those the
# manifest's model names: its envelope variables and states (View).
SWEEP_TABLES = {f"{name}.{'csv' if name == 'summary' else 'parquet'}": columns
                for name, columns in schema.REQUIRED.items()}
TOLERANCES = {"pos_tol_m": ("err_pos", "m", "position error"),
              "tol": ("err", "", "error (error states over their scales)")}
# A sweep written before models were data: the 5-state bicycle over (vx, delta).
BICYCLE = {"name": "dynamic5", "states": ["X", "Y", "psi", "vy", "r"], "inputs": ["delta"],
           "variables": ["vx", "delta"], "error_states": ["vy", "r"], "error_scales": [1, 1],
           "vehicle": True}
PLAN_KEYS = ["status", "path", "start", "goal", "tree", "map", "stats"]
PLAN_MAP_KEYS = ["file", "resolution", "origin"]


@dataclass(frozen=True)
class View:
    """How the report names and draws a sweep's model: Figure 1's state against time, Figure
    2's plane, the error the work-precision and error figures plot (`error`, a runs column,
    and its label), the envelope variables (x axis, then colour)."""
    model: str
    vehicle: bool
    states: tuple
    variables: tuple
    error_states: tuple
    plot_state: str
    plane: tuple
    error: str
    error_unit: str
    error_label: str

    @staticmethod
    def of(manifest: dict, runs: pd.DataFrame) -> "View":
        spec: dict = manifest.get("model_spec") or BICYCLE
        states, errs = tuple(spec["states"]), tuple(spec["error_states"])
        vehicle = bool(spec.get("vehicle")) and "err_pos" in runs
        plot = "r" if vehicle and "r" in states else errs[0]
        plane = ("X", "Y") if vehicle else (errs + tuple(s for s in states if s not in errs)
                                            + errs)[:2]
        column, unit, label = TOLERANCES["pos_tol_m" if vehicle else "tol"]
        if not vehicle and manifest.get("error_estimate") == ESTIMATES["final"]:
            label = "error at the end of the horizon (error states over their scales)"
        return View(str(spec.get("name", manifest.get("model", "?"))), vehicle, states,
                    tuple(spec["variables"]), errs, plot, plane, column, unit, label)

    def with_tolerance(self, tuned) -> "View":
        """The view whose error axis is the one the tuned config's tolerance bounds."""
        for key, (column, unit, label) in TOLERANCES.items():
            if tuned and key in tuned:
                return dataclasses.replace(self, error=column, error_unit=unit,
                                           error_label=label)
        return self


def tolerance(tuned) -> float | None:
    """The tuned config's tolerance, in the unit of its error axis."""
    for key in TOLERANCES:
        if tuned and key in tuned:
            return float(tuned[key])
    return None


@dataclass(frozen=True)
class Sweep:
    """The tables of one `stepzoo sweep` folder, as written by it."""
    folder: Path
    manifest: dict
    runs: pd.DataFrame
    limits: pd.DataFrame
    summary: pd.DataFrame
    eigenvalues: pd.DataFrame
    trajectories: pd.DataFrame

    @property
    def view(self) -> View:
        return View.of(self.manifest, self.runs)


@dataclass(frozen=True)
class Plan:
    """One planned scenario: plan.json as a dict and its occupancy grid (row 0 at the bottom)."""
    name: str
    folder: Path
    record: dict
    occupied: np.ndarray


def _read_table(path: Path) -> pd.DataFrame:
    try:
        if path.suffix == ".csv":
            return pd.read_csv(path)
        return pd.read_parquet(path)
    except OSError:
        raise                     # unreadable, not damaged: the command says which
    except Exception as err:  # pyarrow and pandas raise many types for one cause: bad bytes
        raise UsageError(f"{path} is damaged ({type(err).__name__}); rerun `stepzoo sweep` "
                         "into that folder") from None


def load_sweep(folder) -> Sweep:
    """Every table of a sweep folder, with its required columns checked."""
    folder = Path(folder)
    if not folder.is_dir():
        raise UsageError(f"sweep folder {folder} does not exist; run `stepzoo sweep CONFIG "
                         f"--out {folder}` first")
    missing = [name for name in ["manifest.json", *SWEEP_TABLES]
               if not (folder / name).is_file()]
    if missing:
        raise UsageError(f"sweep folder {folder} lacks {', '.join(missing)}; rerun "
                         f"`stepzoo sweep CONFIG --out {folder}`")
    try:
        manifest = json_loads((folder / "manifest.json").read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UsageError(f"{folder / 'manifest.json'} is damaged ({err}); rerun "
                         "`stepzoo sweep`") from None
    files = {name: _read_table(folder / name) for name in SWEEP_TABLES}
    check_columns(folder, files, SWEEP_TABLES)
    tables = {name.split(".")[0]: table for name, table in files.items()}
    runs = tables["runs"]
    if "model_spec" not in manifest and "err" not in runs and {"err_vy", "err_r"} <= set(runs):
        # A bicycle sweep from before models were data: its error norm is max(|vy|, |r|).
        runs["err"] = runs[["err_vy", "err_r"]].max(axis=1)
    view = View.of(manifest, runs)
    check_columns(folder, files, {"runs.parquet": [*view.variables, view.error, "err"],
                                  "limits.parquet": list(view.variables),
                                  "trajectories.parquet": list(view.states)})
    check_finished(folder, manifest, tables["runs"], tables["limits"])
    if tables["runs"].empty:
        raise UsageError(f"{folder / 'runs.parquet'} has no rows; rerun `stepzoo sweep`")
    if not (tables["trajectories"]["method"] == "reference").any():
        raise UsageError(f"{folder / 'trajectories.parquet'} lacks the 'reference' run; "
                         "rerun `stepzoo sweep`")
    return Sweep(folder, manifest, **tables)


def load_tuned(path, sweep: Sweep | None = None) -> dict:
    """The TOML written by `stepzoo tune`, checked as the tuned kind (stepzoo.tuned_file),
    with a tolerance to draw, and (given `sweep`) of the sweep's model, whose runs have the
    error its tolerance bounds."""
    from stepzoo.config_schema import check
    from stepzoo.tuned_file import TunedFile
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"tuned config {path} does not exist; run `stepzoo tune SWEEP_DIR "
                         f"--tol E --out {path}` first")
    try:
        data = toml_loads(path.read_text())
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise UsageError(f"tuned config {path} is damaged ({err}); rerun `stepzoo tune`") \
            from None
    check(TunedFile, data, f"tuned config {path}")
    if not any(k in data for k in TOLERANCES):
        raise UsageError(f"tuned config {path} lacks {' or '.join(TOLERANCES)}; rerun "
                         "`stepzoo tune`")
    if sweep is not None:
        model = sweep.manifest.get("model", sweep.view.model)
        if data.get("model", model) != model:
            raise UsageError(f"tuned config {path} is of the model {data['model']}, the sweep "
                             f"{sweep.folder} of {model}; give the tuned config of that sweep")
        column = sweep.view.with_tolerance(data).error
        if column not in sweep.runs:
            raise UsageError(f"tuned config {path} bounds the {TOLERANCES['pos_tol_m'][2]} "
                             f"(pos_tol_m), which the sweep {sweep.folder} of {model} has not "
                             "(no X, Y); give the tuned config of that sweep")
    return data


def _load_plan(folder: Path) -> Plan:
    path = folder / "plan.json"
    try:
        record = json_loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UsageError(f"{path} is damaged ({err}); rerun `stepzoo plan`") from None
    if not isinstance(record, dict):
        raise UsageError(f"{path} is not a plan record (a JSON object); rerun `stepzoo plan`")
    missing = [k for k in PLAN_KEYS if k not in record]
    missing += [f"map.{k}" for k in PLAN_MAP_KEYS
                if "map" in record and k not in record["map"]]
    if missing:
        raise UsageError(f"{path} lacks {', '.join(missing)}; rerun `stepzoo plan`")
    grid = folder / record["map"]["file"]
    if not grid.is_file():
        raise UsageError(f"plan folder {folder} lacks {record['map']['file']} (the map of "
                         "plan.json); rerun `stepzoo plan`")
    try:
        occupied = np.load(grid, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise UsageError(f"{grid} is damaged ({err}); rerun `stepzoo plan`") from None
    if occupied.ndim != 2:
        raise UsageError(f"{grid} is not a 2-D occupancy grid; rerun `stepzoo plan`")
    return Plan(record.get("scenario", folder.name), folder, record, occupied.astype(bool))


def load_plans(folder) -> list[Plan]:
    """Plans of a folder: itself when it holds plan.json, else each subfolder that does."""
    folder = Path(folder)
    if not folder.is_dir():
        raise UsageError(f"plans folder {folder} does not exist; run `stepzoo plan --all "
                         f"--config tuned.toml --out {folder}` first")
    if (folder / "plan.json").is_file():
        return [_load_plan(folder)]
    subs = sorted(p.parent for p in folder.glob("*/plan.json"))
    if not subs:
        raise UsageError(f"plans folder {folder} holds no plan.json (nor do its subfolders); "
                         "give a folder written by `stepzoo plan`")
    return [_load_plan(p) for p in subs]


def load_manifest(folder) -> dict | None:
    """A results folder's manifest.json, or None when it has none (an older stepzoo's plans);
    a damaged one is a UsageError naming it."""
    path = Path(folder) / "manifest.json"
    if not path.is_file():
        return None
    try:
        manifest = json_loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UsageError(f"{path} is damaged ({err}); rerun the command that wrote "
                         f"{folder}") from None
    return manifest if isinstance(manifest, dict) else None
