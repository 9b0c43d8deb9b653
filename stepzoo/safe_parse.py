"""TOML and JSON text parsed for every reader of user files (configs, queries, tuned configs,
plan requests, manifests): nesting deeper than Python's recursion allows is the parser's own
decode error, which each reader already turns into its one line, not a RecursionError."""
import json
import tomllib

NESTING = "nested deeper than a stepzoo file ever is (a few levels)"


def toml_loads(text: str) -> dict:
    """tomllib.loads; tomllib.TOMLDecodeError also for runaway nesting."""
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise tomllib.TOMLDecodeError(f"{NESTING}; flatten the tables and arrays") from None


def json_loads(text: str | bytes):
    """json.loads; json.JSONDecodeError also for runaway nesting."""
    try:
        return json.loads(text)
    except RecursionError:
        if isinstance(text, bytes):
            text = text.decode("utf-8", "replace")
        raise json.JSONDecodeError(f"{NESTING}; flatten the arrays and objects", text,
                                   0) from None
