"""The search for each lane's largest stable step [s], as functions of a probe: bracket it by
the step grid, extend the bracket by ladders where the grid holds no failure (or no stable
step), and narrow it to the relative tolerance, guided by the predicted limit. A probe runs
the stability test at candidate steps; these functions hold no state and run nothing else."""
from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

NARROWING = ("the grid's bracket [lo, hi] (lo stable, hi not) shrinks to hi / lo <= 1 + "
             "rel_tol; the first round probes at h_pred (and rel_tol apart around it when the "
             "block's call has room), later ones gallop away from it, then split the bracket "
             "evenly; h_meas is lo, so ratio 1 means a limit in [h_pred, h_pred (1 + rel_tol))")
RISE_DOUBLINGS = 64     # the upward ladder's doublings of the grid's largest step, at most
FALL_HALVINGS = 10      # the downward ladder's halvings of its smallest
PRED_LADDER = 2.0 ** (np.arange(-1, 7) / 2)   # multiples of h_pred probed besides the grid


class Outcome(NamedTuple):
    """Stability runs' results, each of one shape: stable, blow-up time [s] (NaN where none),
    and whether every nonlinear solve converged."""
    stable: np.ndarray
    blowup_t: np.ndarray
    converged: np.ndarray


# probe(lanes (N,), h (N,) [s]) -> Outcome, each (N,): the stability test of lane lanes[i]
# at step h[i].
Probe = Callable[[np.ndarray, np.ndarray], Outcome]


class Bracket(NamedTuple):
    """Per lane, lo (stable) and hi (not) [s] around the limit (both inf: nothing failed; both
    0: nothing was stable; NaN: not bracketed yet), and the cause of hi's failure: 'unstable',
    'solver failed' or 'none'."""
    lo: np.ndarray
    hi: np.ndarray
    cause: np.ndarray


class MeasuredLimit(NamedTuple):
    """Per lane, the largest stable step h_meas [s] and what failed just above it."""
    h_meas: np.ndarray
    cause: np.ndarray


def at_steps(probe: Probe, lanes, hs) -> Outcome:
    """The probe of lanes (L,) at steps hs (K,) [s], the same for each, or (K, L): outcomes
    (L, K). Step by step: a probe's call then holds as few steps as it can, which keeps an
    implicit method's Newton iterations, run in lockstep over a call, as few as each needs."""
    hs = np.asarray(hs, float)
    hs = np.broadcast_to(hs[:, None] if hs.ndim == 1 else hs, (len(hs), len(lanes)))
    out = probe(np.tile(lanes, len(hs)), hs.ravel())
    return Outcome(*(a.reshape(hs.shape).T for a in out))


def _cause(converged: bool) -> str:
    """What failed at a step whose stability run did not pass."""
    return "unstable" if converged else "solver failed"


def bracket(grid: Outcome, hs) -> Bracket:
    """Brackets from the outcomes (B, K) at the steps hs [s] (K,), or per lane (B, K),
    ascending: between the last stable step before the first failure and that failure; NaN
    where the first or no step fails."""
    B = len(grid.stable)
    hs = np.broadcast_to(np.asarray(hs, float), grid.stable.shape)
    lo, hi = np.full(B, np.nan), np.full(B, np.nan)
    cause = np.full(B, "none", object)
    bad = ~grid.stable
    first = np.argmax(bad, axis=1)
    inner = np.where(bad.any(axis=1) & (first > 0))[0]
    lo[inner], hi[inner] = hs[inner, first[inner] - 1], hs[inner, first[inner]]
    cause[inner] = np.where(grid.converged[inner, first[inner]], "unstable", "solver failed")
    return Bracket(lo, hi, cause)


