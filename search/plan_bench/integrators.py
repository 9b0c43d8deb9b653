"""The integrators a plan-bench compares: `METHOD:H` given on the command line, or a tuned
TOML's choice and its runners-up, each a (method, h [s]) with a label and a role, applied to
one planner config so that every integrator plans with the same planner parameters."""
from __future__ import annotations

import math
from dataclasses import dataclass

from stepzoo.errors import UsageError

ROLES = ("tuned", "runner-up", "given")


@dataclass(frozen=True)
class Integrator:
    method: str
    h: float                  # [s] the step of every tree shooting
    role: str                 # one of ROLES: where it came from

    @property
    def label(self) -> str:
        """`method:h`, as the --integrator flag spells it."""
        return f"{self.method}:{self.h:.6g}"


def parse_spec(text: str) -> Integrator:
    """`METHOD:H` (H a step [s] > 0) as an Integrator; else UsageError."""
    from stepzoo.integrators import METHODS
    from stepzoo.validate import check
    method, sep, h = text.partition(":")
    try:
        step = float(h)
    except ValueError:
        step = math.nan
    if not sep or not math.isfinite(step):
        raise UsageError(f"--integrator {text!r}: give METHOD:H, a zoo method and a step [s], "
                         "such as rk4:0.05")
    if method not in METHODS:
        raise UsageError(f"--integrator {text!r}: unknown method {method!r}; use one of "
                         f"{', '.join(METHODS)}")
    return Integrator(method, check("step", f"--integrator {text!r}: the step", step), "given")


def from_tuned(path, runners_up: int | None = None) -> list[Integrator]:
    """The choice of a TOML written by `stepzoo tune` and its runners-up that qualify (the
    first `runners_up` of them; None: all), in the TOML's order. A runner-up listed without
    a step (`qualifies = false`: no step of that method met the tolerance) is not planned.
    The file is checked as the tuned kind (stepzoo.tuned_file), as `plan` checks it."""
    from stepzoo.config_schema import check
    from stepzoo.integrators import METHODS
    from stepzoo.tuned_file import PlannerChoice, RunnerUp, TunedFile
    from stepzoo.validate import read_toml
    where = f"--integrators-from {path}"
    tuned = check(TunedFile, read_toml(path, "--integrators-from", "give a TOML file written "
                                       "by `stepzoo tune`"), where)
    qualified = [r for r in tuned.evidence.runners_up if r.h is not None and r.qualifies]
    out: list[Integrator] = []
    rows: list[PlannerChoice | RunnerUp] = [tuned.choice, *qualified[:runners_up]]
    for k, row in enumerate(rows):
        if row.method not in METHODS:
            raise UsageError(f"{where}: " + ("the choice" if k == 0 else f"runner-up {k}")
                             + f" names {row.method!r}, not a method of the zoo "
                             "(`stepzoo methods` lists them)")
        assert row.h is not None          # qualified: the runners-up that have an h
        out.append(Integrator(row.method, row.h, "tuned" if k == 0 else "runner-up"))
    return out


def choose(specs, tuned_path, runners_up, config) -> list[Integrator]:
    """The integrators to compare: the tuned file's, then the given ones, each (method, h)
    once; none given: the planner config's own (method, h), as plan-bench always did."""
    chosen = (from_tuned(tuned_path, runners_up) if tuned_path else []) \
        + [parse_spec(s) for s in specs or []]
    if not chosen:
        return [Integrator(config.method, config.h, "given")]
    out: list[Integrator] = []
    labels: dict[str, float] = {}
    for item in chosen:
        if (item.method, item.h) in {(i.method, i.h) for i in out}:
            continue
        if item.label in labels:
            raise UsageError(f"integrators {item.method} at h = {item.h!r} s and "
                             f"{labels[item.label]!r} s share the label {item.label}; give "
                             "steps that differ in their first 6 digits")
        labels[item.label] = item.h
        out.append(item)
    return out


def configured(config, integrator: Integrator):
    """`config` (planner parameters) with `integrator`'s method and step, validated."""
    from stepzoo.search.planner.config import make_config
    return make_config(integrator.method, integrator.h, config.provenance, config.source,
                       **config.params.model_dump())
