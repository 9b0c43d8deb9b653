"""One declarative schema per config file kind: each key's type, default, range (with its unit
and the reason for its bounds) and doc line, declared once as a pydantic model. `check`
validates a file's table against it, naming every mistake at once; `sha256` fingerprints a
config by what it sets off the defaults; `kinds` lists the root models for the docs."""
from __future__ import annotations

import difflib
import hashlib
import json
import types
import typing
from typing import Annotated, Literal

import pydantic
from pydantic import ConfigDict, Field
from pydantic.fields import FieldInfo

from stepzoo.errors import UsageError


class Schema(pydantic.BaseModel):
    """A config table: frozen (a config read is a value), unknown keys refused, types strict
    (TOML's 1 is a number, "1" is not), infinities and NaN refused."""
    model_config = ConfigDict(frozen=True, extra="forbid", strict=True, allow_inf_nan=False)


def quantity(what: str, unit: str, reason: str, *, whole: bool = False, **bounds):
    """A number type with its range: `what` names it in messages ("a step size"), `bounds`
    are pydantic's ge/gt/le/lt in `unit`, `reason` says why they are where they are. Declare a
    field as `h: Step = Field(0.1, description="...")`."""
    extra = {"what": what, "unit": unit, "reason": reason}
    return Annotated[int if whole else float, Field(json_schema_extra=extra, **bounds)]


def check(model_cls: type[Schema], data: dict, where: str) -> Schema:
    """`data` (a file's table) as a `model_cls`; UsageError with one line per mistake, each
    starting with `where` (the file, or the table in it)."""
    try:
        return model_cls.model_validate(_tuples(data))
    except pydantic.ValidationError as err:
        raise UsageError("\n".join(f"{where}: {line}" for line in mistakes(model_cls, err)))


def mistakes(model_cls: type[Schema], err: pydantic.ValidationError) -> list[str]:
    """One line per error of a validation of `model_cls`, in the house's words."""
    return [_line(model_cls, e) for e in err.errors(include_url=False)]


