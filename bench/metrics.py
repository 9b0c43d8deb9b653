"""What the sweep measures from trajectories: the blow-up rule, the fitted convergence
order, and the rule's wording for the results' manifest."""
import numpy as np

BLOWUP_RULE = ("A stability run starts from the operating point's initial state plus a "
               "perturbation (the same amount of each eigenmode of the Jacobian there that "
               "bounds a step, of size `perturbation` in the error norm: the largest error "
               "state over its scale) and is compared with a run of the same method and step "
               "from the initial state itself; it blows up at the first step where their "
               "distance in the error norm is not finite or exceeds `growth` times its start, "
               "and is stable if that never happens within `steps` steps and every nonlinear "
               "solve converged.")
ORDER_POINTS = 4          # finest usable steps in the order regression
ERR_CEIL = 1e-1           # larger errors are not in the asymptotic range
FLOOR_FACTOR = 10.0       # errors below this many reference tolerances are not the method's


def order_fit(hs, errors, rtol, atol, scale):
    """Slope of log error on log h over the ORDER_POINTS finest steps whose error lies above
    FLOOR_FACTOR reference tolerances (atol + rtol * scale, `scale` the size of the state
    the error is of) and below ERR_CEIL. NaN when fewer than three steps qualify."""
    hs, e = np.asarray(hs, float), np.asarray(errors, float)
    floor = FLOOR_FACTOR * (atol + rtol * scale)
    sel = np.where(np.isfinite(e) & (e > floor) & (e < ERR_CEIL))[0]
    sel = sel[np.argsort(hs[sel])][:ORDER_POINTS]
    if len(sel) < 3:
        return float("nan")
    return float(np.polyfit(np.log(hs[sel]), np.log(e[sel]), 1)[0])
