"""Where the right-hand side is not smooth along a reference: f itself (a `where` switch) or
its Jacobian in x and u (a clamp, min/max, a saturating tyre) changes between two samples of
the dense reference by far more than over the samples around them. A smooth f changes by
O(h) per sample, evenly; such a point changes by O(1) at once, and caps the observed order
of every method near 1 (a jump of f) or 2 (a jump of its Jacobian)."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

JUMP_FACTOR = 10.0   # a change this many times each of the 2 samples' changes on either side
NOISE = 1e-6         # changes below this fraction of the largest |entry| of their kind (f,
                     # df/dx, df/du) along the lane are round-off or the reference's error
NOISE_PER_RTOL = 1e3  # ... and below this many reference rtol of it (a looser reference
                      # moves the samples, and the Jacobian with them, by about rtol)
SUBSAMPLES = 64      # times of the confirming reference inside a candidate interval
CONCENTRATION = 0.5  # a jump makes this much of an entry's change over the interval within
                     # two of them; a smooth change makes about 2 / SUBSAMPLES of it
MAX_CHECKS = 20      # candidate intervals confirmed per lane, the first in time
CHUNK = 256          # samples per call of the Jacobian program (its one compiled shape)
MAX_LEVELS = 6       # nested refinements of one candidate: 32^-6 of the smallest step
REMEDY = ("land a step on the event (split the horizon there), handle the event (switch the "
          "model there), or smooth the model (a smooth clamp or saturation)")
RULE = (f"f and df/dx, df/du (jax.jacfwd) at every sample of the reference at the smallest "
        f"step: a candidate where an entry changes by more than {JUMP_FACTOR:g} times its "
        f"change over each of the two intervals on either side (over one interval, or two when "
        f"the event falls on a sample) and by more than max({NOISE:g}, {NOISE_PER_RTOL:g} rtol) "
        f"of the largest such entry along the lane; confirmed where, on a reference of "
        f"{SUBSAMPLES} times inside the candidate, at least {CONCENTRATION:g} of the entry's "
        f"change happens within two of them, and again inside those two, until the sub-step "
        f"h has h ||df/dx||_inf <= 1 (a stiff but smooth transient spreads out once "
        f"resolved). nonsmooth_t is the first such time, to the last sub-step; kind 'jump': f "
        "itself jumps (nonsmooth_what: the state whose rate jumps), 'kink': its Jacobian does "
        "(nonsmooth_what: the state or input it is taken over)")


@dataclass(frozen=True)
class Event:
    """The first point where f is not smooth along one reference, and how many there are."""
    t: float = float("nan")    # [s]; NaN where f is smooth along the reference
    what: str = ""             # the state or input that jumps (see RULE)
    kind: str = ""             # "jump" (f jumps) or "kink" (its Jacobian does)
    count: int = 0             # separate events along the reference

    def columns(self) -> dict:
        """The `limits` table's non-smooth columns."""
        return {"nonsmooth_t": self.t, "nonsmooth_what": self.what,
                "nonsmooth_kind": self.kind, "nonsmooth_events": self.count}


@cache
def _program(f):
    """Jitted (f, df/dx, df/du) at CHUNK samples ts (CHUNK,), xs (CHUNK, n) of one lane."""
    import jax

    def at(t, x, u, p):
        jx, ju = jax.jacfwd(lambda x, u: f(t, x, u, p), argnums=(0, 1))(x, u)
        return f(t, x, u, p), jx, ju
    return jax.jit(jax.vmap(at, in_axes=(0, 0, None, None)))


def _along(f, ts, xs, u, p) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(f, df/dx, df/du) at the samples ts (T,), xs (T, n), in calls of CHUNK samples (the
    last one padded): one compiled program per model, whatever the sweep's steps."""
    import jax.numpy as jnp
    T = len(ts)
    pad = -T % CHUNK
    ts = np.concatenate([ts, np.full(pad, ts[-1])])
    xs = np.concatenate([xs, np.repeat(xs[-1:], pad, axis=0)])
    parts = [_program(f)(jnp.asarray(ts[i: i + CHUNK]), jnp.asarray(xs[i: i + CHUNK]), u, p)
             for i in range(0, len(ts), CHUNK)]
    fx, jx, ju = (np.concatenate([np.asarray(part[k]) for part in parts])[:T]
                  for k in range(3))
    return fx, jx, ju


def detect(f, ts, xs, u, p, states, inputs, rtol: float, atol: float) -> list[Event]:
    """Per lane, the non-smooth points of f along the reference xs (B, T, n) at times ts (T,)
    [s], inputs u (B, m), parameters p {name: (B,)}; a lane whose reference is not finite
    gets no event. Each candidate interval of the samples is confirmed on references inside
    it at rtol, atol (`_confirm`): a jump stays within a sub-step however fine, where a
    smooth change faster than the samples (a stiff transient) spreads out once resolved."""
    import jax.numpy as jnp
    ts = np.asarray(ts, float)
    out = []
    for b in range(len(xs)):
        if not np.isfinite(xs[b]).all():
            out.append(Event())
            continue
        ub, pb = jnp.asarray(u[b]), {k: jnp.asarray(v[b]) for k, v in p.items()}
        table = _Entries(*_along(f, ts, np.asarray(xs[b]), ub, pb), states, inputs, rtol)
        found: list[tuple[float, str, str]] = []
        for lo, hi in table.candidates()[:MAX_CHECKS]:
            hit = _confirm(f, ts[lo], ts[hi], xs[b, lo], ub, pb, table, rtol, atol)
            if hit is not None:
                found.append(hit)
        out.append(Event(*found[0], count=len(found)) if found else Event())
    return out


