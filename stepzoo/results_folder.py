"""A results folder has one writer at a time and holds one command's results. `claim(folder,
kind)` checks the folder, creates it if needed and holds its lock file while a command writes
there: a second writer is refused in one line, and since the operating system drops the lock
(flock) of a process that dies, a killed writer never leaves a stale lock behind. A folder is
written only where the user meant it and only over what stepzoo wrote: an empty name, a
folder of another command's results or of anything stepzoo did not write (also where a link
as the folder's own name leads) is refused, in one line, before anything is written
(docs/folders-and-server.md).
`replacing(folder, kind)` writes a folder's results anew beside it and swaps them in whole."""
from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import json
import os
import re
import shutil
import stat
import tempfile
from pathlib import Path

from stepzoo.errors import UsageError

LOCK = ".stepzoo.lock"      # holds the kind of the command that took it last
MANIFEST = "manifest.json"  # its "written_by" names the command that wrote the folder
# What each command leaves in its folder; any one of them marks the folder as that kind's
# where the folder records no writer (written_by).
MARKS = {
    "plan-bench": ("ompl",),
    "sweep": ("chunks", "runs.parquet"),
    "plan": ("plan.json", "summary.json"),
    "report": ("index.html",),
    "run": ("sweep", "plans", "report"),
    "export": ("schedule.csv",),
}
SHOWN = 3                   # entries a refusal names


def _temporary(name: str) -> bool:
    """A file or folder being written (atomic_write's `.NAME.XXXX.tmp`, a staged folder)."""
    return name.startswith(".") and name.endswith(".tmp")


def kind_of(folder) -> str | None:
    """The command whose results `folder` holds (a key of MARKS), or None."""
    folder = Path(folder)
    for kind, marks in MARKS.items():
        if any((folder / m).exists() for m in marks):
            return kind
    return None


def written_by(folder) -> str | None:
    """The command that wrote `folder` as the folder records it: its manifest's "written_by";
    without a manifest, the kind in its lock file (a writer stopped before its manifest).
    None: not recorded (a manifest.json without "written_by", or none and no lock)."""
    folder = Path(folder)
    manifest = folder / MANIFEST
    if manifest.exists() or manifest.is_symlink():
        try:
            said = json.loads(manifest.read_text()).get("written_by") \
                if manifest.is_file() and not manifest.is_symlink() else None
        except (OSError, ValueError, AttributeError, RecursionError):
            said = None
        return said if isinstance(said, str) else None
    try:
        said = (folder / LOCK).read_text().strip()
    except (OSError, UnicodeDecodeError):
        return None
    return said if said in MARKS else None


def _listing(names) -> str:
    names = sorted(names)
    return ", ".join(names[:SHOWN]) + (f" and {len(names) - SHOWN} more"
                                       if len(names) > SHOWN else "")


def check_path(folder, flag: str = "--out") -> Path:
    """`folder` as a Path if a command may write there: a name is given, of a folder or of
    nothing yet. Links among its parents are the user's own layout (macOS's /tmp is one) and
    followed; a name that is itself a link is followed to the folder it leads to, which is
    returned (check_kind then checks what it holds), and refused where it leads to no folder.
    Else UsageError."""
    if not str(folder).strip():
        raise UsageError(f"{flag} is empty; give the name of a folder, such as {flag} results")
    folder = Path(folder)
    if folder.is_symlink():
        real = Path(os.path.realpath(folder))
        if not real.is_dir():
            raise UsageError(f"{flag} {folder} is a symbolic link to {real}, which is not a "
                             f"folder; give a folder, such as {flag} results")
        return real
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"{flag} {folder} exists and is not a folder; give a folder")
    return folder


