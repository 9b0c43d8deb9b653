"""Checks of user input shared by the commands: each failure is one UsageError line."""
import math

from bench.errors import UsageError


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