def extend(br: Bracket, probe: Probe, grid: Outcome, hs, h_probe_max: float,
           pred) -> Bracket:
    """Brackets for the lanes the grid (steps hs [s], (K,) or per lane (B, K)) left open:
    those stable at its largest step climb a doubling ladder to h_probe_max [s] (both ends
    inf where nothing fails), those unstable at its smallest descend a halving one (both 0
    where nothing is stable). Where the predicted limit pred [s] is inf, one probe at
    h_probe_max comes first; the ladder climbs only for the lanes that fail there, where the
    prediction is off."""
    hs = np.broadcast_to(np.asarray(hs, float), grid.stable.shape)
    lo, hi, cause = br.lo.copy(), br.hi.copy(), br.cause.copy()
    rising = np.where(np.isnan(lo) & grid.stable[:, -1])[0]
    unbounded = rising[np.isinf(pred[rising])]
    if len(unbounded):
        ok = at_steps(probe, unbounded, np.array([h_probe_max])).stable[:, 0]
        lo[unbounded[ok]] = hi[unbounded[ok]] = np.inf
        rising = np.setdiff1d(rising, unbounded[ok])
    for top in np.unique(hs[rising, -1]):
        lanes = rising[hs[rising, -1] == top]
        ladder = np.array([*(top * 2.0 ** k for k in range(1, RISE_DOUBLINGS)
                             if top * 2.0 ** k < h_probe_max), h_probe_max])
        ok, _, conv = at_steps(probe, lanes, ladder)
        for r, b in enumerate(lanes):
            fails = np.where(~ok[r])[0]
            if len(fails):
                j = fails[0]
                lo[b], hi[b] = ladder[j - 1] if j else top, ladder[j]
                cause[b] = _cause(conv[r, j])
            else:
                lo[b] = hi[b] = np.inf
    falling = np.where(np.isnan(lo))[0]
    for low in np.unique(hs[falling, 0]):
        lanes = falling[hs[falling, 0] == low]
        ladder = low / 2.0 ** np.arange(1, FALL_HALVINGS + 1)
        ok = at_steps(probe, lanes, ladder).stable
        for r, b in enumerate(lanes):
            fine = np.where(ok[r])[0]
            cause[b] = _cause(grid.converged[b, 0])
            if len(fine):
                j = fine[0]
                lo[b], hi[b] = ladder[j], ladder[j - 1] if j else low
            else:
                lo[b] = hi[b] = 0.0
    return Bracket(lo, hi, cause)


def narrow(br: Bracket, probe: Probe, pred, rel_tol: float, slots: int) -> Bracket:
    """Each finite bracket shrunk until hi / lo <= 1 + rel_tol, guided by the predicted limits
    pred [s] (see `candidates`). Every round makes one probe call of `slots` candidates at
    most: the lanes still open share them, so the last few get several each."""
    lo, hi, cause = br.lo.copy(), br.hi.copy(), br.cause.copy()
    tau = math.log1p(rel_tol)
    with np.errstate(invalid="ignore", divide="ignore"):
        guess = np.where((pred > lo) & (pred < hi), np.log(pred), np.nan)
    rounds = np.zeros(len(lo), int)

    def open_():
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(hi) & (np.log(hi / lo) > tau * (1 + 1e-9)))[0]

    while len(todo := open_()):
        share = slots // len(todo)
        lanes, cands = [], []
        for b in todo:
            # The gallop away from the guess: tau in the second round, doubling after.
            c = np.exp(candidates(math.log(lo[b]), math.log(hi[b]), guess[b],
                                  tau * 2.0 ** (rounds[b] - 1), share, rounds[b] == 0, tau))
            lanes += [b] * len(c)
            cands.append(c)
        ok, _, conv = probe(np.array(lanes), np.concatenate(cands))
        at = 0
        for b, c in zip(todo, cands):
            ok_b, conv_b = ok[at: at + len(c)], conv[at: at + len(c)]
            at += len(c)
            fails = np.where(~ok_b)[0]
            if len(fails):
                j = fails[0]
                hi[b] = c[j]
                cause[b] = _cause(conv_b[j])
                if j:
                    lo[b] = c[j - 1]
            else:
                lo[b] = c[-1]
        rounds[todo] += 1
    return Bracket(lo, hi, cause)


