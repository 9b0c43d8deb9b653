"""The plain data each report figure is drawn from: named arrays, its axes (labels with units,
scales) and series, the caption and the PNG file name. `figure_data` computes them from the
loaded results; the two renderers (`figures`, PNG, and `interactive`, Plotly) read only these,
so both draw the same numbers under the same labels.
Only NumPy here: a process that only draws needs no pandas, JAX or result tables."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


# The axis labels every renderer writes, each in one place (with its unit).
H_LABEL = "step size h [s]"
LIMIT_LABEL = "largest stable step h [s]"
RE_Z, IM_Z = "Re(h lambda)", "Im(h lambda)"
EVALS_LABEL = "right-hand-side evaluations per simulated second"
TIME_LABEL = "wall time per simulated second, fastest round [s]"
X_LABEL, Y_LABEL = "X [m]", "Y [m]"
DEVIATION_LABEL = "median replay deviation of the exact plans [m]"
PLAN_TIME_LABEL = "median plan time [s]"


@dataclass(frozen=True)
class Axes:
    """One panel's axes as both renderers draw them: labels with units, and scales ("linear"
    or "log"); equal: one unit is as long on both axes (positions, the complex plane)."""
    xlabel: str
    ylabel: str
    xscale: str = "linear"
    yscale: str = "linear"
    equal: bool = False


def verdict_label(name: str, h: float) -> str:
    """The legend entry of a step asked about with `stepzoo report --verdict`."""
    return f"{name} at h = {h:g} s (verdict)"


@dataclass(frozen=True)
class Run:
    """One sampled run of a trajectory panel at step h [s]; past: beyond its stability limit."""
    h: float
    x: np.ndarray
    y: np.ndarray
    past: bool


@dataclass(frozen=True)
class TrajectoryPanel:
    """One method's sampled runs; lo, hi: the (x, y) corners of the reference and the stable
    runs, the view in which a blown-up run leaves the panel."""
    method: str
    runs: list
    lo: np.ndarray
    hi: np.ndarray


@dataclass(frozen=True)
class Trajectories:
    """Figures 1 and 2: a state against time, or two states' plane, per method over the
    reference; equal: the axes share a scale (positions [m]); tuned: the tuned method or
    None."""
    number: int
    title: str
    caption: str
    file: str
    xlabel: str
    ylabel: str
    equal: bool
    reference: tuple
    panels: list
    tuned: str | None = None

    @property
    def axes(self) -> list[Axes]:
        return [Axes(self.xlabel, self.ylabel, equal=self.equal)]

    @property
    def series(self) -> list[str]:
        return ["reference", *(p.method for p in self.panels)]


@dataclass(frozen=True)
class RegionPanel:
    """One method's stability region on the grid (x = Re z, y = Im z, stable where |R| <= 1),
    its boundary |R(z)| = 1 (NaN between pieces), and which h*lambda points lie outside."""
    method: str
    x: np.ndarray
    y: np.ndarray
    stable: np.ndarray
    boundary: tuple
    outside: np.ndarray


@dataclass(frozen=True)
class Regions:
    """Figure 3: every method's region with z = h*lambda of the envelope at the tuned step h
    [s] (None without a tuned config); outside: z's points outside the tuned method's region."""
    number: int
    title: str
    caption: str
    file: str
    h: float | None
    z: np.ndarray
    re: tuple
    im: tuple
    tuned: str | None
    outside: np.ndarray
    panels: list

    @property
    def axes(self) -> list[Axes]:
        return [Axes(RE_Z, IM_Z, equal=True)]

    @property
    def series(self) -> list[str]:
        return [p.method for p in self.panels]


@dataclass(frozen=True)
class ErrorPanel:
    """One method's worst error norm at each step h [s] stable everywhere; slope: the declared
    order's line (h pair, error pair, order) or None; fit: the fitted order (NaN if none)."""
    method: str
    h: np.ndarray
    err: np.ndarray
    fit: float
    slope: tuple | None
    verdicts: list


@dataclass(frozen=True)
class ErrorVsStep:
    """Figure 4: error against step, log-log, one panel per method; verdicts: (method, h)."""
    number: int
    title: str
    caption: str
    file: str
    ylabel: str
    panels: list
    verdicts: list

    @property
    def axes(self) -> list[Axes]:
        return [Axes(H_LABEL, self.ylabel, "log", "log")]

    @property
    def series(self) -> list[str]:
        return [p.method for p in self.panels]


