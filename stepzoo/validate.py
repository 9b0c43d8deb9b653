"""Checks of user input shared by the commands, each failure one UsageError line: one table
of physical and numerical ranges (RANGES) that every command and config file checks its
numbers against."""
import functools
import math
import os
import resource
import tomllib
from dataclasses import dataclass
from pathlib import Path

from stepzoo.errors import UsageError
from stepzoo.ranges import Range
from stepzoo.safe_parse import toml_loads


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
        return toml_loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise UsageError(f"{path}: not valid TOML ({err}); fix the file") from None


# The stability margin: h <= (1 - margin) x the measured largest stable step. 0.2, not less:
# the limit is measured at the envelope's grid points only, and a step that close to it
# leaves |R(h lambda)| near 1, so a perturbation decays over hundreds of steps.
DEFAULT_MARGIN = 0.2

# The one table of ranges every command and config checks its numbers against, so a value
# refused by one is refused by all, with the same words. Plain data: a flag is checked here
# without pydantic (`stepzoo plan --server` starts in a few imports); a config file's field is
# declared with config_schema.ranged(kind), the same range as a pydantic type.
RANGES = {
    "step": Range("a step size", "s", "below 1e-9 s round-off swamps the step; a step is at "
                  "most the horizon", ge=1e-9, le=100.0),
    "horizon": Range("a horizon", "s", "about a day of driving at most", ge=1e-9, le=1e5),
    "speed": Range("a speed", "m/s", "the bicycle models divide by the speed; 150 m/s is past "
                   "any road vehicle", ge=0.1, le=150.0),
    "goal_speed": Range("a goal speed", "m/s", "150 m/s is past any road vehicle", ge=0.0,
                        le=150.0),
    "steer": Range("a steer angle", "rad", "the wheels turn less than a quarter turn either "
                   "way", gt=-math.pi / 2, lt=math.pi / 2),
    "rtol": Range("a relative tolerance", "", "float64 resolves about 1e-16; a reference asked "
                  "for less than 1e-14 never meets it", ge=1e-14, le=0.1),
    "atol": Range("an absolute tolerance", "", "a positive float64 at most 1", ge=1e-300,
                  le=1.0),
    "growth": Range("a blow-up growth factor", "", "a stability run can grow further only from "
                    "steps far past the limit, which biases the measured limit upward", gt=2.0,
                    le=1e4),
    "perturbation": Range("a modal perturbation", "", "a deviation that the lateral states "
                          "resolve", ge=1e-12, le=10.0),
    "rel_tol": Range("a bisection tolerance", "", "relative width of the bracket of the "
                     "largest stable step", ge=1e-12, lt=0.1),
    "pos_tol": Range("a position tolerance", "m", "float64 resolves positions to about 1e-12 m "
                     "over this horizon", ge=1e-12, le=1e4),
    "tol": Range("an error tolerance", "", "in the sweep's error norm: the largest error state "
                 "over its scale", ge=1e-14, le=1e6),
    "margin": Range("a stability margin", "", "a fraction of the measured largest stable step",
                    ge=0.0, lt=1.0),
    "seed": Range("a seed", "", "NumPy's seed range", whole=True, ge=0, le=2**32 - 1),
    "position": Range("a coordinate", "m", "a map of 1000 km at most", ge=-1e6, le=1e6),
    "heading": Range("a heading", "rad", "one turn either way", ge=-2 * math.pi,
                     le=2 * math.pi),
    "cell": Range("a cell size", "m/cell", "a millimetre to 100 m per cell", ge=1e-3, le=100.0),
    "rounds": Range("a number of timed rounds", "", "repeats of each timed run; a thousand is "
                    "minutes of timing alone", whole=True, ge=1, le=1000),
    # The fields of integrators.newton.NewtonOptions, the implicit methods' solves ([newton]).
    "newton_rtol": Range("a relative tolerance", "", "0: atol alone; below round-off a solve "
                         "stops where its increments are round-off", ge=0.0, le=0.1),
    "newton_atol": Range("an absolute tolerance", "", "0: rtol alone; in the states' own units",
                         ge=0.0, le=1.0),
    "newton_res_tol": Range("a residual tolerance", "", "times the residual an error within "
                            "tolerance makes", gt=0.0, le=1e6),
    "newton_max_iter": Range("an iteration limit", "", "simplified Newton iterations per solve",
                             whole=True, ge=1, le=1000),
    "newton_max_iter_full": Range("an iteration limit", "", "full Newton iterations of the "
                                  "retry; 0: no retry", whole=True, ge=0, le=1000),
}