def candidates(lo, hi, guess, width, k, first, tau):
    """Up to k candidate log-steps strictly inside the bracket (lo, hi) of log-steps, for a
    bracket wider than tau = log(1 + rel_tol). Where the predicted limit `guess` lies in the
    bracket, the first round probes at it and tau apart around it (the bracket is then
    often done), and later rounds gallop from the bracket's end nearest the guess, `width`
    away (doubling per round), until that passes the bracket's middle; otherwise, and then,
    k evenly spaced points."""
    even = lo + (hi - lo) * np.arange(1, k + 1) / (k + 1)
    if np.isnan(guess) or (hi - lo) <= (k + 1) * tau:
        return even
    if first:
        near = guess + tau * (np.arange(k) - (k - 1) // 2)
        near = near[(near > lo) & (near < hi)]
        return near if len(near) else even
    if 2 * width >= hi - lo:
        return even
    if guess - lo <= hi - guess:
        return lo + width * np.arange(1, k + 1) / k
    return (hi - width * np.arange(1, k + 1) / k)[::-1]


def with_ladder(grid: Outcome, probe: Probe, hs, pred, top: float = math.inf
                ) -> tuple[Outcome, np.ndarray]:
    """The grid's outcomes (B, K) at steps hs (K,) [s] with the probes at PRED_LADDER times
    each lane's finite predicted limit pred (B,) [s] merged in, per lane ascending: (the
    outcomes (B, K + L), their steps (B, K + L)). A test that is not monotone in h (a
    saturating model's chatter that needs steps within the horizon to grow) can pass at a
    coarse grid step above a failing one; the ladder probes where the limit should be.
    Rungs that cannot move the bracket are not probed (`ladder_rungs`); each stands in as a
    copy of the grid's largest step and its outcome."""
    L = len(PRED_LADDER)
    H = np.broadcast_to(np.asarray(hs, float), grid.stable.shape)
    with np.errstate(invalid="ignore"):
        rungs = np.asarray(pred, float)[:, None] * PRED_LADDER
    extra = np.repeat(H[:, -1:], L, 1)
    more = [np.repeat(a[:, -1:], L, 1) for a in grid]
    failed = np.where((~grid.stable).any(1), np.where(~grid.stable, H, np.inf).min(1), np.inf)
    for r in range(L):          # ascending: a rung past a lane's first failure is not needed
        lanes = np.where(ladder_rungs(rungs[:, r], failed, top))[0]
        if not len(lanes):
            continue
        out = probe(lanes, rungs[lanes, r])
        extra[lanes, r] = rungs[lanes, r]
        for a, b in zip(more, out):
            a[lanes, r] = b
        bad = lanes[~out.stable]
        failed[bad] = np.minimum(failed[bad], rungs[bad, r])
    H = np.concatenate([H, extra], 1)
    order = np.argsort(H, axis=1, kind="stable")
    pick = lambda a, b: np.take_along_axis(np.concatenate([a, b], 1), order, 1)
    return Outcome(*(pick(a, b) for a, b in zip(grid, more))), \
        np.take_along_axis(H, order, 1)


def ladder_rungs(rung, failed, top: float) -> np.ndarray:
    """Which lanes probe their rung rung (B,) [s] of the predicted-limit ladder: a finite,
    positive prediction (an unbounded one has no ladder: one probe at the top decides it,
    `extend`), at most `top` [s] (steps the horizon or h_probe_max rule out), and below the
    lane's first failure so far failed (B,) [s] (the bracket ends at the first failure:
    a probe past it cannot move it)."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(rung) & (rung > 0) & (rung <= top) & (rung < failed)


def measured_limit(grid: Outcome, probe: Probe, hs, pred, h_probe_max: float,
                   rel_tol: float, slots: int, ladder: bool = False) -> MeasuredLimit:
    """The largest stable step per lane [s] from the grid's outcomes (B, K) at steps hs (K,):
    bracketed (with the probes of `with_ladder` where `ladder`), extended, then narrowed to
    rel_tol from the predicted limits pred (B,) [s]. inf: nothing failed up to h_probe_max
    (the largest step worth a probe); 0: unstable even at the smallest probe."""
    if ladder:
        grid, hs = with_ladder(grid, probe, hs, pred, h_probe_max)
    br = extend(bracket(grid, hs), probe, grid, hs, h_probe_max, pred)
    if (np.isfinite(br.hi) & (br.hi > br.lo * (1 + rel_tol))).any():
        br = narrow(br, probe, pred, rel_tol, slots)
    return MeasuredLimit(br.lo, br.cause)
