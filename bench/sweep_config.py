"""A sweep config: a TOML file read into a frozen, validated `SweepConfig`. Every mistake is
one line naming the key, what is wrong and what to write instead; all mistakes are reported
at once (UsageError, exit 2)."""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from stepzoo.errors import UsageError
from stepzoo.validate import problem, read_toml

TOP = {"name", "model", "vehicle", "horizon", "methods", "envelope", "steps", "reference", "limits",
       "stability", "chunks", "trajectories", "timing"}
MAX_GRID = 10_000       # values of one grid, or points of an envelope: more is a typo, and
                        # would be allocated before any estimate of the work
SECTIONS = {
    "envelope": {"vx", "delta", "x0"},
    "steps": {"h"},
    "reference": {"rtol", "atol"},
    "stability": {"steps", "growth", "perturbation", "h_probe_max", "rel_tol"},
    "chunks": {"points"},
    "trajectories": {"vx", "delta", "fractions", "past_limit"},
    "limits": {"memory_gib", "steps"},
    "timing": {"rounds"},
}
DEFAULT_ROUNDS = 5     # timed repeats of each accuracy run, after its compilation


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep. Step sizes are snapped to horizon/n (whole steps, each run ends at
    the horizon) and sorted; the operating points are every (vx, delta), vx-major."""
    name: str
    model: str
    vehicle: str
    horizon: float                 # [s] of the accuracy runs
    methods: tuple
    vx: tuple                      # [m/s]
    delta: tuple                   # [rad]
    x0: tuple                      # initial state of the accuracy runs
    hs: tuple                      # [s], ascending
    rtol: float
    atol: float
    stab_steps: int                # steps of one stability run
    growth: float                  # blow-up threshold on the modal deviation
    perturbation: float            # modal amplitude of the stability runs' initial deviation
    h_probe_max: float             # [s] largest step probed for a blow-up
    rel_tol: float                 # bisection stops when h_hi / h_lo - 1 <= rel_tol
    points_per_chunk: int
    traj_point: tuple              # (vx [m/s], delta [rad]) of the sample trajectories
    traj_fractions: tuple          # sample steps, as fractions of the measured limit
    traj_past_limit: float         # the sample past the limit, as a multiple of it
    source: str = field(default="", compare=False)
    # [limits]: what the sweep may allocate [GiB] and integrate (they decide no result)
    max_memory_gib: float | None = field(default=None, compare=False)
    max_steps: float | None = field(default=None, compare=False)
    timing_rounds: int = DEFAULT_ROUNDS    # timed repeats of each accuracy run

    @property
    def points(self) -> list[tuple[float, float]]:
        return [(v, d) for v in self.vx for d in self.delta]

    def canonical(self) -> dict:
        """Everything that decides the results (not the file's path or layout)."""
        d = asdict(self)
        for key in ("source", "max_memory_gib", "max_steps"):
            d.pop(key)
        return d

    @property
    def sha256(self) -> str:
        text = json.dumps(self.canonical(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


def load(path) -> SweepConfig:
    """Read and validate a sweep TOML; UsageError (one line per mistake) if it is wrong."""
    raw = read_toml(path, "sweep config", "give a TOML file such as bench/configs/small.toml")
    return validate(raw, str(path))


def validate(raw: dict, source: str = "config") -> SweepConfig:
    from stepzoo import dynamics
    from stepzoo.integrators import METHODS
    bad: list[str] = []
    check = _Checker(bad, source)

    for key in sorted(set(raw) - TOP):
        bad.append(f"{source}: unknown key {key!r}; known: {', '.join(sorted(TOP))}")
    sections = {}
    for sec, keys in SECTIONS.items():
        table = raw.get(sec, {})
        if not isinstance(table, dict):
            bad.append(f"{source}: [{sec}] must be a table")
            table = {}
        for key in sorted(set(table) - keys):
            bad.append(f"{source}: unknown key {sec}.{key}; known: {', '.join(sorted(keys))}")
        sections[sec] = table

    model_name = raw.get("model", "dynamic5")
    if model_name != "dynamic5":
        bad.append(f"{source}: model {model_name!r} is not supported by the sweep; use "
                   "\"dynamic5\" (its lateral dynamics are linear, so limits can be predicted)")
    vehicle = raw.get("vehicle", dynamics.default_vehicle())
    if vehicle not in dynamics.vehicle_names():
        bad.append(f"{source}: unknown vehicle {vehicle!r}; known: "
                   f"{', '.join(dynamics.vehicle_names())}")

    horizon = check.ranged("horizon", "horizon", raw.get("horizon"))
    methods = raw.get("methods", "all")
    if methods == "all":
        methods = list(METHODS)
    elif not (isinstance(methods, list) and methods and all(isinstance(m, str) for m in methods)):
        bad.append(f"{source}: methods must be \"all\" or a non-empty list of names")
        methods = []
    for m in methods:
        if m not in METHODS:
            bad.append(f"{source}: unknown method {m!r} in methods; known: {', '.join(METHODS)}")
    if len(set(methods)) != len(methods):
        bad.append(f"{source}: methods lists a name twice; list each once")

    env = sections["envelope"]
    vx = check.grid("envelope.vx", env.get("vx"), "m/s", "speed", log=False)
    delta = check.grid("envelope.delta", env.get("delta"), "rad", "steer", log=False)
    if len(vx) * len(delta) > MAX_GRID:
        bad.append(f"{source}: the envelope has {len(vx)} x {len(delta)} operating points; at "
                   f"most {MAX_GRID}")
    x0 = env.get("x0", [0.0] * 5)
    if not (isinstance(x0, list) and len(x0) == 5 and all(_is_num(v) for v in x0)):
        bad.append(f"{source}: envelope.x0 must be 5 finite numbers [X, Y, psi, vy, r]")
        x0 = [0.0] * 5

    hs = check.grid("steps.h", sections["steps"].get("h"), "s", "step", log=True)
    if horizon and hs:
        if max(hs) > horizon:
            bad.append(f"{source}: steps.h reaches {max(hs):g} s, past the horizon "
                       f"{horizon:g} s; keep every step <= horizon")
        hs = sorted({horizon / max(1, round(horizon / h)) for h in hs})

    ref = sections["reference"]
    rtol = check.ranged("rtol", "reference.rtol", ref.get("rtol", 1e-10))
    atol = check.ranged("atol", "reference.atol", ref.get("atol", 1e-12))
    stab = sections["stability"]
    steps = stab.get("steps", 1000)
    if not (isinstance(steps, int) and not isinstance(steps, bool) and 50 <= steps <= 100_000):
        bad.append(f"{source}: stability.steps must be a whole number in [50, 100000], "
                   f"got {steps!r}")
    growth = check.ranged("growth", "stability.growth", stab.get("growth", 100.0))
    perturbation = check.ranged("perturbation", "stability.perturbation",
                                stab.get("perturbation", 0.1))
    h_probe_max = check.ranged("step", "stability.h_probe_max", stab.get("h_probe_max", 2.0))
    if h_probe_max and hs and h_probe_max < max(hs):
        bad.append(f"{source}: stability.h_probe_max ({h_probe_max:g} s) is below the "
                   f"largest step ({max(hs):g} s); raise it")
    rel_tol = check.ranged("rel_tol", "stability.rel_tol", stab.get("rel_tol", 1e-3))
    per_chunk = sections["chunks"].get("points", 25)
    if not (isinstance(per_chunk, int) and not isinstance(per_chunk, bool) and per_chunk >= 1):
        bad.append(f"{source}: chunks.points must be a whole number >= 1, got {per_chunk!r}")

    traj = sections["trajectories"]
    tvx = traj.get("vx", vx[0] if vx else 1.0)
    tdelta = traj.get("delta", delta[0] if delta else 0.0)
    check.ranged("speed", "trajectories.vx", tvx)
    check.ranged("steer", "trajectories.delta", tdelta)
    fractions = traj.get("fractions", [0.2, 0.5, 0.9])
    if not (isinstance(fractions, list) and fractions
            and all(_is_num(f) and 0 < f <= 1 for f in fractions)):
        bad.append(f"{source}: trajectories.fractions must be numbers in (0, 1] (of the "
                   "measured largest stable step)")
        fractions = [0.5]
    past = check.positive("trajectories.past_limit", traj.get("past_limit", 1.5), "")
    if past and past <= 1:
        bad.append(f"{source}: trajectories.past_limit must be > 1 (a multiple of the limit)")

    limits = [sections["limits"].get(key) for key in ("memory_gib", "steps")]
    for key, value in zip(("limits.memory_gib", "limits.steps"), limits):
        if value is not None and not (_is_num(value) and value > 0):
            bad.append(f"{source}: {key} must be a number > 0, got {value!r}")
    rounds = check.ranged("rounds", "timing.rounds",
                          sections["timing"].get("rounds", DEFAULT_ROUNDS))
    name = raw.get("name", Path(source).stem)
    if not isinstance(name, str):
        bad.append(f"{source}: name must be a string")
    if bad:
        raise UsageError("\n".join(bad))
    return SweepConfig(str(name), model_name, vehicle, float(horizon), tuple(methods),
                       tuple(vx), tuple(delta), tuple(float(v) for v in x0), tuple(hs),
                       float(rtol), float(atol), int(steps), float(growth), float(perturbation),
                       float(h_probe_max), float(rel_tol), int(per_chunk),
                       (float(tvx), float(tdelta)), tuple(float(f) for f in fractions),
                       float(past), source, *limits, timing_rounds=int(rounds))


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


class _Checker:
    """Appends one line per mistake to `bad`; returns a usable value either way."""

    def __init__(self, bad, source):
        self.bad, self.source = bad, source

    def positive(self, key, value, unit):
        if not (_is_num(value) and value > 0):
            units = f" [{unit}]" if unit else ""
            self.bad.append(f"{self.source}: {key} must be a number > 0{units}, got {value!r}")
            return None
        return float(value)

    def ranged(self, kind, key, value):
        """`value` if it lies in RANGES[kind], else None (and a line in `bad`)."""
        message = problem(kind, key, value)
        if message:
            self.bad.append(f"{self.source}: {message}")
            return None
        return float(value)

    def grid(self, key, value, unit, kind, log):
        """A list of numbers, or {min, max, num <= MAX_GRID} spaced linearly (log-spaced if
        `log`), each in RANGES[kind]."""
        spacing = "log-spaced" if log else "evenly spaced"
        what = (f"{key} must be a list of numbers [{unit}] or {{min = ..., max = ..., "
                f"num = ...}} ({spacing})")
        if isinstance(value, dict):
            lo, hi, num = value.get("min"), value.get("max"), value.get("num")
            if set(value) != {"min", "max", "num"} or not (_is_num(lo) and _is_num(hi)) \
                    or not (isinstance(num, int) and not isinstance(num, bool)
                            and 1 <= num <= MAX_GRID) or lo > hi:
                self.bad.append(f"{self.source}: {what} with min <= max and 1 <= num <= "
                                f"{MAX_GRID}, got {value!r}")
                return []
            if self.ranged(kind, f"{key}.min", lo) is None \
                    or self.ranged(kind, f"{key}.max", hi) is None:
                return []
            values = np.geomspace(lo, hi, num) if log else np.linspace(lo, hi, num)
            return [float(v) for v in values]
        if not (isinstance(value, list) and value and all(_is_num(v) for v in value)):
            self.bad.append(f"{self.source}: {what}, got {value!r}")
            return []
        if len(value) > MAX_GRID:
            self.bad.append(f"{self.source}: {key} lists {len(value)} values; at most "
                            f"{MAX_GRID}")
            return []
        if any(self.ranged(kind, f"every {key}", v) is None for v in value):
            return []
        if len(set(value)) != len(value):
            self.bad.append(f"{self.source}: {key} lists a value twice; list each once")
            return []
        return [float(v) for v in value]


def check_workload(cfg: SweepConfig):
    """UsageError (the estimate and the limit) if the sweep would hold more trajectory memory
    or integrate more steps than allowed ([limits], --max-memory, --max-steps)."""
    from stepzoo.validate import GIB, check_budget
    lanes = min(cfg.points_per_chunk, len(cfg.points))
    steps = max(round(cfg.horizon / cfg.hs[0]), cfg.stab_steps) + 1   # every call's length
    blocks = -(-len(cfg.points) // cfg.points_per_chunk)
    # Per method and block: accuracy and stability runs at every step, the probes past the
    # grid (doubling to h_probe_max, ten halvings) and the bisection to rel_tol.
    probes = 2 * len(cfg.hs) + math.log2(cfg.h_probe_max / cfg.hs[-1]) + 10 \
        + math.log2(1 / cfg.rel_tol) + 2
    memory = cfg.max_memory_gib and cfg.max_memory_gib * GIB
    check_budget(f"the sweep {cfg.name!r}", steps, lanes, len(cfg.x0),
                 calls=len(cfg.methods) * blocks * probes, memory=memory,
                 max_steps=cfg.max_steps)