def describe(kind: str) -> str:
    """The range of the quantity `kind` of RANGES in words: what, bounds, unit and why."""
    return RANGES[kind].words()


def problem(kind: str, name: str, value) -> str | None:
    """What is wrong with `value` for the quantity `kind` of RANGES, named `name` (None: it
    is in range)."""
    return None if RANGES[kind].valid(value) is not None else \
        f"{name} must be {describe(kind)}, got {value!r}"


def check(kind: str, name: str, value) -> float:
    """`value` as a float (an int for a whole quantity) if it is in the range of `kind`; else
    UsageError naming `name`."""
    ok = RANGES[kind].valid(value)
    if ok is None:
        raise UsageError(f"{name} must be {describe(kind)}, got {value!r}")
    return ok


GIB = 2**30
# Work a command may take on before it refuses: at about 1e7 steps per second per core,
# 1e11 integration steps (summed over trajectories) take hours.
DEFAULT_MAX_STEPS = 1e11


def _physical_memory() -> float:
    """This machine's physical memory [bytes] (inf where it cannot be read)."""
    try:
        return float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return math.inf


@functools.cache
def _cgroup_limit() -> tuple[float, Path | None]:
    """(this process's control group memory limit [bytes], the file of its usage): cgroup
    v2's memory.max and memory.current, or v1's limit and usage; (inf, None) without a
    limit, or off Linux. Read once: a process does not change group."""
    try:
        own = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return math.inf, None
    places = []
    for line in own:
        _, controllers, path = line.split(":", 2)
        if controllers == "":
            base = Path("/sys/fs/cgroup") / path.lstrip("/")
            places += [(base / "memory.max", base / "memory.current")]
        elif "memory" in controllers.split(","):
            base = Path("/sys/fs/cgroup/memory") / path.lstrip("/")
            places += [(base / "memory.limit_in_bytes", base / "memory.usage_in_bytes")]
    # Inside a container the process's own group is often mounted as the root.
    places += [(Path("/sys/fs/cgroup/memory.max"), Path("/sys/fs/cgroup/memory.current")),
               (Path("/sys/fs/cgroup/memory/memory.limit_in_bytes"),
                Path("/sys/fs/cgroup/memory/memory.usage_in_bytes"))]
    for limit, used in places:
        try:
            text = limit.read_text().strip()
            value = math.inf if text == "max" else float(text)
        except (OSError, ValueError):
            continue
        # cgroup v1 writes no limit as a number near 2**63.
        return (math.inf, None) if value >= 2.0 ** 60 else (value, used)
    return math.inf, None


def _cgroup_room() -> float:
    """What this process's control group may still take [bytes] (inf without a limit)."""
    limit, used = _cgroup_limit()
    if used is None or not math.isfinite(limit):
        return limit
    try:
        return max(0.0, limit - float(used.read_text()))
    except (OSError, ValueError):
        return limit