def check_kind(folder, kind: str, flag: str = "--out", *, overwrite: bool | None = None) -> Path:
    """`folder` (where a link as its name leads: check_path) if `kind` may write its results
    there: nothing, or what `kind` itself wrote (its manifest says so; without one, its lock
    file or its result files, MARKS). A folder of another command's results is refused; one
    of anything else too, unless `overwrite` is True and `folder` is no link (a link could
    expose any folder of other files). `overwrite` None: the command has no --overwrite
    flag."""
    given = folder
    linked = Path(folder).is_symlink()
    folder = check_path(folder, flag)
    if not folder.is_dir():
        return folder
    entries = [p.name for p in folder.iterdir() if p.name != LOCK and not _temporary(p.name)]
    if not entries:
        return folder
    # Without a recorded writer, the files it holds tell (a folder of a stepzoo that did not
    # record its writer in the manifest yet).
    writer = written_by(folder) or kind_of(folder)
    if writer == kind:
        return folder
    name = f"{flag} {given}" + (f" (a symbolic link to {folder})" if linked else "")
    if writer is not None:
        found = next((m for m in (*MARKS.get(writer, ()), MANIFEST) if (folder / m).exists()),
                     LOCK)
        raise UsageError(f"{name} holds the results of `stepzoo {writer}` ({found}), "
                         f"not of `stepzoo {kind}`; give another {flag} (or remove that folder "
                         "first)")
    if overwrite and not linked:
        return folder
    how = (f"give an empty or new {flag}, or pass --overwrite to write into it anyway"
           if overwrite is False and not linked else f"give an empty or new {flag}")
    raise UsageError(f"{name} holds files that `stepzoo {kind}` did not write "
                     f"({_listing(entries)}); {how}")


class _Lock:
    """An exclusive flock on `folder`/LOCK, not waited for; the file says `kind` once held."""

    def __init__(self, folder: Path, kind: str, flag: str):
        self.path, self.kind, self.flag = folder / LOCK, kind, flag
        self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(self.fd)
            raise UsageError(f"{folder} is in use by another stepzoo command (it holds "
                             f"{self.path}); wait for that one to finish, or give another "
                             f"{flag}") from None

    def mark(self):
        data = f"{self.kind}\n".encode()
        try:                         # written before the cut: a failure leaves it as it was
            os.pwrite(self.fd, data, 0)
            os.ftruncate(self.fd, len(data))
        except OSError as err:       # a full disk, say: name the file, as a write does not
            raise OSError(err.errno, err.strerror, str(self.path)) from None

    def release(self):
        fcntl.flock(self.fd, fcntl.LOCK_UN)
        os.close(self.fd)


@contextlib.contextmanager
def claim(folder, kind: str, flag: str = "--out", *, overwrite: bool | None = None):
    """Check `folder` for `kind` (check_kind), create it if needed and hold its lock while
    the block writes into it; yields the folder as a Path. `overwrite`: as check_kind's (the
    command's --overwrite flag; None where it has none). E.g. `with claim(args.out,
    "plan-bench", overwrite=args.overwrite) as out: ...`."""
    folder = check_kind(folder, kind, flag, overwrite=overwrite)
    folder.mkdir(parents=True, exist_ok=True)
    lock = _Lock(folder, kind, flag)
    try:
        # A writer that finished just before may have been another command.
        check_kind(folder, kind, flag, overwrite=overwrite)
        lock.mark()
        yield folder
    finally:
        lock.release()


@contextlib.contextmanager
def replacing(folder, kind: str, flag: str = "--out"):
    """claim `folder`, then yield a new empty folder beside it (hidden, `.NAME.XXXX.tmp`) to
    write the results into; when the block ends without an error, the new folder takes
    `folder`'s place in one atomic exchange and the old one is removed, so a reader, a
    failure or a kill finds the old results whole or the new ones whole, never a mix. The
    old folder must hold only what its manifest lists ("files"): nothing else is lost."""
    with claim(folder, kind, flag) as folder:
        _check_listed(folder, kind, flag)
        # A killed writer's folder; not one of a folder named alike (`report.x`'s is
        # `.report.x.XXXXXXXX.tmp`), which another command may be writing now.
        staged = re.compile(re.escape(f".{folder.name}.") + r"[a-z0-9_]{8}\.tmp")
        for stale in folder.parent.iterdir():
            if staged.fullmatch(stale.name) and stale.is_dir() and not stale.is_symlink():
                shutil.rmtree(stale, ignore_errors=True)
        new = Path(tempfile.mkdtemp(dir=folder.parent, prefix=f".{folder.name}.",
                                    suffix=".tmp"))
        try:
            yield new
            os.chmod(new, stat.S_IMODE(folder.stat().st_mode))   # mkdtemp makes 0700
            _exchange(new, folder)
        finally:
            shutil.rmtree(new, ignore_errors=True)     # the old results, or the unfinished