@dataclass(frozen=True)
class WorkLine:
    """One method's points, one per step h [s] stable everywhere: worst error, RHS
    evaluations and wall time per simulated second (fastest round; the median and slowest
    rounds' NaN for a sweep timed once)."""
    method: str
    h: np.ndarray
    worst: np.ndarray
    evals_per_s: np.ndarray
    time_per_s: np.ndarray
    time_median: np.ndarray
    time_max: np.ndarray


@dataclass(frozen=True)
class WorkPrecision:
    """Figure 5 (or one per problem of a suite): error against cost; tol and pick (the tuned
    point, a WorkLine of zero or one point) None without a tuned config."""
    number: int
    title: str
    caption: str
    file: str
    ylabel: str
    error_label: str
    unit: str
    lines: list
    tuned: str | None = None
    tuned_h: float | None = None
    tol: float | None = None
    pick: WorkLine | None = None

    @property
    def axes(self) -> list[Axes]:
        """The evaluations panel, then the wall-time panel (bars to the median round)."""
        return [Axes(EVALS_LABEL, self.ylabel, "log", "log"),
                Axes(TIME_LABEL, self.ylabel, "log", "log")]

    @property
    def series(self) -> list[str]:
        return [line.method for line in self.lines] + (["tuned choice"] if self.pick else [])


@dataclass(frozen=True)
class LimitCurve:
    """The operating points at one value of the colour variable (None without one), ordered
    by x: predicted and measured largest stable step [s]; blowup, solver, untried: where the
    measured one is a blow-up, the end of the converging solves, or not found up to h_tried
    [s], the largest step tried."""
    value: float | None
    x: np.ndarray
    pred: np.ndarray
    meas: np.ndarray
    blowup: np.ndarray
    solver: np.ndarray
    untried: np.ndarray
    h_tried: float | None


@dataclass(frozen=True)
class LimitPanel:
    """One method's curves; unlimited: no finite limit predicted (A-stable)."""
    method: str
    curves: list
    unlimited: bool
    verdicts: list


@dataclass(frozen=True)
class StableStep:
    """Figure 6: largest stable step against xvar, a curve per value of cvar (or None)."""
    number: int
    title: str
    caption: str
    file: str
    xvar: str
    cvar: str | None
    xlabel: str
    values: list
    panels: list
    any_failed: bool
    verdicts: list
    x_span: tuple

    @property
    def axes(self) -> list[Axes]:
        return [Axes(self.xlabel, LIMIT_LABEL, yscale="log")]

    @property
    def series(self) -> list[str]:
        return [p.method for p in self.panels]


@dataclass(frozen=True)
class PlanMap:
    """One planned scenario: occupancy (row 0 at the bottom) over extent (x0, x1, y0, y1)
    [m], tree edges as (k, 2) arrays [m], the path's (t, X, Y, heading) rows or None, start
    and goal poses (X [m], Y [m], heading [rad]), its sub-caption and PNG name."""
    name: str
    status: str
    occupied: np.ndarray
    extent: tuple
    tree: list
    path: np.ndarray | None
    start: tuple
    goal: tuple
    caption: str
    file: str

    @property
    def axes(self) -> list[Axes]:
        return [Axes(X_LABEL, Y_LABEL, equal=True)]

    @property
    def series(self) -> list[str]:
        return ["tree"] * bool(self.tree) + ["path"] * (self.path is not None) + \
            ["start", "goal"]


@dataclass(frozen=True)
class Plans:
    """Figure 7: every planned scenario."""
    number: int
    title: str
    caption: str
    maps: list = field(default_factory=list)


@dataclass(frozen=True)
class Tradeoff:
    """Figure 8: an integrator per point: median plan time [s] against median and largest
    replay deviation [m], exact rate, tuned, the paper's method, on the Pareto front; margin:
    the planner's collision margin [m] or None."""
    number: int
    title: str
    caption: str
    file: str
    integrator: list
    role: list
    time_s: np.ndarray
    deviation_m: np.ndarray
    deviation_max_m: np.ndarray
    exact_rate: np.ndarray
    tuned: np.ndarray
    paper: np.ndarray
    pareto: np.ndarray
    margin: float | None

    @property
    def axes(self) -> list[Axes]:
        return [Axes(DEVIATION_LABEL, PLAN_TIME_LABEL, "log", "log")]

    @property
    def series(self) -> list[str]:
        return [*self.integrator, "Pareto front"]