def _mapped() -> float:
    """The address space this process maps now [bytes] (0 where it cannot be read)."""
    try:
        return float(Path("/proc/self/statm").read_text().split()[0]) * os.sysconf(
            "SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError, AttributeError):
        return 0.0


def memory_room() -> tuple[float, str]:
    """(what this process may still allocate before a hard limit [bytes], what bounds it):
    the lesser of its control group's room (a container's limit) and the address space left
    under its limit (RLIMIT_AS, `ulimit -v`); inf without either. An allocation past them
    fails inside XLA, which then waits forever, so work is checked against them before it
    starts. (The physical memory is no hard limit: past it the system swaps.)"""
    found = [(_cgroup_room(), "the room left in this process's control group (its "
              "container's memory limit)")]
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        found.append((max(0.0, soft - _mapped()), f"the address space left under this "
                      f"process's limit of {soft / GIB:.3g} GiB (ulimit -v)"))
    return min(found, key=lambda f: f[0])


def _half_the_memory() -> float:
    """Half of the lesser of the physical memory and memory_room's (8 GiB where neither can
    be read): room for the copies the work makes beside the trajectories it keeps."""
    room = min(_physical_memory(), memory_room()[0])
    return room / 2 if math.isfinite(room) else 8.0 * GIB


# The address space JAX's CPU runtime maps when it starts, and a first compilation with it
# (thread stacks, arenas, the compiler): below it JAX aborts in C++ (std::bad_alloc) with no
# word the command could catch.
JAX_ADDRESS_SPACE = 2 * GIB


def check_address_space() -> None:
    """UsageError if this process's address-space limit (ulimit -v) leaves JAX too little
    to start; called by the command before JAX's first computation."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY and soft - _mapped() < JAX_ADDRESS_SPACE:
        raise UsageError(f"the address-space limit of {soft / GIB:.3g} GiB (ulimit -v) leaves "
                         f"less than the {JAX_ADDRESS_SPACE / GIB:g} GiB JAX needs to start "
                         "and compile; raise it (ulimit -v unlimited)")


@dataclass
class Budget:
    """What one command may allocate [bytes] and integrate [steps x trajectories]; the
    command line sets it from --max-memory and --max-steps."""
    memory: float | None = None
    steps: float | None = None


BUDGET = Budget()


def check_budget(what: str, steps: float, batch: float, states: int, calls: float = 1,
                 memory: float | None = None, max_steps: float | None = None):
    """UsageError, with the estimate and the limit, if `what` would hold more trajectory
    memory than allowed (`steps` x `batch` x `states` float64 values at once) or integrate
    more than `calls` x `steps` x `batch` steps. The limits, first found: the command line's
    (BUDGET), the arguments (a config's), the defaults (half the memory, DEFAULT_MAX_STEPS)."""
    check_memory(what, 8.0 * steps * batch * states, f"{steps:.3g} steps x {batch:.3g} "
                 f"trajectories x {states} states, float64", "use a larger step or a shorter "
                 "horizon", memory)
    work = float(calls) * steps * batch
    limit = BUDGET.steps or max_steps or DEFAULT_MAX_STEPS
    if work > limit:
        raise UsageError(f"{what} would take {work:.3g} integration steps (summed over "
                         f"trajectories), past the limit of {limit:.3g}; use a larger step "
                         "or a shorter horizon, or raise the limit with --max-steps N")


def check_memory(what: str, need: float, made_of: str, instead: str,
                 memory: float | None = None):
    """UsageError if `what` would allocate more than `need` bytes (`made_of` says of what)
    past the limit (BUDGET, else `memory`, else half of memory_room's), or past what this
    process can allocate at all; `instead` says what to change."""
    room, bound = memory_room()
    if need > room:
        raise UsageError(f"{what} would hold {need / GIB:.3g} GiB ({made_of}), past "
                         f"{bound}, {room / GIB:.3g} GiB; {instead}")
    limit = BUDGET.memory or memory or _half_the_memory()
    if need > limit:
        raise UsageError(f"{what} would hold {need / GIB:.3g} GiB ({made_of}), past the limit "
                         f"of {limit / GIB:.3g} GiB; {instead}, or raise the limit with "
                         "--max-memory GIB")
