"""One declarative schema per config file kind: each key's type, default, range (with its unit
and the reason for its bounds) and doc line, declared once as a pydantic model. `check`
validates a file's table against it, naming every mistake at once; `sha256` fingerprints a
config by what it sets off the defaults; `kinds` lists the root models for the docs."""
from __future__ import annotations

import difflib
import functools
import hashlib
import importlib
import json
import types
import typing
from typing import Annotated, Any, Literal, TypeVar

import pydantic
from pydantic import ConfigDict, Discriminator, Field, Tag
from pydantic_core import ErrorDetails
from pydantic.fields import FieldInfo
from pydantic.json_schema import JsonDict

from stepzoo.errors import UsageError
from stepzoo.ranges import BOUNDS, Range


class Schema(pydantic.BaseModel):
    """A config table: frozen (a config read is a value), unknown keys refused, types strict
    (TOML's 1 is a number, "1" is not), infinities and NaN refused."""
    model_config = ConfigDict(frozen=True, extra="forbid", strict=True, allow_inf_nan=False)


S = TypeVar("S", bound=Schema)


def quantity(what: str, unit: str, reason: str, *, ge: float | None = None,
             gt: float | None = None, le: float | None = None,
             lt: float | None = None) -> FieldInfo:
    """The range of a number type: `what` names it in messages ("a step size"; "": the number
    alone), the bounds are pydantic's ge/gt/le/lt in `unit`, `reason` says why they are where
    they are. Declare the type as `Step = Annotated[float, quantity(...)]` (int: a whole
    number) and a field as `h: Step = Field(0.1, description="...")`."""
    return of_range(Range(what, unit, reason, ge=ge, gt=gt, le=le, lt=lt))


def of_range(r: Range) -> FieldInfo:
    """The pydantic Field of the Range `r`, to annotate a number type with (its `whole` is the
    type's: int or float)."""
    extra: JsonDict = {"what": r.what, "unit": r.unit, "reason": r.reason}
    return Field(json_schema_extra=extra, **r.bounds())


@functools.cache
def ranged(kind: str) -> FieldInfo:
    """The Field of validate.RANGES[kind], to annotate a number type with (int where the range
    is whole, else float): a config file's field checked against the same range, in the same
    words, as the command line's flag."""
    from stepzoo.validate import RANGES
    return of_range(RANGES[kind])


def optional(model: type[Schema], name: str, doc: str, **more: Any) -> type[Schema]:
    """A table of `model`'s keys, each optional (a required one None when not given), plus
    the fields `more` (name=(type, Field)): a table whose keys fill in or replace another's,
    as a suite's top level and problems do a sweep config's."""
    fields: dict[str, Any] = {
        key: (typing.Optional[info.annotation], FieldInfo.merge_field_infos(info, default=None))
        if info.is_required() else (info.annotation, info)
        for key, info in model.model_fields.items()}
    return pydantic.create_model(name, __base__=Schema, __doc__=doc, __module__=model.__module__,
                                 **fields, **more)


def _shape(value) -> str:
    if isinstance(value, (dict, pydantic.BaseModel)):
        return "table"
    return "list" if isinstance(value, (list, tuple)) else "value"


# A key a file may write in several shapes, `value` (a number or a string), `list` or `table`,
# each its own type tagged with its shape (`Annotated[X, Tag("list")]`): the shape written
# picks the one that validates it, so that one mistake is one line (not one per shape it might
# have been). Declare it as `Annotated[Annotated[A, Tag("value")] | ..., BY_SHAPE]`.
BY_SHAPE = Discriminator(_shape)


def check(model_cls: type[S], data: dict, where: str) -> S:
    """`data` (a file's table) as a `model_cls`; UsageError with one line per mistake, each
    starting with `where` (the file, or the table in it). A file that is one mistake whole
    (empty, or a config of another kind) is one line, not one per key it lacks."""
    try:
        return model_cls.model_validate(_tuples(data))
    except pydantic.ValidationError as err:
        lines = mistakes(model_cls, err)
        if len(lines) > 1 and isinstance(data, dict):
            lines = _whole_file(model_cls, data) or lines
        raise UsageError("\n".join(f"{where}: {line}" for line in lines)) from None


