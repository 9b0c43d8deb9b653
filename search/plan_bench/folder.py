"""A plan-bench's results folder: what plan-bench writes there (OWN), whether it may start,
continue (`--resume`) or start again (`--overwrite`) in it, and the finished runs it holds.
Which folders it may write into at all, and its lock, are stepzoo.results_folder's (one rule
for every command); each finished (integrator, query, run) is a file of its own, written
atomically, so a killed plan-bench loses no finished run."""
from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

from stepzoo.errors import UsageError
from stepzoo.output import atomic_write, to_json
from stepzoo.results_folder import MANIFEST, check_kind
from stepzoo.safe_parse import json_loads
from stepzoo.search.plans.schema import run_row_problem

PARTS = "parts"                       # one JSON row per finished (integrator, query, run)
OWN = (MANIFEST, "runs.parquet", "runs.csv", "summary.parquet", "summary.csv", "ompl", PARTS)


def check_out(out, overwrite: bool):
    """UsageError unless plan-bench may write into `out` (results_folder's rule: new,
    empty, or plan-bench's; anything else only with --overwrite, and kept)."""
    check_kind(out, "plan-bench", overwrite=overwrite)


def start(out: Path, settings: dict, resume: bool, overwrite: bool) -> dict[str, dict]:
    """The finished rows to keep, by part name (empty: a fresh start); called with the
    folder claimed. `settings` is what makes two benches the same (queries, integrators,
    runs, seeds, planner config): --resume continues only the same bench; --overwrite
    removes what plan-bench wrote, nothing else."""
    holds = [n for n in OWN if (out / n).exists()]
    if not holds or overwrite:
        if resume:
            raise UsageError(f"--resume: {out} holds no plan-bench to continue; leave out "
                             "--resume to start one")
        for name in holds:
            path = out / name
            shutil.rmtree(path) if path.is_dir() else path.unlink()
        return {}
    if not resume:
        raise UsageError(f"{out} already holds a plan-bench ({', '.join(holds[:3])}); pass "
                         "--resume to continue it or --overwrite to start again")
    try:
        manifest = json_loads((out / MANIFEST).read_text())
    except (OSError, ValueError):
        manifest = {}
    held = manifest.get("settings") if isinstance(manifest, dict) else None
    now = json.loads(to_json(settings))
    if isinstance(held, dict) and isinstance(held.get("map_sha256"), dict) and \
            {**held, "map_sha256": None} == {**now, "map_sha256": None}:
        changed = [m for m, sha in now["map_sha256"].items() if held["map_sha256"].get(m) != sha]
        if changed:
            raise UsageError(f"--resume: the map file {changed[0]} is not the one the "
                             f"plan-bench in {out} began with (its sha256 differs); restore "
                             "it, or give a new --out")
    if held != now:
        raise UsageError(f"--resume: {out} holds a plan-bench of other queries, integrators, "
                         "runs or planner settings; resume with the same command, or give a "
                         "new --out")
    return finished(out)


def sha256(path) -> str:
    """The hex sha256 of the file at `path` (a map: what --resume checks is unchanged)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def finished(out: Path) -> dict[str, dict]:
    """The rows of every finished run in `out`, by part name; a part cut off mid-write
    cannot exist (parts are renamed into place), so every file read is whole."""
    rows = {}
    for path in sorted((Path(out) / PARTS).glob("*.json")):
        try:
            row = json_loads(path.read_text())
        except (OSError, ValueError) as err:
            raise UsageError(f"--resume: {path} is not a run plan-bench saved ({err}); remove "
                             "it to plan that run again") from None
        problem = run_row_problem(row)
        if problem:
            raise UsageError(f"--resume: {path} is not a run plan-bench saved ({problem}); "
                             "remove it to plan that run again")
        rows[path.stem] = row
    return rows


def save(out: Path, name: str, row: dict) -> None:
    """One finished run, atomically."""
    atomic_write(Path(out) / PARTS / f"{name}.json", json.dumps(row) + "\n")
