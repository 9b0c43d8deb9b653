"""What a result was computed on, recorded in every results folder's manifest.json as
pytest-benchmark records its machine_info and commit_info: the machine (CPU model, cores,
memory), the operating system, Python, the numerical libraries' versions, JAX's backend,
devices and float precision, stepzoo's version and git commit, and the command line."""
from __future__ import annotations

import os
import platform
import shlex
import subprocess
import sys
from datetime import datetime, timezone
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

# Versions recorded: what decides the numbers (JAX, NumPy, CasADi) and what draws them.
PACKAGES = ("jax", "jaxlib", "numpy", "scipy", "casadi", "pandas", "pyarrow", "matplotlib",
            "plotly")
GIT_TIMEOUT_S = 5.0


def now() -> str:
    """The current UTC time, ISO 8601 to the second."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def command_line() -> str:
    """This process's command line, the program as its name (not the path it was run from)."""
    argv = list(sys.argv) or ["python"]
    program = Path(argv[0])
    name = f"python -m {program.parent.name}" if program.name == "__main__.py" else program.name
    return " ".join([name or argv[0], shlex.join(argv[1:])]).strip()


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("model name", "Hardware", "cpu model")):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass                       # not Linux: the platform module's less specific name
    return platform.processor() or platform.machine() or "unknown"


def _memory_bytes() -> int | None:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def _cores_usable() -> int | None:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:          # no affinity call on this OS: every core counts
        return os.cpu_count()


@cache
def machine() -> dict:
    """The machine and operating system (constant for the process)."""
    memory = _memory_bytes()
    return {
        "node": platform.node(),
        "cpu": _cpu_model(),
        "architecture": platform.machine(),
        "cores": os.cpu_count(),
        "cores_usable": _cores_usable(),
        "memory_gib": round(memory / 2 ** 30, 1) if memory else None,
        "system": platform.system(),
        "release": platform.release(),
        "platform": platform.platform(),
        "python_version": platform.python_version(),
        "python_implementation": platform.python_implementation(),
        "python_compiler": platform.python_compiler(),
    }


def packages() -> dict:
    """Installed versions of PACKAGES (None where one is not installed)."""
    return dict(_versions())


@cache
def _versions() -> tuple:
    """(name, version or None) of PACKAGES, read once a process: a sweep writes its manifest
    after every chunk, and reading the installed packages' metadata is most of that."""
    out: list[tuple[str, str | None]] = []
    for name in PACKAGES:
        try:
            out.append((name, version(name)))
        except PackageNotFoundError:
            out.append((name, None))
    return tuple(out)


def jax_runtime() -> dict:
    """JAX's default backend, its devices and the float precision it computes in now."""
    import jax
    devices = jax.devices()
    return {"backend": jax.default_backend(),
            "devices": [f"{d.platform}:{d.id} {d.device_kind}" for d in devices],
            "device_count": len(devices),
            "float": "float64" if jax.config.read("jax_enable_x64") else "float32"}


@cache
def source() -> dict:
    """stepzoo's version, and its git commit when it runs from a git checkout (an editable
    install): the commit id, branch and whether tracked files differ from it."""
    from stepzoo import __version__
    info: dict[str, str | bool | None] = {"version": __version__, "commit": None,
                                          "branch": None, "dirty": None}
    here = Path(__file__).resolve().parent

    def git(*args):
        return subprocess.run(["git", "-C", str(here), *args], capture_output=True, text=True,
                              timeout=GIT_TIMEOUT_S, check=True).stdout.strip()
    try:
        # Only when this very file is tracked: an installed copy inside some other checkout
        # (a virtual environment in a repository) must not borrow that checkout's commit.
        git("ls-files", "--error-unmatch", Path(__file__).name)
        info["commit"] = git("rev-parse", "HEAD")
        info["branch"] = git("rev-parse", "--abbrev-ref", "HEAD")
        info["dirty"] = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        pass                       # no git, or not a checkout: version only
    return info


def environment() -> dict:
    """Everything above, as one JSON-ready dict for a manifest's "environment" key."""
    return {"machine": machine(), "packages": packages(), "jax": jax_runtime(),
            "stepzoo": source()}


def provenance(command: str, started: str, finished: str | None) -> dict:
    """The keys every manifest.json carries: the stepzoo command that wrote the folder
    ("sweep", "plan", "report", "run"), the process's command line, when it started and
    finished (UTC; None while unfinished) and the environment."""
    return {"written_by": command, "command_line": command_line(), "started": started,
            "finished": finished, "environment": environment()}


def write_manifest(folder, command: str, started: str, record: dict | None = None) -> Path:
    """`folder`/manifest.json: `record` (what the command wrote) and its provenance."""
    from stepzoo.output import atomic_write, to_json
    manifest = {**(record or {}), **provenance(command, started, now())}
    return atomic_write(Path(folder) / "manifest.json", to_json(manifest) + "\n")
