"""Traced programs kept across processes (the driver's, and the planner's call of the tree's
moves): a program traced once (`jax.export`) is written into a folder the caller names
(`keep_in`), and a later process that runs the same program loads it instead of tracing the
method and the model again; XLA's own persistent cache then serves its compilation. Off until
`keep_in` is called (the `stepzoo` command keeps them beside JAX's compilation cache, a
folder of the user's that it trusts as XLA's: a kept file is read with pickle).

A program is kept only where its key holds everything that decides it: the source of every
module of the stepzoo package (its models, methods and driver), the zoo's method by name
(a Method of the registry, not a user's), the right-hand side as a function of stepzoo's by
its module, name and captured values (a user's function, or one capturing what the key
cannot name, is traced as before), the static arguments, the shapes, dtypes and weak types
of the run-time ones, and JAX's version, settings, devices and XLA_FLAGS. What it cannot
name is a stepzoo module changed at run time (a patched global): the key is its source.
Modules a function captures are named by name (JAX's and NumPy's versions are in the key)."""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib.util
import os
import pickle
import threading
import types
from pathlib import Path
from typing import Any, Callable

import jax
import jaxlib
import numpy as np
from jax import export
from jax.sharding import Mesh, NamedSharding, PartitionSpec

_folder: Path | None = None
# key -> a call of the kept program on (args, kwargs), in this process
_loaded: dict[str, Callable[[tuple, dict], Any]] = {}
_refused: set[str] = set()        # keys whose program cannot be exported (a callback, say)
# (function name, static arguments, tree, argument types) -> key, or None where the key
# cannot name them: in a process these objects stand for themselves, as jax.jit's own cache
# holds them (a function, a Method are static arguments by identity), so each is named once.
_keys: dict[tuple, str | None] = {}
_lock = threading.Lock()


class Unnamed(Exception):
    """A value the key cannot name: the program is traced, not kept."""


def keep_in(folder) -> None:
    """Keep the driver's programs in `folder` (created when first written); None: keep none."""
    global _folder
    _folder = None if folder is None else Path(folder)


def folder() -> Path | None:
    """Where programs are kept (None: nowhere)."""
    return _folder


@functools.cache
def library_source() -> str:
    """sha256 of the source of every module of the stepzoo package (source_digest)."""
    import stepzoo
    roots = list(stepzoo.__path__)
    for name in ("dynamics", "integrators", "bench", "search", "reports"):
        spec = importlib.util.find_spec(f"stepzoo.{name}")
        if spec is not None and spec.submodule_search_locations:
            roots += list(spec.submodule_search_locations)
    return source_digest(roots)


def source_digest(roots) -> str:
    """sha256 of every .py file under the folders `roots`: its path in its folder and text."""
    digest = hashlib.sha256()
    for root in sorted({str(root) for root in roots}):
        for path in sorted(Path(root).rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode() + b"\0")
            digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def name_of(value) -> str:
    """A text that names `value` for the key, equal for equal values across processes;
    raises Unnamed for what it cannot name (a function or type not of stepzoo's)."""
    if value is None or isinstance(value, (bool, int, str, bytes)):
        return f"{type(value).__name__}:{value!r}"
    if isinstance(value, float):
        return f"float:{value.hex()}"
    if isinstance(value, (tuple, list)):
        kind: type = type(value)
        if kind not in (tuple, list):
            _ours(kind.__module__, value)      # a NamedTuple of stepzoo's
        return f"{kind.__module__}.{kind.__qualname__}({','.join(name_of(v) for v in value)})"
    if isinstance(value, dict):
        items = sorted((name_of(k), name_of(v)) for k, v in value.items())
        return "dict(" + ",".join(f"{k}={v}" for k, v in items) + ")"
    if isinstance(value, (np.ndarray, np.generic, jax.Array)):
        if isinstance(value, jax.core.Tracer):
            raise Unnamed("a traced value")
        a = np.asarray(value)
        return f"array:{a.dtype}:{a.shape}:{hashlib.sha256(a.tobytes()).hexdigest()}"
    if isinstance(value, functools.partial):
        return (f"partial({name_of(value.func)},{name_of(value.args)},"
                f"{name_of(value.keywords)})")
    if isinstance(value, types.FunctionType):
        _ours(value.__module__, value)
        cells = tuple(c.cell_contents for c in value.__closure__ or ())
        return (f"function:{value.__module__}.{value.__qualname__}({name_of(cells)},"
                f"{name_of(value.__defaults__)},{name_of(value.__kwdefaults__)})")
    from stepzoo.integrators.methods import METHODS, Method
    if isinstance(value, Method):
        if METHODS.get(value.name) is not value:
            raise Unnamed(f"the method {value.name!r} is not the zoo's registry's")
        return f"method:{value.name}"
    if isinstance(value, types.ModuleType):      # by name: their versions are in the key
        return f"module:{value.__name__}"
    if isinstance(value, type):
        _ours(value.__module__, value)
        return f"type:{value.__module__}.{value.__qualname__}"
    if dataclasses.is_dataclass(value):
        kind = type(value)  # type: ignore[assignment]
        _ours(kind.__module__, value)
        fields = {field.name: getattr(value, field.name) for field in dataclasses.fields(value)}
        return f"{kind.__module__}.{kind.__qualname__}{name_of(fields)}"
    raise Unnamed(f"a {type(value).__name__}")