def mistakes(model_cls: type[Schema], err: pydantic.ValidationError) -> list[str]:
    """One line per error of a validation of `model_cls`, in the house's words; a value that
    fits none of a union's types (a number, a whole number or true or false) is one line."""
    lines: list[str | None] = []
    expected: dict[tuple[str, str], tuple[int, list[str]]] = {}
    for e in err.errors(include_url=False):
        place = _type_mistake(model_cls, e)
        if place is None:
            lines.append(_line(model_cls, e))
            continue
        key, words, got = place
        if (key, got) in expected:           # another member of the same union
            expected[key, got][1].append(words)
        else:
            expected[key, got] = (len(lines), [words])
            lines.append(None)
    for (key, got), (at, alternatives) in expected.items():
        lines[at] = f"{key} must be {' or '.join(dict.fromkeys(alternatives))}, got {got}"
    return [line for line in lines if line is not None]


def _whole_file(model_cls: type[Schema], data: dict) -> list[str] | None:
    """The one line for a table that is wrong as a whole: empty, or with only the keys of
    another config kind (a sweep config given where a tuned config belongs); else None."""
    mine = next((k for k in KINDS if kind_model(k) is model_cls), None)
    what = f"a {mine} config" if mine else "this table"
    required = [k for k, info in model_cls.model_fields.items() if info.is_required()]
    if not data:
        return [f"is empty; {what} needs at least {' and '.join(required)}"]
    if set(data) <= set(model_cls.model_fields):
        return None
    other = next((k for k in KINDS if k != mine and set(data) <= set(kind_model(k).model_fields)),
                 None)
    if other is None:
        return None
    return [f"is a {other} config, not {what} (it has {_listing(sorted(data))} and lacks "
            f"{', '.join(k for k in required if k not in data) or 'none'}); give {what}"]


def _listing(names: list[str], shown: int = 3) -> str:
    return ", ".join(names[:shown]) + (f" and {len(names) - shown} more keys"
                                       if len(names) > shown else "")


def differing(instance: object) -> dict:
    """The values of a Schema (or pydantic dataclass) `instance` that differ from their
    defaults, nested tables alike, as JSON-ready data; fields declared `exclude=True` (those
    that decide no result, such as a file's path) are left out."""
    kind: type = type(instance)       # as `type`, which mypy reads as hashable
    return _adapter(kind).dump_python(instance, mode="json", exclude_defaults=True)


@functools.cache
def _adapter(cls: type) -> pydantic.TypeAdapter:
    return pydantic.TypeAdapter(cls)


