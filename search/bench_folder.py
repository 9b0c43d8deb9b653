"""A plan-bench's results folder: what plan-bench writes there (OWN), whether it may start,
continue (`--resume`) or start again (`--overwrite`) in it, and the finished runs it holds.
A folder with anything else in it (a sweep, a user's files) is refused, never written into;
each finished (integrator, query, run) is a file of its own, written atomically, so a killed
plan-bench loses no finished run."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from stepzoo.errors import UsageError
from stepzoo.output import atomic_write, to_json
from stepzoo.results_folder import LOCK

PARTS = "parts"                       # one JSON row per finished (integrator, query, run)
OWN = ("manifest.json", "runs.parquet", "runs.csv", "summary.parquet", "summary.csv", "ompl",
       PARTS, LOCK)


def check_out(out) -> Path:
    """`out` as a folder plan-bench may write into: new, empty, or holding only what
    plan-bench writes; else UsageError naming what is there."""
    if str(out) == "":
        raise UsageError("--out is empty; give a folder (use . for this one)")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} exists and is not a folder; give a folder")
    manifest = _manifest(out)
    ours = manifest is not None and manifest.get("written_by") == "plan-bench"
    if not ours and manifest is not None and manifest.get("written_by"):
        raise UsageError(f"--out {out} holds the results of `stepzoo "
                         f"{manifest['written_by']}` (manifest.json); give a new or empty "
                         "folder")
    # Without plan-bench's manifest, even a file of one of its names is someone else's.
    foreign = [n for n in _entries(out) if not ours or n not in OWN]
    if foreign:
        more = f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
        raise UsageError(f"--out {out} holds files plan-bench did not write "
                         f"({', '.join(foreign[:3])}{more}); give a new or empty folder")
    return out


def start(out: Path, settings: dict, resume: bool, overwrite: bool) -> dict[str, dict]:
    """The finished rows to keep, by part name (empty: a fresh start), with the lock held.
    `settings` is what makes two benches the same (queries, integrators, runs, seeds,
    planner config): --resume continues only the same bench."""
    if resume and overwrite:
        raise UsageError("--resume and --overwrite contradict each other (continue the "
                         "bench, or discard it); give one")
    check_out(out)
    holds = _entries(out)
    if not holds:
        if resume:
            raise UsageError(f"--resume: {out} holds no plan-bench to continue; leave out "
                             "--resume to start one")
        return {}
    if overwrite:
        for name in holds:
            path = out / name
            shutil.rmtree(path) if path.is_dir() else path.unlink()
        return {}
    if not resume:
        raise UsageError(f"{out} already holds a plan-bench ({', '.join(holds)}); pass "
                         "--resume to continue it or --overwrite to start again")
    manifest = _manifest(out) or {}
    if manifest.get("settings") != json.loads(to_json(settings)):
        raise UsageError(f"--resume: {out} holds a plan-bench of other queries, integrators, "
                         "runs or planner settings; resume with the same command, or give a "
                         "new --out")
    return finished(out)


def finished(out: Path) -> dict[str, dict]:
    """The rows of every finished run in `out`, by part name; a part cut off mid-write
    cannot exist (parts are renamed into place), so every file read is whole."""
    parts = Path(out) / PARTS
    return {p.stem: json.loads(p.read_text()) for p in sorted(parts.glob("*.json"))}


def save(out: Path, name: str, row: dict) -> None:
    """One finished run, atomically."""
    atomic_write(Path(out) / PARTS / f"{name}.json", json.dumps(row) + "\n")


def _entries(out: Path) -> list[str]:
    """The names in `out`, less the lock and the temporary files of writes cut off."""
    if not out.is_dir():
        return []
    return sorted(p.name for p in out.iterdir()
                  if p.name != LOCK and not (p.name.startswith(".") and
                                             p.name.endswith(".tmp")))


def _manifest(out: Path) -> dict | None:
    try:
        data = json.loads((out / "manifest.json").read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None
