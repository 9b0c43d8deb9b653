"""Writing results: tables as text or JSON to stdout, a user's prints kept off it, and atomic
file writes."""
import contextlib
import json
import os
import sys
import tempfile
import threading
from pathlib import Path

_LOCK = threading.Lock()
_DEPTH = 0
_SAVED = None


@contextlib.contextmanager
def prints_to_stderr():
    """While inside, print() goes to stderr, so that stdout holds the command's output alone
    (--format json). Safe when several threads (a sweep compiling methods side by side, each
    tracing the user's model) enter and leave in any order: the first in saves stdout and
    the last out puts it back, where nested contextlib.redirect_stdout calls leaving out of
    order would leave stdout pointing at stderr for the rest of the command."""
    global _DEPTH, _SAVED
    with _LOCK:
        if _DEPTH == 0:
            _SAVED, sys.stdout = sys.stdout, sys.stderr
        _DEPTH += 1
    try:
        yield
    finally:
        with _LOCK:
            _DEPTH -= 1
            if _DEPTH == 0:
                sys.stdout, _SAVED = _SAVED, None


def atomic_write(path, data: bytes | str) -> Path:
    """Write to a temporary file beside `path`, then rename: readers never see half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mode = "wb" if isinstance(data, bytes) else "w"
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode) as fh:
            fh.write(data)
        os.chmod(tmp, 0o644)           # mkstemp makes 0600; results are for everyone to read
        os.replace(tmp, path)
    except OSError as err:             # a write error names no file: name the one meant
        Path(tmp).unlink(missing_ok=True)
        raise OSError(err.errno, err.strerror, str(path)) from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_file(path, data: bytes) -> Path:
    """Write `data` to `path` (no rename: for files inside a folder that is itself renamed
    into place); an error names `path`, as a failed write() alone does not."""
    path = Path(path)
    try:
        path.write_bytes(data)
    except OSError as err:
        raise OSError(err.errno, err.strerror, str(path)) from None
    return path


def to_json(obj) -> str:
    return json.dumps(obj, indent=2, allow_nan=False)


def text_table(rows: list[dict], columns: list[str]) -> str:
    """Left-aligned plain-text table; None prints as '-', floats with 4 significant digits."""
    def cell(v):
        if v is None:
            return "-"
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)
    cells = [[cell(r.get(c)) for c in columns] for r in rows]
    widths = [max([len(c)] + [len(row[i]) for row in cells]) for i, c in enumerate(columns)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(columns, widths))]
    lines += ["  ".join(v.ljust(w) for v, w in zip(row, widths)) for row in cells]
    return "\n".join(line.rstrip() for line in lines)