def _confirm(f, t0, t1, x0, u, p, table, rtol, atol):
    """(time [s], what, kind) of a jump in [t0, t1] from x0 there, or None: the interval is
    sampled SUBSAMPLES times by a reference; where an entry's change concentrates in two
    sub-intervals, they are sampled in turn, until the sub-step resolves the fastest rate
    there (h ||df/dx||_inf <= 1: a smooth change would spread) or MAX_LEVELS."""
    import jax.numpy as jnp

    from stepzoo.integrators.reference import reference
    for _ in range(MAX_LEVELS):
        sub = np.linspace(t0, t1, SUBSAMPLES + 1)
        ref = reference(f, jnp.asarray(x0), u, p, jnp.asarray(sub), rtol, atol)
        if not bool(ref.success):
            return None
        fx, jx, ju = _along(f, sub, np.asarray(ref.x), u, p)
        fine = _Entries(fx, jx, ju, table.states, table.inputs, rtol, table.floor)
        hit = fine.concentrated(sub)
        if hit is None:
            return None
        j = hit[3]
        rate = np.abs(np.asarray(jx)).sum(axis=-1).max()
        if (sub[1] - sub[0]) * rate <= 1.0:
            break
        t0, t1, x0 = sub[j], sub[j + 2], np.asarray(ref.x)[j]
    return hit[:3]


class _Entries:
    """f, df/dx and df/du at T samples as the columns of one (T, K) table, each with its kind
    (0 f, 1 df/dx, 2 df/du), what it names and its noise floor (`floor`, or the lane's)."""

    def __init__(self, fx, jx, ju, states, inputs, rtol, floor=None):
        fx, jx, ju = np.asarray(fx), np.asarray(jx), np.asarray(ju)
        T, n = fx.shape
        values = np.hstack([fx, jx.reshape(T, -1), ju.reshape(T, -1)])
        self.values = np.where(np.isfinite(values), values, 0.0)
        self.states, self.inputs = states, inputs
        self.kind = np.repeat([0, 1, 2], [n, jx[0].size, ju[0].size])
        self.names = [*states, *[states[j] for _ in range(n) for j in range(n)],
                      *[inputs[j] for _ in range(n) for j in range(ju.shape[2])]]
        if floor is None:
            size = np.array([np.abs(self.values[:, self.kind == k]).max(initial=0.0)
                             for k in range(3)])
            floor = max(NOISE, NOISE_PER_RTOL * rtol) * size[self.kind]
        self.floor = floor

    def candidates(self) -> list[tuple[int, int]]:
        """(first, last) sample of each stretch where an entry changes by JUMP_FACTOR times
        the changes of the 2 intervals on either side, over one interval or (an event on a
        sample splits its jump) two; in time order, overlapping stretches merged."""
        step = np.abs(np.diff(self.values, axis=0))              # (T-1, K) per interval
        pad = np.zeros((2, step.shape[1]))
        padded = np.vstack([pad, step, pad, pad[:1]])            # interval k at row k + 2
        spans = []
        for width in (1, 2):
            change = np.abs(self.values[width:] - self.values[:-width])
            k = np.arange(len(change))
            around = np.max([padded[k], padded[k + 1], padded[k + 2 + width],
                             padded[k + 3 + width]], axis=0)
            fire = (change > JUMP_FACTOR * around) & (change > self.floor)
            spans += [(i, i + width) for i in np.where(fire.any(axis=1))[0]]
        merged: list[tuple[int, int]] = []
        for lo, hi in sorted(spans):
            if merged and lo <= merged[-1][1]:
                merged[-1] = (merged[-1][0], max(hi, merged[-1][1]))
            else:
                merged.append((lo, hi))
        return merged

    def concentrated(self, ts):
        """(time [s], what, kind, first sample of the two intervals) of a jump over the
        samples ts: an entry whose change from the first sample to the last, above its
        floor, happens for at least CONCENTRATION of it within two intervals; None if no
        entry's does. A jump of f itself names it first (its Jacobian may jump with it)."""
        total = np.abs(self.values[-1] - self.values[0])
        two = np.abs(self.values[2:] - self.values[:-2])
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.where(total > self.floor, two.max(axis=0) / total, 0.0)
        jumps = share >= CONCENTRATION
        if not jumps.any():
            return None
        if jumps[self.kind == 0].any():
            jumps &= self.kind == 0
        e = int(np.argmax(np.where(jumps, total / np.maximum(self.floor, 1e-300), -np.inf)))
        j = int(np.argmax(two[:, e]))
        return float(ts[j + 1]), self.names[e], "jump" if self.kind[e] == 0 else "kink", j


def note(limits) -> str:
    """One line on the non-smooth points of a sweep's `limits` rows ("" if none): where, in
    which state or input, and the remedy."""
    if "nonsmooth_t" not in limits:
        return ""
    per_point = limits.drop_duplicates("point")
    hit = per_point[np.isfinite(per_point["nonsmooth_t"].to_numpy(float))]
    if not len(hit):
        return ""
    whats = ", ".join(f"{w} ({k})" for w, k in
                      hit[["nonsmooth_what", "nonsmooth_kind"]].drop_duplicates()
                      .itertuples(index=False))
    first, last = f"{hit['nonsmooth_t'].min():.4g}", f"{hit['nonsmooth_t'].max():.4g}"
    when = first if first == last else f"{first}..{last}"
    return (f"f is not smooth along the reference at {len(hit)} of {len(per_point)} points "
            f"(t = {when} s; {whats}): the fitted orders there are "
            f"the model's, not the methods'; {REMEDY}")
