"""A sweep's results folder: whether a sweep may start, continue or start again in it, and
whether it holds every chunk and every (method, h, point) row its config implies. The sweep
checks before it writes its tables and marks the manifest complete; tune and report check
again before they read, so a folder that lost chunks is refused, never read as a result."""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pandas as pd

from stepzoo.bench.sweep.tables import REQUIRED, SORT
from stepzoo.errors import UsageError
from stepzoo.safe_parse import json_loads


def check_flags(resume: bool, overwrite: bool):
    if resume and overwrite:
        raise UsageError("--resume and --overwrite contradict each other (continue the sweep, "
                         "or discard it); give one")


def check_start(cfg, out: Path, resume: bool, overwrite: bool, discard=None) -> dict | None:
    """The old manifest a resumed sweep continues (None: a fresh start); UsageError when the
    folder holds a sweep and neither flag says what to do with it. With `overwrite`,
    `discard(old manifest)` removes what the folder holds (default: its chunks)."""
    manifest = out / "manifest.json"
    holds = manifest.is_file() or (out / "chunks").is_dir()
    if not holds:
        return None
    try:
        old = json_loads(manifest.read_text()) if manifest.is_file() else {}
    except (json.JSONDecodeError, UnicodeDecodeError):
        old = {}
    if overwrite:
        if discard is None:
            shutil.rmtree(out / "chunks", ignore_errors=True)
        else:
            discard(old)
        return None
    if not resume:
        raise UsageError(f"{out} already holds a sweep; pass --resume to continue it or "
                         "--overwrite to start again")
    if old.get("config_sha256") != cfg.sha256:
        raise UsageError(f"{out} holds a sweep of a different config (sha256 "
                         f"{str(old.get('config_sha256'))[:12]}..., this one {cfg.sha256[:12]}"
                         "...); resume with the same config, or give a new --out (a folder "
                         "written before 2026-11-25 has its sha256 by an older rule: "
                         "start it again with --overwrite)")
    return old


def missing_chunks(ids: list[str], chunks: Path) -> list[str]:
    """The chunks of `ids` that `chunks` does not hold."""
    return [c for c in ids if not (chunks / c).is_dir()]


def set_aside_damaged(ids: list[str], chunks: Path) -> dict[str, str]:
    """Move each chunk of `ids` in `chunks` with a table that cannot be read (a file cut
    short by a full disk or a copy, emptied) to the hidden `.ID.damaged` beside it, so that
    the sweep computes it again and a reader finds the bytes it had; {chunk id: what is
    wrong}. A chunk is written whole or not at all (sweep._write_chunk), so a damaged one
    was damaged after, by something else."""
    damaged = {}
    for cid in ids:
        for path in sorted((chunks / cid).glob("*.parquet")):
            try:
                pd.read_parquet(path)
            except OSError:
                raise                     # unreadable, not damaged: the command says which
            except Exception as err:  # damaged bytes raise many types from pyarrow
                damaged[cid] = f"{path.name}: {type(err).__name__}"
                break
    for cid in damaged:
        aside = chunks / f".{cid}.damaged"
        shutil.rmtree(aside, ignore_errors=True)
        os.replace(chunks / cid, aside)
    return damaged


