"""What the sweep measures from trajectories: the blow-up rule, the observed convergence
order on the asymptotic range of steps, and the rules' wording for the results' manifest."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BLOWUP_RULE = ("A stability run starts from the operating point's initial state plus a "
               "perturbation (the same amount of each eigenmode of the Jacobian there that "
               "bounds a step, of size `perturbation` in the error norm: the largest error "
               "state over its scale) and is compared with a run of the same method and step "
               "from the initial state itself; it blows up at the first step where their "
               "distance in the error norm is not finite or exceeds `growth` times its start, "
               "and is stable if that never happens within `steps` steps and every nonlinear "
               "solve converged.")
AGREE_TOL = 0.1          # h_meas / h_pred within [1 / (1 + tol), 1 + tol]: they agree
ERR_CEIL = 1.0            # errors this many times the solution's size are not asymptotic
FLOOR_FACTOR = 10.0       # errors below this many reference tolerances are not the method's
SLOPE_SPREAD = 0.1        # local slopes of one asymptotic range differ by at most this
MIN_SLOPE = 0.5           # a range starts where local slopes are at least this (every method
                          # here has order >= 1): below, the error is not the method's own
ORDER_TOL = 0.2           # an observed order this close to the declared one matches it
STIFF_H_RHO = 1.0         # a step h with h * rho(J) above this is in the stiff range: the
                          # classical error expansion (in powers of h lambda) does not hold
ORDER_RULE = (f"slope of log err on log h over the asymptotic range, read from every accuracy "
              f"run whose nonlinear solves converged against a reference that succeeded, "
              f"whatever the blow-up test says of that step: the finest run of at "
              f"least 3 consecutive usable steps ({FLOOR_FACTOR:g} * (atol + rtol * max|x|) "
              f"< err < {ERR_CEIL:g} * max|x|) whose local slopes are at least {MIN_SLOPE:g} (an "
              f"error that barely falls, or grows, as h shrinks is round-off accumulating over "
              f"more steps, not the method's) and differ by at most {SLOPE_SPREAD:g}, extended "
              "to coarser steps while they still do (err and |x|: the error states over their "
              "scales); order_h_min/order_h_max/order_points record the range, order_note why "
              "there is none (then the fit is over every usable step, or NaN with fewer than 3)")


def run_error(spec, x, ref, estimate: str) -> np.ndarray:
    """Each run's error `err` (B,): the scaled distance (the error states over their scales)
    of runs x (B, N+1, d) from the reference ref at the same times, its largest over the run
    (estimate "max") or its value at the end ("final"; inf for a run that left the finite
    range on the way, which has no final error to speak of): sweep_config.ESTIMATES."""
    with np.errstate(invalid="ignore", over="ignore"):
        dev = spec.scaled(x - ref)
    if estimate == "max":
        return dev.max(axis=1)
    return np.where(np.isfinite(dev).all(axis=1), dev[:, -1], np.inf)


@dataclass(frozen=True)
class OrderFit:
    """An observed order and the range of steps [s] it was fitted on."""
    order: float
    h_min: float
    h_max: float
    points: int
    note: str              # "asymptotic", or why no asymptotic range was found

    def columns(self) -> dict:
        """The `limits` table's order columns."""
        return {"order_fit": self.order, "order_h_min": self.h_min, "order_h_max": self.h_max,
                "order_points": self.points, "order_note": self.note}


def order_fit(hs, errors, rtol, atol, scale) -> OrderFit:
    """The observed order: slope of log error on log h over the asymptotic range, the finest
    run of >= 3 consecutive usable steps whose slopes, >= MIN_SLOPE, agree within SLOPE_SPREAD,
    extended to coarser steps while they still agree (local slopes tend to the order as h
    goes to 0, and the finest usable steps are nearest that limit). `hs` [s] and `errors`
    are those of the accuracy runs whose solves converged against a good reference (not
    only the steps the blow-up test calls stable: a perturbation that grows with the exact
    solution, or an error scale that makes it unphysical, would hide the order). A step is
    usable when its error is finite and lies above FLOOR_FACTOR reference tolerances (atol +
    rtol * scale, `scale` the size of the state the error is of; below, the error is the
    reference's or round-off) and below ERR_CEIL times that size (above, it is no
    approximation at all)."""
    hs, e = np.asarray(hs, float), np.asarray(errors, float)
    by_h = np.argsort(hs)
    hs, e = hs[by_h], e[by_h]
    finite = np.isfinite(e)
    floor = FLOOR_FACTOR * (atol + rtol * scale)
    ceil = ERR_CEIL * scale
    usable = finite & (e > floor) & (e < ceil)
    if usable.sum() < 3:
        note = "unstable at every step" if not finite.any() else (
            f"{usable.sum()} stable step(s) in the range: {(finite & (e <= floor)).sum()} at "
            f"the reference's accuracy, {(finite & (e >= ceil)).sum()} with error above "
            f"{ERR_CEIL:g} x the solution's size")
        return OrderFit(float("nan"), float("nan"), float("nan"), int(usable.sum()), note)
    h, err = np.log(hs[usable]), np.log(e[usable])
    slopes = np.diff(err) / np.diff(h)
    best = None                                 # (first, last) point of the range
    for i in range(len(h) - 2):
        first = slopes[i:i + 2]
        if np.ptp(first) <= SLOPE_SPREAD and first.min() >= MIN_SLOPE:
            j = i + 2
            while j + 1 < len(h) and np.ptp(slopes[i:j + 1]) <= SLOPE_SPREAD:
                j += 1
            best = (i, j)
            break
    if best is None:
        lo, hi, note = 0, len(h) - 1, (f"no asymptotic range: local slopes from "
                                      f"{slopes.min():.2f} to {slopes.max():.2f}")
    else:
        (lo, hi), note = best, "asymptotic"
    fit = float(np.polyfit(h[lo: hi + 1], err[lo: hi + 1], 1)[0])
    return OrderFit(fit, float(np.exp(h[lo])), float(np.exp(h[hi])), hi - lo + 1, note)