def _check_listed(folder: Path, kind: str, flag: str):
    try:
        files = json.loads((folder / MANIFEST).read_text()).get("files", [])
    except (OSError, ValueError, AttributeError, RecursionError):
        files = []
    keep = {LOCK, MANIFEST, *(f for f in files if isinstance(f, str))}
    extra = [p.name for p in folder.iterdir() if p.name not in keep and not _temporary(p.name)]
    if extra:
        raise UsageError(f"{flag} {folder} holds files that `stepzoo {kind}` did not write "
                         f"({_listing(extra)}), which replacing its results would lose; move "
                         f"them, or give another {flag}")


_RENAME_EXCHANGE = 2                     # renameat2's flag (Linux 3.15)
_AT_FDCWD = -100


def _exchange(a: Path, b: Path):
    """Swap the folders `a` and `b` atomically where the system can (Linux renameat2); else
    by two renames, between which `b`'s old content is at `a` alone (docs: a kill there
    leaves the old results in the hidden folder)."""
    libc = ctypes.CDLL(None, use_errno=True)
    swap = getattr(libc, "renameat2", None)
    if swap is not None:
        if swap(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
            return
        err = ctypes.get_errno()
        if err not in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
            raise OSError(err, os.strerror(err), str(b))
    old = Path(tempfile.mkdtemp(dir=b.parent, prefix=f".{b.name}.", suffix=".tmp"))
    os.rename(b, old / b.name)
    os.rename(a, b)
    os.rename(old, a)


def check_file_target(path, flag: str = "--out", *, kind: FileKind | None = None,
                      inputs=()) -> Path:
    """`path` if a command may write a file there: nothing there yet, or a regular file (a
    folder, a device such as /dev/null, a link or a pipe is refused, never replaced) that is
    none of the run's `inputs` (paths it reads) and, where `kind` is given, of the kind the
    command writes (a user's model module or config given by mistake is refused, never
    replaced)."""
    path = Path(path)
    if path.is_symlink() or (path.exists() and not path.is_file()):
        what = "a folder" if path.is_dir() and not path.is_symlink() else \
            "a link" if path.is_symlink() else "not a regular file"
        raise UsageError(f"{flag} {path} is {what}; give the name of a regular file, such as "
                         f"{kind.example if kind else 'tuned.toml'}")
    if not path.exists():
        return path
    for given in inputs:
        if given is not None and Path(given).exists() and os.path.samefile(path, given):
            raise UsageError(f"{flag} {path} is {given}, which this command reads; give a new "
                             f"file name, such as {kind.example if kind else 'out'}")
    if kind is not None and not kind.holds(path):
        raise UsageError(f"{flag} {path} is not {kind.words}, which this command writes, and "
                         f"would be lost; give a new file name, such as {kind.example}")
    return path


class FileKind:
    """The kind of file a command writes, so that it replaces only a file of that kind:
    `words` names it, `example` is a file name to suggest, `holds(path)` tells one."""

    def __init__(self, words: str, example: str, holds):
        self.words, self.example, self._holds = words, example, holds

    def holds(self, path: Path) -> bool:
        """Whether the file `path` is of this kind (an unreadable one: OSError, which the
        command names as it does every file it cannot read)."""
        try:
            return bool(self._holds(path))
        except ValueError:                  # not TOML, not text: another kind of file
            return False


def _toml_with(*keys):
    def holds(path: Path) -> bool:
        from stepzoo.safe_parse import toml_loads
        table = toml_loads(path.read_text())
        return all(k in table for k in keys)
    return holds


def _csv_headed(*columns):
    def holds(path: Path) -> bool:
        with open(path, encoding="utf-8") as fh:
            return fh.readline().rstrip("\r\n").split(",")[:len(columns)] == list(columns)
    return holds


# What `stepzoo tune` writes (a planner config: method and h), and `verdict --csv`.
TUNED_FILE = FileKind("a tuned config (a TOML file with method and h)", "tuned.toml",
                      _toml_with("method", "h"))
VERDICT_CSV = FileKind("a verdict table (a CSV file of columns method, h, point, ...)",
                       "verdict.csv", _csv_headed("method", "h", "point"))
