"""`[model] casadi = ...`: a user's CasADi model, from "module:function" (a function that
returns a casadi.Function) or a file written by casadi.Function.save, made a JAX right-hand
side (dynamics.casadi_model) that the sweep uses as any JAX model."""
from __future__ import annotations

import hashlib
import re
from pathlib import Path

from stepzoo.bench.model.spec import import_user_module
from stepzoo.errors import UsageError
from stepzoo.output import prints_to_stderr

FUNCTION_REF = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")
_CONVERTED: dict = {}     # one right-hand side per (function, sizes): one compilation


def casadi_function(ref: str, folder: Path, source: str):
    """The casadi.Function that `ref` names: "module:function" (imported with `folder` first
    on the path, then called with no arguments) or a saved file (relative to `folder`)."""
    import casadi as ca
    if not FUNCTION_REF.match(ref):
        path = folder / ref
        if not path.is_file():
            raise UsageError(f"{source}: model.casadi names no file {path} (give a file "
                             "written by casadi.Function.save, or \"module:function\")")
        _check_loads(path, source)
        try:
            return ca.Function.load(str(path))
        except RuntimeError as err:
            raise UsageError(f"{source}: model.casadi: {path} is not a file written by "
                             f"casadi.Function.save ({_last_line(err)})") from None
    module_name, func_name = ref.split(":")
    module = import_user_module(module_name, folder, source, "casadi")
    make = getattr(module, func_name, None)
    if not callable(make):
        raise UsageError(f"{source}: {module_name!r} has no function {func_name!r} (model.casadi "
                         "names a function returning a casadi.Function)")
    try:
        # What the factory prints goes to stderr: stdout carries the command's output
        # (--format json).
        with prints_to_stderr():
            fn = make()
    except Exception as err:   # the user's code failing: one line
        raise UsageError(f"{source}: calling {ref}() failed: {type(err).__name__}: "
                         f"{_last_line(err)}") from None
    if not isinstance(fn, ca.Function):
        raise UsageError(f"{source}: {ref}() returned a {type(fn).__name__}, not a "
                         "casadi.Function (of x, u and optionally p, t)")
    return fn


# [s] CasADi loads a saved function of thousands of instructions in well under a second.
LOAD_TIMEOUT_S = 30.0
_LOADABLE: set = set()    # (path, size, mtime) of the files a child process loaded whole
_CHILD_LOAD = "import sys, casadi\ntry:\n    casadi.Function.load(sys.argv[1])\n" \
    "except RuntimeError:\n    sys.exit(1)\n"


def _check_loads(path: Path, source: str):
    """UsageError if CasADi's loader crashes or hangs on the file `path`, tried first in a
    child process: its deserializer checks some bytes only, and a file with one byte changed
    may kill the process (SIGSEGV) or loop. A loader's own error (exit 1) is left to the
    load here, which says it."""
    import signal
    import subprocess
    import sys
    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    if key in _LOADABLE:
        return
    try:
        child = subprocess.run([sys.executable, "-c", _CHILD_LOAD, str(path)],
                               capture_output=True, timeout=LOAD_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise UsageError(f"{source}: model.casadi: CasADi did not finish loading {path} in "
                         f"{LOAD_TIMEOUT_S:g} s: the file is damaged; save the function again "
                         "(casadi.Function.save)") from None
    if child.returncode < 0:
        raise UsageError(f"{source}: model.casadi: CasADi's loader crashed on {path} "
                         f"({signal.Signals(-child.returncode).name}): the file is damaged; "
                         "save the function again (casadi.Function.save)")
    if child.returncode == 0:
        _LOADABLE.add(key)


def load(ref, folder: Path, states, inputs, p_names, source: str):
    """(f(t, x, u, p) -> dx/dt, sha256 of the function's serialized graph) of the CasADi
    model `ref`; UsageError (one line) when it cannot be had or does not fit the model."""
    from stepzoo.dynamics.casadi_model import rhs
    fn = casadi_function(ref, folder, source)
    sha = hashlib.sha256(fn.serialize().encode()).hexdigest()
    key = (sha, len(states), len(inputs), tuple(p_names))
    if key not in _CONVERTED:
        try:
            _CONVERTED[key] = rhs(fn, len(states), len(inputs), tuple(p_names))
        except ValueError as err:
            raise UsageError(f"{source}: model.casadi {ref}: {err}") from None
    return _CONVERTED[key], sha


def check_p(p_names, params: dict, source: str, bad: list) -> tuple:
    """model.p: the names of the entries of the function's p, each with a value in [params];
    appends to `bad` if wrong. Every [params] key must be one of them (nothing else reads
    it)."""
    if p_names is None:
        p_names = []
    if not (isinstance(p_names, list) and all(isinstance(s, str) and s for s in p_names)):
        bad.append(f"{source}: model.p must be a list of parameter names (the entries of the "
                   "CasADi function's input p, in order)")
        return ()
    if len(set(p_names)) != len(p_names):
        bad.append(f"{source}: model.p lists a name twice; list each once")
    for name in p_names:
        if name not in params:
            bad.append(f"{source}: model.p names {name!r}, which has no value in [params]; "
                       f"add {name} = ... there")
    for name in params:
        if name not in p_names:
            bad.append(f"{source}: params.{name} is not an entry of model.p "
                       f"({', '.join(p_names) or 'empty'}), so the CasADi model never reads "
                       "it; add it to model.p in the order of the function's p")
    return tuple(p_names)


def _last_line(err) -> str:
    text = str(err).strip()
    return text.splitlines()[-1] if text else ""
