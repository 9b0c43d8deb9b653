"""Checks of user input shared by the commands, each failure one UsageError line: one table
of physical and numerical ranges (RANGES) that every command checks its numbers against."""
import math
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

from stepzoo.errors import UsageError
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


@dataclass(frozen=True)
class Range:
    """The values a quantity may take: [lo, hi] (ends excluded where `open_lo`/`open_hi`),
    in `unit`, and why the bounds are where they are."""
    what: str
    lo: float
    hi: float
    unit: str
    why: str
    open_lo: bool = False
    open_hi: bool = False
    whole: bool = False

    def holds(self, value) -> bool:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False
        if self.whole and not float(value).is_integer():
            return False
        lo_ok = value > self.lo if self.open_lo else value >= self.lo
        hi_ok = value < self.hi if self.open_hi else value <= self.hi
        return math.isfinite(value) and lo_ok and hi_ok

    def describe(self) -> str:
        left, right = "(" if self.open_lo else "[", ")" if self.open_hi else "]"
        unit = f" {self.unit}" if self.unit else ""
        lo, hi = (f"{int(v)}" if self.whole else f"{v:g}" for v in (self.lo, self.hi))
        kind = "whole number" if self.whole else "number"
        return f"{self.what}: a {kind} in {left}{lo}, {hi}{right}{unit} ({self.why})"


# The stability margin: h <= (1 - margin) x the measured largest stable step. 0.2, not less:
# the limit is measured at the envelope's grid points only, and a step that close to it
# leaves |R(h lambda)| near 1, so a perturbation decays over hundreds of steps.
DEFAULT_MARGIN = 0.2

# The one table of ranges every command checks its numbers against, so a value refused by
# one command is refused by all, with the same words.
RANGES = {
    "step": Range("a step size", 1e-9, 100.0, "s", "below 1e-9 s round-off swamps the "
                  "step; a step is at most the horizon", open_lo=False),
    "horizon": Range("a horizon", 1e-9, 1e5, "s", "about a day of driving at most"),
    "speed": Range("a speed", 0.1, 150.0, "m/s", "the bicycle models divide by the speed; "
                   "150 m/s is past any road vehicle"),
    "goal_speed": Range("a goal speed", 0.0, 150.0, "m/s", "150 m/s is past any road vehicle"),
    "steer": Range("a steer angle", -math.pi / 2, math.pi / 2, "rad", "the wheels turn "
                   "less than a quarter turn either way", open_lo=True, open_hi=True),
    "rtol": Range("a relative tolerance", 1e-14, 0.1, "", "float64 resolves about 1e-16; a "
                  "reference asked for less than 1e-14 never meets it"),
    "atol": Range("an absolute tolerance", 1e-300, 1.0, "", "a positive float64 at most 1"),
    "growth": Range("a blow-up growth factor", 2.0, 1e4, "", "a stability run can grow "
                    "further only from steps far past the limit, which biases the measured "
                    "limit upward", open_lo=True),
    "perturbation": Range("a modal perturbation", 1e-12, 10.0, "", "a deviation that the "
                          "lateral states resolve"),
    "rel_tol": Range("a bisection tolerance", 1e-12, 0.1, "", "relative width of the "
                     "bracket of the largest stable step", open_hi=True),
    "pos_tol": Range("a position tolerance", 1e-12, 1e4, "m", "float64 resolves positions "
                     "to about 1e-12 m over this horizon"),
    "tol": Range("an error tolerance", 1e-14, 1e6, "", "in the sweep's error norm: the "
                 "largest error state over its scale"),
    "margin": Range("a stability margin", 0.0, 1.0, "", "a fraction of the measured "
                    "largest stable step", open_hi=True),
    "seed": Range("a seed", 0, 2**32 - 1, "", "NumPy's seed range", whole=True),
    "position": Range("a coordinate", -1e6, 1e6, "m", "a map of 1000 km at most"),
    "heading": Range("a heading", -2 * math.pi, 2 * math.pi, "rad", "one turn either way"),
    "cell": Range("a cell size", 1e-3, 100.0, "m/cell", "a millimetre to 100 m per cell"),
    "rounds": Range("a number of timed rounds", 1, 1000, "", "repeats of each timed run; "
                    "a thousand is minutes of timing alone", whole=True),
    # [newton]: the fields of integrators.newton.NewtonOptions, the implicit methods' solves
    "newton_rtol": Range("a relative tolerance", 0.0, 0.1, "", "0: atol alone; below "
                         "round-off a solve stops where its increments are round-off"),
    "newton_atol": Range("an absolute tolerance", 0.0, 1.0, "", "0: rtol alone; in the "
                         "states' own units"),
    "newton_res_tol": Range("a residual tolerance", 0.0, 1e6, "", "times the residual an "
                            "error within tolerance makes", open_lo=True),
    "newton_max_iter": Range("an iteration limit", 1, 1000, "", "simplified Newton "
                             "iterations per solve", whole=True),
    "newton_max_iter_full": Range("an iteration limit", 0, 1000, "", "full Newton "
                                  "iterations of the retry; 0: no retry", whole=True),
}


def problem(kind: str, name: str, value) -> str | None:
    """What is wrong with `value` for the quantity `kind` of RANGES, named `name` (None: it
    is in range)."""
    spec = RANGES[kind]
    return None if spec.holds(value) else f"{name} must be {spec.describe()}, got {value!r}"


def check(kind: str, name: str, value) -> float:
    """`value` as a float if it is in the range of `kind`; else UsageError naming `name`."""
    message = problem(kind, name, value)
    if message:
        raise UsageError(message)
    return int(value) if RANGES[kind].whole else float(value)


GIB = 2**30
# Work a command may take on before it refuses: at about 1e7 steps per second per core,
# 1e11 integration steps (summed over trajectories) take hours.
DEFAULT_MAX_STEPS = 1e11


def _half_the_memory() -> float:
    """Half this machine's physical memory [bytes] (8 GiB where it cannot be read)."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2
    except (ValueError, OSError, AttributeError):
        return 8.0 * GIB


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
    past the limit (BUDGET, else `memory`, else half the machine's); `instead` says what to
    change."""
    limit = BUDGET.memory or memory or _half_the_memory()
    if need > limit:
        raise UsageError(f"{what} would hold {need / GIB:.3g} GiB ({made_of}), past the limit "
                         f"of {limit / GIB:.3g} GiB; {instead}, or raise the limit with "
                         "--max-memory GIB")