def sha256(instance: Schema) -> str:
    """The hex sha256 of the values that differ from the defaults, as canonical JSON (sorted
    keys, no spaces): writing a default out keeps a config's fingerprint."""
    text = json.dumps(instance.model_dump(mode="json", exclude_defaults=True), sort_keys=True,
                      separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def kinds() -> dict[str, type[Schema]]:
    """Every config file kind -> its root model (imported here, lazily: the kinds live beside
    the code that reads them, above this module)."""
    from stepzoo.bench.suite import SuiteFile
    from stepzoo.bench.sweep_config import SweepFile
    from stepzoo.bench.tune import TunedFile
    from stepzoo.search.planner_config import PlannerParams
    from stepzoo.search.scenarios import ScenarioFile
    return {"sweep": SweepFile, "suite": SuiteFile, "planner": PlannerParams,
            "scenario": ScenarioFile, "tuned": TunedFile}


def describe(info: FieldInfo, annotation=None) -> str:
    """What a field takes, in words: "a step size: a number in (0, 100] s (why)" for a
    quantity, else from its type ("a whole number", "one of 'max', 'final'")."""
    extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
    annotation = annotation if annotation is not None else info.annotation
    if "what" not in extra:
        return _kind_words(annotation)
    whole = _bare(annotation) is int
    bound = {}
    for m in info.metadata:
        for name in ("ge", "gt", "le", "lt"):
            if getattr(m, name, None) is not None:
                bound[name] = getattr(m, name)
    show = (lambda v: f"{int(v)}") if whole else (lambda v: f"{v:g}")
    lo = next(((k, v) for k, v in bound.items() if k in ("ge", "gt")), None)
    hi = next(((k, v) for k, v in bound.items() if k in ("le", "lt")), None)
    kind = "whole number" if whole else "number"
    if lo and hi:
        span = (f"in {'[' if lo[0] == 'ge' else '('}{show(lo[1])}, {show(hi[1])}"
                f"{']' if hi[0] == 'le' else ')'}")
    else:
        ops = {"ge": ">=", "gt": ">", "le": "<=", "lt": "<"}
        span = " and ".join(f"{ops[k]} {show(v)}" for k, v in filter(None, (lo, hi)))
    unit = f" {extra['unit']}" if extra.get("unit") else ""
    return f"{extra['what']}: a {kind} {span}{unit} ({extra['reason']})"


# ---------------------------------------------------------------- the words of the messages

def _tuples(value):
    """TOML's arrays as tuples, so that frozen models hold hashable values."""
    if isinstance(value, dict):
        return {k: _tuples(v) for k, v in value.items()}
    if isinstance(value, list):
        return tuple(_tuples(v) for v in value)
    return value


def _lists(value):
    """Tuples back as lists, to show a value as the file wrote it."""
    if isinstance(value, tuple):
        return [_lists(v) for v in value]
    if isinstance(value, dict):
        return {k: _lists(v) for k, v in value.items()}
    return value


def _line(model_cls, e: dict) -> str:
    info, annotation, names, every = _walk(model_cls, e["loc"])
    key = ".".join(names)
    if e["type"] == "extra_forbidden":
        parent = _bare(_walk(model_cls, e["loc"][:-1])[1])
        known = sorted(_fields_of(parent)) if _is_schema(parent) else []
        close = difflib.get_close_matches(names[-1], known, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        return f"unknown key {key if len(names) > 1 else repr(key)}; known: " \
               f"{', '.join(known)}{hint}"
    if e["type"] in ("value_error", "assertion_error"):
        message = str(e.get("ctx", {}).get("error", e["msg"]))
        return f"{key}: {message}" if key else message
    if e["type"] == "missing":
        doc = f" ({info.description})" if info is not None and info.description else ""
        return f"{key} is missing{doc}; give it"
    words = describe(info, annotation) if info is not None else _error_words(e)
    return f"{'every ' if every else ''}{key} must be {words}, got {_lists(e['input'])!r}"


def _error_words(e: dict) -> str:
    """A field's expectation from the error alone (no declaration found for its place)."""
    return {"float_type": "a number", "int_type": "a whole number", "int_from_float":
            "a whole number", "bool_type": "true or false", "string_type": "a string",
            "finite_number": "a finite number", "dict_type": "a table",
            "model_type": "a table", "tuple_type": "a list"}.get(e["type"], e["msg"].lower())


def _walk(model_cls, loc):
    """Follow an error's place `loc` through the declarations: (the FieldInfo there, its
    type, the key names on the way, whether it passed a list's element). Pydantic's union
    member tags in `loc` are skipped."""
    info, cur, names, every = None, model_cls, [], False
    for part in loc:
        cur = _bare(cur)
        if isinstance(part, int) and typing.get_origin(cur) is tuple:
            cur, every = typing.get_args(cur)[0], True
            info = _annotated_info(cur) or info
        elif _is_schema(cur) and part in cur.model_fields:
            info, cur = cur.model_fields[part], cur.model_fields[part].annotation
            names.append(part)
        elif typing.get_origin(cur) is dict and isinstance(part, str):
            cur = typing.get_args(cur)[1]
            info = _annotated_info(cur) or info
            names.append(part)
        elif _is_schema(cur) or not isinstance(part, str):
            names.append(str(part))           # an unknown key, or a place not declared
            info, cur = None, None
        else:
            cur = _member(cur, part)
    return info, cur, names, every


def _member(union, tag: str):
    """The member of a union type that pydantic's error place names by `tag`."""
    for arg in typing.get_args(union):
        if tag in (getattr(arg, "__name__", ""), str(arg).replace("typing.", "")):
            return arg
    return union


def _is_schema(cls) -> bool:
    return isinstance(cls, type) and issubclass(cls, Schema)


def _annotated_info(annotation) -> FieldInfo | None:
    """The Field declared in an Annotated[...] element type (a quantity), if any."""
    if typing.get_origin(annotation) is Annotated:
        infos = [a for a in typing.get_args(annotation)[1:] if isinstance(a, FieldInfo)]
        if infos:
            return FieldInfo.merge_field_infos(*infos, annotation=typing.get_args(annotation)[0])
    return None


def _bare(annotation):
    """The type under Annotated[...] and Optional[...]."""
    while True:
        origin = typing.get_origin(annotation)
        if origin is Annotated:
            annotation = typing.get_args(annotation)[0]
        elif origin in (typing.Union, types.UnionType):
            rest = [a for a in typing.get_args(annotation) if a is not type(None)]
            if len(rest) != 1:
                return annotation
            annotation = rest[0]
        else:
            return annotation


def _fields_of(model) -> list[str]:
    return [info.alias or name for name, info in model.model_fields.items()]


def _kind_words(annotation) -> str:
    bare = _bare(annotation)
    origin = typing.get_origin(bare)
    if origin is Literal:
        return "one of " + ", ".join(map(repr, typing.get_args(bare)))
    if origin is tuple:
        return f"a list of {_plural(typing.get_args(bare)[0])}"
    if origin is dict:
        return f"a table of {_plural(typing.get_args(bare)[1])}"
    if isinstance(bare, type) and issubclass(bare, Schema):
        return "a table"
    return {float: "a number", int: "a whole number", bool: "true or false",
            str: "a string"}.get(bare, str(bare))


def _plural(annotation) -> str:
    words = _kind_words(annotation)
    return {"a number": "numbers", "a whole number": "whole numbers", "a string": "strings",
            "true or false": "true or false values", "a table": "tables"}.get(words, words)

