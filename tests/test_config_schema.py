"""The generic config schema: every mistake of a table named at once in the house's words, and
a fingerprint that only what differs from the defaults decides."""
from typing import Annotated

import pytest

from stepzoo.config_schema import Field, Schema, check, quantity, sha256
from stepzoo.errors import UsageError

Step = Annotated[float, quantity("a step size", "s", "round-off below, the horizon above",
                                 gt=0.0, le=100.0)]
Count = Annotated[int, quantity("a number of steps", "", "at least one", ge=1)]


class Inner(Schema):
    h: tuple[Step, ...] = Field((0.1,), description="steps to try [s]")
    rounds: Count = Field(5, description="timed repeats")


class Outer(Schema):
    horizon: Step = Field(1.0, description="length of a run [s]")
    estimate: str = Field("max", description="which error")
    inner: Inner = Inner()


def test_a_table_is_read_by_keyword_with_its_defaults():
    cfg = check(Outer, {"horizon": 2, "inner": {"h": [0.5, 1.0]}}, "a.toml")
    assert cfg == Outer(horizon=2.0, inner=Inner(h=(0.5, 1.0)))
    assert cfg.inner.rounds == 5 and isinstance(cfg.horizon, float)


def test_every_mistake_is_one_line_naming_its_key_unit_and_reason():
    with pytest.raises(UsageError) as err:
        check(Outer, {"horizon": 0, "estimat": "final", "inner": {"h": [0.1, 200.0],
                                                                  "rounds": 2.5, "x": 1}},
              "a.toml")
    lines = str(err.value).splitlines()
    assert len(lines) == 5 and all(ln.startswith("a.toml: ") for ln in lines)
    text = str(err.value)
    assert ("horizon must be a step size: a number in (0, 100] s (round-off below, the "
            "horizon above), got 0") in text
    assert "every inner.h must be a step size" in text and "got 200.0" in text
    assert "inner.rounds must be a number of steps: a whole number >= 1" in text
    assert "unknown key 'estimat'; known: estimate, horizon, inner (did you mean estimate?)" \
        in text
    assert "unknown key inner.x; known: h, rounds" in text


def test_a_string_is_not_a_number_nor_a_bool_a_count():
    with pytest.raises(UsageError, match=r"horizon must be a step size.*got '1'") as err:
        check(Outer, {"horizon": "1", "inner": {"rounds": True}}, "f")
    assert "inner.rounds must be a number of steps" in str(err.value)


def test_writing_a_default_out_keeps_the_fingerprint():
    plain = check(Outer, {"horizon": 2.0}, "f")
    spelled = check(Outer, {"horizon": 2, "estimate": "max", "inner": {"rounds": 5}}, "f")
    assert sha256(plain) == sha256(spelled)
    assert sha256(plain) != sha256(check(Outer, {"horizon": 2.0, "inner": {"rounds": 6}}, "f"))
    assert sha256(check(Outer, {}, "f")) == sha256(Outer())


def _tables(model, seen=None):
    """`model` and every table declared inside it."""
    import typing
    seen = seen if seen is not None else {}
    if model.__name__ in seen:
        return seen
    seen[model.__name__] = model
    for info in model.model_fields.values():
        stack = [info.annotation]
        while stack:
            t = stack.pop()
            if isinstance(t, type) and issubclass(t, Schema):
                _tables(t, seen)
            stack.extend(typing.get_args(t))
    return seen


def test_every_key_of_every_kind_has_a_doc_line_and_every_range_a_reason():
    from stepzoo.config_schema import KINDS, kind_model
    found = set()
    for kind in KINDS:
        try:
            root = kind_model(kind)
        except AttributeError:       # the planner's PlannerParams comes with branch planner
            assert kind == "planner"
            continue
        for table in _tables(root).values():
            if not table.model_fields:       # named keys alone ([params.<name>]): none to doc
                continue
            properties = table.model_json_schema()["properties"]
            for key, info in table.model_fields.items():
                found.add(f"{table.__name__}.{key}")
                assert info.description, f"{kind}: {table.__name__}.{key} has no doc line"
                text = repr(properties[key])
                if any(b in text for b in ("'minimum'", "'maximum'", "'exclusiveM")):
                    assert "'reason'" in text, f"{table.__name__}.{key}: a range without reason"
    # The keys a newcomer had to find in the tests and envelope.toml are declared.
    assert {"Stability.h_probe_max", "Chunks.points", "Stability.growth",
            "Trajectories.fractions", "Trajectories.past_limit"} <= found


def _ranged_bases(annotation, tables):
    """(base type, kind) of every Annotated[base, ranged(kind)] inside `annotation`; the
    tables met on the way go into `tables`."""
    import typing
    from stepzoo.config_schema import ranged
    from stepzoo.validate import RANGES
    if typing.get_origin(annotation) is Annotated:
        base, *meta = typing.get_args(annotation)
        yield from ((base, kind) for kind in RANGES if any(m is ranged(kind) for m in meta))
        yield from _ranged_bases(base, tables)
    elif isinstance(annotation, type) and issubclass(annotation, Schema):
        tables.append(annotation)
    else:
        for arg in typing.get_args(annotation):
            yield from _ranged_bases(arg, tables)


def test_a_field_of_a_shared_range_is_whole_exactly_where_the_range_is():
    # The shared ranges (validate.RANGES) are declared as Annotated[int or float, ranged(k)]:
    # an int base where the range is whole, so the file refuses 2.5 where the flag does.
    import typing
    from stepzoo.config_schema import KINDS, kind_model
    from stepzoo.validate import RANGES
    tables = [kind_model(kind) for kind in KINDS if kind != "suite"]   # suite: sweep's keys
    seen, found = set(), []
    while tables:
        table = tables.pop()
        if table in seen:
            continue
        seen.add(table)
        for hint in typing.get_type_hints(table, include_extras=True).values():
            found += _ranged_bases(hint, tables)
    assert {"step", "rounds", "cell"} <= {kind for _, kind in found}
    wrong = [(base, kind) for base, kind in found if (base is int) != RANGES[kind].whole]
    assert not wrong, wrong