def _ours(module: str, value) -> None:
    if module != "stepzoo" and not module.startswith("stepzoo."):
        raise Unnamed(f"{value!r} is not stepzoo's")


def _aval(leaf) -> str:
    """A run-time argument's shape, dtype and weak type (a Python number's dtype is JAX's
    for its type under the x64 setting, which the key holds)."""
    if isinstance(leaf, (bool, int, float, complex)):
        return f"{type(leaf).__name__}w"
    weak = "w" if getattr(leaf, "weak_type", False) else ""
    return f"{leaf.dtype}{tuple(leaf.shape)}{weak}"


def key(fn_name: str, lead: tuple, static: dict, dynamic) -> str:
    """The key of the program of the function named `fn_name` with the static arguments
    `lead` (positional, first) and `static` (keywords) and the run-time arguments `dynamic`
    (a pytree); raises Unnamed where it cannot name one."""
    leaves, tree = jax.tree.flatten(dynamic)
    parts = [library_source(), jax.__version__, jaxlib.__version__, np.__version__,
             jax.default_backend(), str(len(jax.devices())),
             str(jax.config.read("jax_enable_x64")), os.environ.get("XLA_FLAGS", ""), fn_name,
             name_of(lead), name_of(static), str(tree), ",".join(map(_aval, leaves))]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _key_of(fn_name: str, lead: tuple, static: dict, dynamic) -> str | None:
    """key(...), named once a process for these objects and argument types; None where it
    cannot name one, or an argument is traced."""
    leaves, tree = jax.tree.flatten(dynamic)
    types: list = []
    for leaf in leaves:
        if isinstance(leaf, (bool, int, float, complex)):
            types.append(type(leaf))
        elif isinstance(leaf, jax.core.Tracer):
            return None
        else:
            types.append((leaf.shape, leaf.dtype, getattr(leaf, "weak_type", False)))
    seen = (fn_name, lead, tuple(sorted(static.items())), tree, tuple(types))
    k = _keys.get(seen, "")
    if k == "":
        try:
            k = key(fn_name, lead, static, dynamic)
        except Unnamed:
            k = None
        _keys[seen] = k
    return k


def call(fn, fn_name: str, lead: tuple, static: dict, args: tuple, kwargs: dict):
    """fn(*lead, *args, **kwargs, **static), fn a function jitted with `lead` (its first
    positional arguments) and `static`'s keywords static: through the program kept under
    its key where one is, else traced, kept and run; where the key cannot name an argument,
    or nothing is kept, plain fn."""
    place = _folder
    plain = lambda: fn(*lead, *args, **kwargs, **static)
    if place is None:
        return plain()
    k = _key_of(fn_name, lead, static, (args, kwargs))
    if k is None:
        return plain()
    run = _loaded.get(k)
    if run is None and k not in _refused:
        run = _load(place / f"{k}.pkl")
        if run is None:
            run = _export(place / f"{k}.pkl", fn, lead, static, args, kwargs)
        with _lock:
            if run is None:
                _refused.add(k)
            else:
                _loaded[k] = run
    if run is None:
        return plain()
    return run(args, kwargs)


def _runner(exported):
    """A call of the exported program on (args, kwargs), on as many devices as it was
    exported for (a batch shared among cores runs on each of them)."""
    jitted = jax.jit(exported.call)
    if exported.nr_devices == 1:
        return lambda args, kwargs: jitted(*args, **kwargs)
    everywhere = NamedSharding(Mesh(np.array(jax.devices()[:exported.nr_devices]), ("d",)),
                               PartitionSpec())
    return lambda args, kwargs: jitted(*jax.device_put(args, everywhere),
                                       **jax.device_put(kwargs, everywhere))


def _load(path: Path):
    try:
        exported = pickle.loads(path.read_bytes())
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, TypeError):
        return None
    return _runner(exported)


def _export(path: Path, fn, lead, static, args, kwargs):
    """Trace and export the program, write it to `path` (atomically) and return its runner;
    None where JAX cannot export it."""
    try:
        exported = export.export(fn)(*lead, *args, **kwargs, **static)
    except Exception:   # noqa: BLE001 (what JAX cannot export is traced as before)
        return None
    # The vjp is made on request from the function, which is not kept.
    blob = pickle.dumps(dataclasses.replace(exported, _get_vjp=None))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
        tmp.write_bytes(blob)
        os.replace(tmp, path)
    except OSError:
        pass
    return _runner(exported)