def table_problem(cfg, runs: pd.DataFrame, limits: pd.DataFrame) -> str | None:
    """What is wrong with the tables of a sweep of `cfg` (None: nothing): `runs` must hold
    each (method, h, point) once, `limits` each (method, point) once, for exactly the config's
    methods, steps and points."""
    n_points = len(cfg.points)
    want_runs = len(cfg.methods) * len(cfg.hs) * n_points
    want_limits = len(cfg.methods) * n_points
    keys_runs = runs[["method", "h", "point"]].drop_duplicates() if len(runs) else runs
    keys_limits = limits[["method", "point"]].drop_duplicates() if len(limits) else limits
    if len(runs) != want_runs or len(keys_runs) != want_runs:
        return (f"runs has {len(runs)} rows ({len(keys_runs)} distinct), the config implies "
                f"{want_runs} ({len(cfg.methods)} methods x {len(cfg.hs)} steps x {n_points} "
                "points)")
    if len(limits) != want_limits or len(keys_limits) != want_limits:
        return (f"limits has {len(limits)} rows ({len(keys_limits)} distinct), the config "
                f"implies {want_limits} ({len(cfg.methods)} methods x {n_points} points)")
    if set(runs["method"]) != set(cfg.methods) or set(limits["method"]) != set(cfg.methods):
        return f"its methods are not the config's ({', '.join(cfg.methods)})"
    if not set(runs["h"]) <= set(cfg.hs) or not set(runs["point"]) <= set(range(n_points)):
        return "it holds steps or points the config does not"
    return None


def check_columns(folder, tables: dict[str, pd.DataFrame], wanted: dict[str, list[str]]):
    """UsageError naming the first of `tables` (by file name: "runs.parquet", "summary.csv")
    of the sweep folder `folder` that lacks a column of `wanted` (by file name): a table of
    another command (without the sweep's key columns, schema.SORT), or of another version."""
    for name, columns in wanted.items():
        have = list(tables[name].columns)
        lacking = [c for c in columns if c not in have]
        if not lacking:
            continue
        table, path = name.split(".")[0], Path(folder) / name
        if not set(SORT.get(table, ())) <= set(have):      # not even keyed as the sweep's
            raise UsageError(f"{path} is not a sweep's {table} table (it lacks "
                             f"{_listing(c for c in SORT[table] if c not in have)}; its columns "
                             f"are {_listing(have)}): another command's table? give a folder "
                             "written by `stepzoo sweep`")
        raise UsageError(f"{path} lacks column(s) {_listing(lacking)}: it was written by "
                         "another version of `stepzoo sweep`, or changed since; rerun "
                         "`stepzoo sweep` into a new folder")


def _listing(names, shown: int = 4) -> str:
    names = list(names)
    return ", ".join(map(str, names[:shown])) + (f" and {len(names) - shown} more"
                                                 if len(names) > shown else "")


def check_finished(folder, manifest: dict, runs: pd.DataFrame, limits: pd.DataFrame):
    """UsageError unless `folder` holds a finished sweep whose tables are whole: marked
    complete, its config.toml the one the manifest names, the columns every reader needs
    (schema.REQUIRED and the model's envelope variables) there, every implied row once."""
    from stepzoo.bench.sweep.config import load
    folder = Path(folder)
    again = f"rerun `stepzoo sweep {folder / 'config.toml'} --out {folder} --resume`"
    problems = manifest.get("problems")
    if problems:
        raise UsageError(f"{folder} holds a suite of {len(problems)} problems "
                         f"({', '.join(map(str, problems))}); this reads one problem's sweep: "
                         f"give its folder, such as {folder / str(problems[0])}")
    if not manifest.get("complete"):
        raise UsageError(f"{folder} holds an unfinished sweep; finish it: {again}")
    if not (folder / "config.toml").is_file():
        raise UsageError(f"{folder} lacks config.toml, so its tables cannot be checked; "
                         "rerun `stepzoo sweep CONFIG --out` into a new folder")
    cfg = load(folder / "config.toml")
    if cfg.sha256 != manifest.get("config_sha256"):
        raise UsageError(f"{folder}: config.toml is not the config the manifest names; rerun "
                         "`stepzoo sweep CONFIG --out` into a new folder")
    variables = list(cfg.spec.variables)
    check_columns(folder, {"runs.parquet": runs, "limits.parquet": limits},
                  {"runs.parquet": [*REQUIRED["runs"], *variables],
                   "limits.parquet": [*REQUIRED["limits"], *variables]})
    problem = table_problem(cfg, runs, limits)
    if problem:
        raise UsageError(f"{folder} holds an incomplete or inconsistent sweep: {problem}; "
                         f"{again}")
