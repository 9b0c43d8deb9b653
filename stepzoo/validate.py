"""Checks of user input shared by the commands: each failure is one UsageError line."""
import math
import tomllib
from pathlib import Path

from stepzoo.errors import UsageError


def positive(name: str, value: float) -> float:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise UsageError(f"{name} must be a positive number of seconds or metres, got {value!r}")
    return float(value)


def lookup(kind: str, fetch, name):
    """Call fetch(name) and turn its KeyError (which names the known choices) into a UsageError."""
    try:
        return fetch(name)
    except KeyError as err:
        raise UsageError(f"{err.args[0]} (choose a {kind} from that list)") from None


def read_toml(path, what: str, hint: str) -> dict:
    """The table of a TOML file; a missing file or bad TOML is one UsageError line (`what`
    names the file's role, `hint` says what to give instead)."""
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{what} {path} not found; {hint}")
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise UsageError(f"{path}: not valid TOML ({err}); fix the file") from None