def sha256(instance: object) -> str:
    """The hex sha256 of differing(instance) as canonical JSON (sorted keys, no spaces):
    writing a default out keeps a config's fingerprint."""
    text = json.dumps(differing(instance), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


# Every config file kind -> its root model, by name: the kinds live beside the code that
# reads them, in packages above this one, which may not be imported from here (as with entry
# points, a name is resolved when asked for).
KINDS = {"sweep": "stepzoo.bench.sweep.config:SweepConfig",
         "suite": "stepzoo.bench.sweep.suite:SuiteFile",
         "planner": "stepzoo.search.planner.config:PlannerParams",
         "scenario": "stepzoo.search.world.scenarios:ScenarioFile",
         "tuned": "stepzoo.tuned_file:TunedFile",
         "queries": "stepzoo.search.world.query_file:QueryFile"}


def kinds() -> dict[str, type[Schema]]:
    """Every config file kind ("sweep", "suite", "planner", "scenario", "tuned", "queries":
    each of a query file's objects) -> its root model, from which the docs' config reference
    is generated."""
    return {kind: kind_model(kind) for kind in KINDS}


def kind_model(kind: str) -> type[Schema]:
    """The root model of one config file kind of KINDS."""
    module, _, name = KINDS[kind].partition(":")
    return getattr(importlib.import_module(module), name)


def describe(info: FieldInfo, annotation: Any = None) -> str:
    """What a field takes, in words: "a step size: a number in (0, 100] s (why)" for a
    quantity, else from its type ("a whole number", "one of 'max', 'final'")."""
    annotation = annotation if annotation is not None else info.annotation
    inner = _annotated_info(_bare_optional(annotation)) if not _ranged(info) else None
    if inner is not None:                     # Optional[quantity]: the range is inside
        info, annotation = inner, inner.annotation
    extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
    if "reason" not in extra:
        return _kind_words(annotation)
    bounds = {name: getattr(m, name) for m in info.metadata for name in BOUNDS
              if getattr(m, name, None) is not None}
    return Range(str(extra["what"]), str(extra["unit"]), str(extra["reason"]),
                 _bare(annotation) is int, **bounds).words()


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


def _line(model_cls: type[Schema], e: ErrorDetails) -> str:
    """The line of a mistake that is not a value's type or range (_type_mistake's)."""
    info, annotation, names, every = _walk(model_cls, e["loc"])
    key = ".".join(names)
    if e["type"] == "extra_forbidden":
        parent = _bare(_walk(model_cls, e["loc"][:-1])[1])
        known = sorted(parent.model_fields) if _is_schema(parent) else []
        close = difflib.get_close_matches(names[-1], known, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        return f"unknown key {key if len(names) > 1 else repr(key)}; known: " \
               f"{', '.join(known)}{hint}"
    if e["type"] in ("value_error", "assertion_error"):
        # A validator's message reads after the key ("must be {min, max, num} with min <=
        # max"), or names the keys itself ("newton.rtol and newton.atol are both 0").
        message = str(e.get("ctx", {}).get("error", e["msg"]))
        return message if not key or message.startswith(key) else f"{key} {message}"
    if e["type"] == "missing" and e["loc"] and isinstance(e["loc"][-1], int):
        info, annotation, names, _ = _walk(model_cls, e["loc"][:-1])    # a list too short
        words = describe(info, annotation) if info is not None else "longer"
        return f"{'.'.join(names)} must be {words}, got {_lists(e['input'])!r}"
    doc = f" ({info.description})" if info is not None and info.description else ""
    return f"lacks {key}{doc}"


def _type_mistake(model_cls: type[Schema], e: ErrorDetails) -> tuple[str, str, str] | None:
    """(the key, what it must be, what it got) of a value of the wrong type or range; None
    for another mistake (a missing or unknown key, a validator's own message)."""
    if e["type"] in ("extra_forbidden", "value_error", "assertion_error", "missing"):
        return None
    info, annotation, names, every = _walk(model_cls, e["loc"])
    words = describe(info, annotation) if info is not None else _error_words(e)
    return f"{'every ' if every else ''}{'.'.join(names)}", words, repr(_lists(e["input"]))


def _error_words(e: ErrorDetails) -> str:
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
            args = typing.get_args(cur)
            if len(args) == 2 and args[1] is Ellipsis:
                cur, every = args[0], True
            else:                             # a fixed list: name the place, key[i]
                cur = args[part] if part < len(args) else args[-1]
                names[-1:] = [f"{names[-1] if names else ''}[{part}]"]
            info = _annotated_info(cur) or info
        elif _is_schema(cur) and part in cur.model_fields:
            info, cur = cur.model_fields[part], cur.model_fields[part].annotation
            names.append(part)
        elif typing.get_origin(cur) is dict and isinstance(part, str):
            cur = typing.get_args(cur)[1]
            info = _annotated_info(cur) or info
            names.append(part)
        elif _is_schema(cur) and _extra_type(cur) is not None:
            cur = _extra_type(cur)            # a key of a table that takes keys of its own
            info = _annotated_info(cur)
            names.append(part)
        elif _is_schema(cur) or not isinstance(part, str):
            names.append(str(part))           # an unknown key, or a place not declared
            info, cur = None, None
        else:
            cur = _member(cur, part)
    return info, cur, names, every


def _extra_type(model):
    """The type of the values of the keys a table takes beyond its fields (None: it takes
    none)."""
    if model.model_config.get("extra") != "allow":
        return None
    hint = typing.get_type_hints(model, include_extras=True).get("__pydantic_extra__")
    return typing.get_args(hint)[1] if hint is not None else None


def _member(union, tag: str):
    """The member of a union type that pydantic's error place names by `tag`."""
    for arg in typing.get_args(union):
        tags = [m.tag for m in typing.get_args(arg)[1:] if isinstance(m, Tag)] \
            if typing.get_origin(arg) is Annotated else []
        if tag in (*tags, getattr(arg, "__name__", ""), str(arg).replace("typing.", "")):
            return arg
    return union


def _ranged(info: FieldInfo) -> bool:
    return isinstance(info.json_schema_extra, dict) and "reason" in info.json_schema_extra


def _bare_optional(annotation):
    """X of Optional[X] (X itself otherwise), keeping X's Annotated[...] metadata."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        rest = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(rest) == 1:
            return rest[0]
    return annotation


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


def _kind_words(annotation) -> str:
    bare = _bare(annotation)
    origin = typing.get_origin(bare)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_kind_words(a) for a in typing.get_args(bare) if a is not type(None))
    if origin is Literal:
        return "one of " + ", ".join(map(repr, typing.get_args(bare)))
    if origin is tuple:
        args = typing.get_args(bare)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_plural(args[0])}"
        kinds = {_plural(a) for a in args}
        return f"a list of {len(args)} {kinds.pop() if len(kinds) == 1 else 'values'}"
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