def orders_matched(statuses, tol: float = ORDER_TOL) -> str:
    """"N of M (problem, method) pairs within tol of the declared order", from their
    order statuses."""
    statuses = list(statuses)
    return (f"{sum(s == 'matches' for s in statuses)} of {len(statuses)} (problem, method) "
            f"pairs within {tol:g} of the declared order")


def order_status(observed: float, declared: float, note: str,
                 h_rho: float = float("nan"), nonsmooth: bool = False) -> str:
    """How an observed order compares with the declared one: "matches" (within ORDER_TOL on
    an asymptotic range), "limited by non-smooth f" (it is below the declared one, and f is
    not smooth along the references, `nonsmooth`: bench.nonsmooth; the error at such a point falls
    like h or h^2 whatever the method), "stiff range" (it does not match, and even the
    finest step of the fit has h * rho(J) > STIFF_H_RHO, `h_rho`, rho the largest spectral
    radius of the Jacobian along the reference: the classical order is a statement about
    smaller steps, and order reduction at these is the theory of stiff problems), "below
    declared", "above declared", "no asymptotic range", or "not observable"."""
    if not np.isfinite(observed):
        return "not observable"
    if note == "asymptotic" and abs(observed - declared) <= ORDER_TOL:
        return "matches"
    # A kink or jump of f lowers the observed order; it cannot be what an order above the
    # declared one comes from.
    if nonsmooth and observed < declared:
        return "limited by non-smooth f"
    if h_rho > STIFF_H_RHO:
        return "stiff range"
    if note != "asymptotic":
        return "no asymptotic range"
    return "below declared" if observed < declared else "above declared"


def disagreement(limits) -> dict:
    """A method's points (`limits` rows) whose limit_note is not "agrees", their number and
    most common note."""
    notes = limits["limit_note"] if "limit_note" in limits else limits.iloc[:0, 0]
    off = notes[notes != "agrees"]
    return {"disagreeing_points": int(len(off)),
            "disagreement_note": str(off.value_counts().index[0]) if len(off) else ""}


def own_limits(limits) -> dict:
    """A method's limits over its points (`limits` rows, one method), the solver's apart from
    the method's: h_meas_min [s] over the points where the method itself blew up or nothing
    failed (NaN when a failed nonlinear solve ended every point's stable range), worst_ratio
    of those points' h_meas / h_pred (the one farthest from 1), and over the points where a
    failed solve ended it, their number (solver_limited_points) and smallest h_meas
    (h_solver_limit_min [s], NaN when none): a solver's failure says nothing of the method's
    stability."""
    failed = (limits["limit_cause"] == "solver failed").to_numpy() \
        if "limit_cause" in limits else np.zeros(len(limits), bool)
    own = limits[~failed]
    ratios = own["ratio"].to_numpy(float) if "ratio" in own else np.zeros(0)
    ratios = ratios[np.isfinite(ratios) & (ratios > 0)]
    return {"h_meas_min": float(own["h_meas"].min()) if len(own) else float("nan"),
            "worst_ratio": float(ratios[np.argmax(np.abs(np.log(ratios)))]) if len(ratios)
            else float("nan"),
            "solver_limited_points": int(failed.sum()),
            "h_solver_limit_min": float(limits["h_meas"][failed].min()) if failed.any()
            else float("nan")}


def limit_note(row: dict, growth: float, tol: float = AGREE_TOL) -> str:
    """Why a `limits` row's h_meas and h_pred differ, from its columns ("agrees" where the
    ratio lies within [1 / (1 + tol), 1 + tol] or both are unbounded): the model's own
    divergence (ref_growth > growth), a failed solve, non-smooth f, or the measured run's
    binding state and time against the prediction's."""
    pred, meas, ratio = row["h_pred"], row["h_meas"], row["ratio"]
    close = np.isfinite(ratio) and ratio > 0 and abs(np.log(ratio)) <= np.log1p(tol)
    if close or (np.isinf(pred) and np.isinf(meas)):
        return "agrees"
    fail = (f"state {row['unstable_state']} departs at t = {row['unstable_t']:.3g} s"
            if row.get("unstable_state") else "")
    if row.get("ref_growth", np.nan) > growth:
        return (f"the model is unstable here: the reference's own perturbation grows "
                f"{row['ref_growth']:.3g}-fold within the horizon (the method is judged "
                f"against that growth){'; ' + fail if fail else ''}")
    if row["limit_cause"] == "solver failed":
        return "a nonlinear solve failed inside the horizon just above h_meas"
    if np.isfinite(row.get("nonsmooth_t", np.nan)):
        return (f"f is not smooth at t = {row['nonsmooth_t']:.3g} s ({row['nonsmooth_what']}, "
                f"{row['nonsmooth_kind']}): the frozen Jacobians do not bound the step there")
    if np.isinf(meas):
        return f"nothing failed up to h_probe_max = {row['h_probe_max']:.3g} s"
    if meas > pred:
        return (f"measured above the prediction: the mode binding at t = {row['t_bind']:.3g} "
                f"s is that fast only briefly or saturates within the horizon; just above "
                f"h_meas {fail or 'no state departs'}")
    return (f"unstable below the prediction (a nonlinear effect the frozen Jacobians do not "
            f"see){': ' + fail if fail else ''}")
