"""What the sweep measures from trajectories: the blow-up rule, errors against the reference,
the fitted convergence order and the bisection of the largest stable step.

Blow-up rule: at constant (vx, delta) the lateral state (vy, r) obeys d/dt [vy, r] = A [vy, r]
+ b exactly. A stability run starts it off its equilibrium by the same amount in each
eigenmode of A; the run blows up at the first step where (vy, r) is not finite or its
deviation from the equilibrium, in the eigenmode coordinates of A, has grown past `growth`
times its start. Only (vy, r) count: X, Y, psi integrate them and grow even in exact runs."""
import numpy as np

BLOWUP_RULE = ("A stability run starts the lateral state (vy, r) off its equilibrium by the "
               "same amount in each eigenmode of A(vx, delta) and blows up at the first step "
               "where (vy, r) is not finite or its deviation from the equilibrium, measured in "
               "those eigenmode coordinates, exceeds `growth` times its start; it is stable if "
               "that never happens within `steps` steps.")
ORDER_POINTS = 4          # finest usable steps in the order regression
ERR_CEIL = 1e-1           # larger errors are not in the asymptotic range
FLOOR_FACTOR = 10.0       # errors below this many reference tolerances are not the method's


def modal_frame(A, b):
    """(equilibrium (2,), eigenvectors V (2, 2) complex, V^-1) of d/dt y = A y + b."""
    eq = -np.linalg.solve(A, b)
    _, V = np.linalg.eig(A)
    return eq, V, np.linalg.inv(V)


def perturbed_lateral(A, b, amplitude):
    """Initial (vy, r): the equilibrium plus `amplitude` in each eigenmode (real, since a
    complex pair's eigenvectors are conjugate)."""
    eq, V, _ = modal_frame(A, b)
    return eq + np.real(V @ np.full(2, amplitude))


def blowup_steps(lateral, eq, Vinv, growth):
    """Per lane, the first step index at which a run blows up by the rule above, or -1.
    `lateral` (B, N+1, 2) is (vy, r) at every step; eq (B, 2) and Vinv (B, 2, 2) are the
    lanes' modal frames."""
    with np.errstate(invalid="ignore", over="ignore"):
        w = np.einsum("bij,bnj->bni", Vinv, lateral - eq[:, None, :])
        size = np.max(np.abs(w), axis=2)
        blown = ~np.isfinite(lateral).all(axis=2) | ~(size <= growth * size[:, :1])
    return np.where(blown.any(axis=1), np.argmax(blown, axis=1), -1)


def run_errors(x, ref):
    """Largest absolute error of each state, of position, and the position error at the
    final time, of a run x (n+1, 5) against the reference at the same times. Non-finite
    values count as an infinite error (a blow-up is a result, not a gap)."""
    with np.errstate(invalid="ignore", over="ignore"):
        d = np.abs(x - ref)
        d = np.where(np.isfinite(d), d, np.inf)
        pos = np.hypot(d[:, 0], d[:, 1])
    return d.max(axis=0), float(pos.max()), float(pos[-1])


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


def bisect_limit(is_stable, lo, hi, rel_tol):
    """Largest stable step [s] per lane by geometric bisection of [lo, hi] (lo stable, hi
    unstable); `is_stable(h)` takes and returns (B,) arrays. Lanes with lo == hi are done."""
    lo, hi = np.array(lo, float), np.array(hi, float)
    while np.any(busy := hi > lo * (1 + rel_tol)):
        mid = np.sqrt(lo * hi)
        # Finished lanes still run (the batch has a fixed shape) at a harmless step.
        ok = np.asarray(is_stable(np.where(busy, mid, mid[busy].min())))
        lo = np.where(busy & ok, mid, lo)
        hi = np.where(busy & ~ok, mid, hi)
    return lo
