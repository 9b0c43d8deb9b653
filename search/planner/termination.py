"""When a plan stops searching (OMPL's PlannerTerminationCondition), as values composable with
`|`: `timed(seconds) | expansions(n) | exact` stops at whichever comes first."""
from __future__ import annotations

import math
from dataclasses import dataclass
from time import perf_counter


@dataclass(frozen=True)
class Progress:
    """What a condition looks at: expansions done, whether an exact path exists, and the
    search's start on the perf_counter clock [s] (read only when a condition asks)."""
    expansions: int
    solved: bool
    t0: float

    @property
    def elapsed_s(self) -> float:
        return perf_counter() - self.t0


class Termination:
    """A stopping rule; `a | b` stops when either does, `a`'s verdict first."""

    def stop(self, progress: Progress) -> Termination | None:
        """The condition (this one, or a part of it) that says stop, or None."""
        raise NotImplementedError

    def room(self, expansions: int) -> float:
        """How many more expansions this condition allows after `expansions` (inf: it does
        not count them), so a batch of nodes does not overshoot it."""
        return math.inf

    @property
    def budget(self) -> str | None:
        """The plan.json `budget_bound` word when this condition stops a plan, None if a
        plan so stopped ended by itself (and is the same on any machine)."""
        return None

    def __or__(self, other: Termination) -> Termination:
        return AnyOf((self, other))


@dataclass(frozen=True)
class AnyOf(Termination):
    parts: tuple

    def stop(self, progress):
        return next((hit for p in self.parts if (hit := p.stop(progress)) is not None), None)

    def room(self, expansions):
        return min(p.room(expansions) for p in self.parts)

    def __or__(self, other):
        return AnyOf((*self.parts, other))


@dataclass(frozen=True)
class Timed(Termination):
    """Stop after `seconds` [s] of wall time, search and connections."""
    seconds: float

    def stop(self, progress):
        return self if progress.elapsed_s >= self.seconds else None

    @property
    def budget(self):
        return "max_seconds"


@dataclass(frozen=True)
class Expansions(Termination):
    """Stop after `n` expansions."""
    n: int

    def stop(self, progress):
        return self if progress.expansions >= self.n else None

    def room(self, expansions):
        return self.n - expansions

    @property
    def budget(self):
        return "max_expansions"


@dataclass(frozen=True)
class Exact(Termination):
    """Stop at the first exact path: no improvement (OMPL's exact-solution condition)."""

    def stop(self, progress):
        return self if progress.solved else None


def timed(seconds: float) -> Termination:
    return Timed(float(seconds))


def expansions(n: int) -> Termination:
    return Expansions(int(n))


exact = Exact()


def default_termination(params) -> Termination:
    """The planner parameters' budget: max_expansions, then max_seconds."""
    return expansions(params.max_expansions) | timed(params.max_seconds)
