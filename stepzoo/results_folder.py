"""A results folder has one writer at a time and holds one command's results. `writing(folder,
kind)` holds a lock file in the folder while a command writes there: a second writer is
refused in one line, and since the operating system drops the lock of a process that dies
(flock), a killed writer never leaves a stale lock behind. A folder that holds another
command's results (a plan in a sweep folder, say) is refused before anything is written."""
from __future__ import annotations

import contextlib
from pathlib import Path

from filelock import FileLock, Timeout

from stepzoo.errors import UsageError

LOCK = ".stepzoo.lock"
# What each command leaves in its folder; any one of them marks the folder as that kind's.
# plan-bench first: its folder holds a runs.parquet too.
MARKS = {
    "plan-bench": ("parts",),
    "sweep": ("chunks", "runs.parquet"),
    "plan": ("plan.json", "summary.json"),
    "report": ("index.html",),
    "run": ("sweep", "plans", "report"),
}


def kind_of(folder) -> str | None:
    """The command whose results `folder` holds (a key of MARKS), or None."""
    folder = Path(folder)
    for kind, marks in MARKS.items():
        if any((folder / m).exists() for m in marks):
            return kind
    return None


def check_kind(folder, kind: str, flag: str = "--out") -> Path:
    """`folder` if it is, or can become, a folder of `kind`'s results; else UsageError."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"{flag} {folder} exists and is not a folder; give a folder")
    other = kind_of(folder)
    if other not in (None, kind):
        found = next(m for m in MARKS[other] if (folder / m).exists())
        raise UsageError(f"{flag} {folder} holds the results of `stepzoo {other}` ({found}), "
                         f"not of `stepzoo {kind}`; give another {flag} (or remove that folder "
                         "first)")
    return folder


@contextlib.contextmanager
def writing(folder, kind: str, flag: str = "--out"):
    """Create `folder` if needed and hold its lock while the block writes into it."""
    folder = check_kind(folder, kind, flag)
    folder.mkdir(parents=True, exist_ok=True)
    lock = FileLock(folder / LOCK, blocking=False)
    try:
        lock.acquire()
    except Timeout:
        raise UsageError(f"{folder} is in use by another stepzoo command (it holds "
                         f"{folder / LOCK}); wait for that one to finish, or give another "
                         f"{flag}") from None
    try:
        check_kind(folder, kind, flag)      # a writer that finished just before may have
        yield folder                        # been another command
    finally:
        lock.release()


def check_file_target(path, flag: str = "--out") -> Path:
    """`path` if a command may write a file there: nothing there yet, or a regular file (a
    folder, a device such as /dev/null, a link or a pipe is refused, never replaced)."""
    path = Path(path)
    if path.is_symlink() or (path.exists() and not path.is_file()):
        what = "a folder" if path.is_dir() and not path.is_symlink() else \
            "a link" if path.is_symlink() else "not a regular file"
        raise UsageError(f"{flag} {path} is {what}; give the name of a regular file, such as "
                         "tuned.toml")
    return path
