"""Where the report's inputs came from, as the page shows it: paths relative to the report
(never the user's absolute paths), command lines likewise, and the appendix table of the
environment each results folder was computed in, read from its manifest.json."""
from __future__ import annotations

import os
import shlex
from pathlib import Path

from stepzoo.reports.tables import Table

MAX_UP = 2              # a path shown relative to the report climbs at most this many folders


def public_path(path, base) -> str:
    """`path` as the page shows it: relative to the folder `base` when near it, else only its
    last part after an ellipsis (an absolute path tells of the user's machine)."""
    path, base = Path(path).absolute(), Path(base).absolute()
    rel = os.path.relpath(path, base)
    if Path(rel).parts[:MAX_UP + 1].count("..") <= MAX_UP:
        return rel
    return ".../" + path.name


def public_command(line: str, base) -> str:
    """A command line with every absolute path (also in --flag=PATH) made public."""
    try:
        words = shlex.split(line)
    except ValueError:               # unbalanced quotes: not a command line we wrote
        return "..."
    out = []
    for word in words:
        flag, eq, value = word.partition("=") if word.startswith("-") else ("", "", word)
        if os.path.isabs(value):
            value = public_path(value, base)
        out.append(flag + eq + value)
    return shlex.join(out)


def _rows(env: dict, manifest: dict, base) -> list:
    """(quantity, value) of one manifest; '-' where it records nothing."""
    machine, packages = env.get("machine", {}), env.get("packages", {})
    jax, source = env.get("jax", {}), env.get("stepzoo", {})
    cores = machine.get("cores")
    usable = machine.get("cores_usable")
    commit = source.get("commit")
    rows = [
        ("command line", public_command(manifest["command_line"], base)
         if manifest.get("command_line") else None),
        ("started (UTC)", manifest.get("started")),
        ("finished (UTC)", manifest.get("finished")),
        ("CPU", machine.get("cpu")),
        ("cores (usable)", f"{cores} ({usable})" if cores else None),
        ("memory [GiB]", machine.get("memory_gib")),
        ("operating system", " ".join(str(machine[k]) for k in ("system", "release",
                                                                 "architecture")
                                      if machine.get(k)) or None),
        ("Python", " ".join(str(machine[k]) for k in ("python_implementation",
                                                       "python_version") if machine.get(k))
         or None),
        *[(name, packages.get(name)) for name in ("jax", "jaxlib", "numpy", "scipy", "casadi",
                                                   "pandas", "matplotlib", "plotly")],
        ("JAX backend", jax.get("backend")),
        ("JAX devices", ", ".join(jax["devices"]) if jax.get("devices") else None),
        ("float precision", jax.get("float")),
        ("stepzoo version", source.get("version") or manifest.get("stepzoo_version")),
        ("git commit", (commit[:12] + (" (with uncommitted changes)" if source.get("dirty")
                                       else "")) if commit else None),
    ]
    return rows


def environment_table(manifests: dict, base) -> Table:
    """The appendix: one row per quantity, one column per results folder (name -> its
    manifest dict, or None when it has none)."""
    names = list(manifests)
    columns = [("quantity", "quantity"), *[(n, n) for n in names]]
    by_name = {n: dict(_rows((m or {}).get("environment", {}), m or {}, base))
               for n, m in manifests.items()}
    quantities = [q for q, _ in _rows({}, {}, base)]
    rows = [{"quantity": q, **{n: by_name[n].get(q) for n in names}} for q in quantities]
    caption = ("What each results folder was computed on and with, from its manifest.json "
               "(as pytest-benchmark records its machine_info): the timings of the figures "
               "are of this machine and these versions. '-' where a folder records nothing "
               "(written by an older stepzoo, or no manifest).")
    return Table("Environment", caption, rows, columns)
