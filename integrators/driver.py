"""The one driver: `lax.scan` over fixed steps, batched with `vmap` over initial states, inputs
and parameters. Everything that integrates with a fixed step goes through `integrate`.

With `max_steps` given, the step count may be a run-time value: a while loop takes the steps
and writes each state into a buffer of max_steps + 1 rows, so one compilation serves every
step size (output rows past the last step are NaN).

A batch of at least `SMALL_BATCH` trajectories runs in chunks (`chunk_size`) with the batch as
the last axis of the carried state: each component is then a contiguous row that XLA
vectorises, and a chunk's state stays in registers and L1 through all its steps. A smaller
batch is a plain vmap of the one-trajectory loop. With several host devices, batches of at
least `SHARE` trajectories per device are shared out among them, one core each: see
`use_all_cores`."""
import os
import re
import weakref
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.sharding import Mesh, PartitionSpec

from stepzoo.integrators import arguments, kept_programs
from stepzoo.integrators.fast_trig import flagged_trig

# The constants below were chosen by measurement; the numbers are in
# docs/studies/driver-constants-2026-11.md. Rerun them before changing one.
# Trajectories per chunk: small enough to stay in cache with each loop compiled whole, large
# enough to fill the vector lanes (the explicit methods' rates peak here).
CHUNK = 8
# XLA:CPU compiles a chunk's step loop into one native function only when the loop touches
# fewer bytes than its xla_cpu_small_while_loop_byte_threshold (1 kB unless XLA_FLAGS raise
# it, as the `stepzoo` command does); otherwise every operation of every step is a runtime
# call, whose cost a bigger chunk spreads over more trajectories: this many per chunk then.
CHUNK_CALLS = 128
# Implicit methods run Newton's while loop inside every step, which XLA does not compile into
# the native step loop, so they favour larger chunks than explicit ones; but a chunk's loop
# runs until its slowest trajectory converges, which smaller chunks bound.
CHUNK_IMPLICIT = 64
# ... except that up to this many per device run as one chunk: two small chunks cost a second
# compile and run no faster.
ONE_CHUNK_IMPLICIT = 256
# ... and at most as many as hold this many bytes of the largest matrix a step factorises:
# XLA:CPU compiles the step loop as one native function only while its cost model counts
# fewer bytes in the loop than the threshold (the command's 1e8), and the full-Newton
# retry's elimination counts that matrix some tens of times.
SYSTEM_BYTES = 2 << 20
# Below this many trajectories a plain vmap of the one-trajectory loop beats the chunks (their
# bookkeeping is not repaid). A single trajectory runs without a batch axis: a vmap of one
# still costs more than the plain loop.
SMALL_BATCH = 32
# Trajectories per device below which sharing a batch among devices costs more (the
# devices' start-up and gathering) than it saves.
SHARE = 128


class Trajectory(NamedTuple):
    """A fixed-step solution; with integrate_batch every field gains a leading batch axis.

    `converged` says whether every nonlinear solve of an implicit method converged (always
    True for explicit methods): a step whose solve failed, and every state after it, is NaN.
    A non-finite state with converged True is the method's own blow-up, not the solver's."""
    t: jax.Array          # [s], shape (N+1,)
    x: jax.Array          # states, shape (N+1, d); NaN rows past the last step
    evals: jax.Array      # right-hand-side evaluations spent
    converged: jax.Array  # bool, shape (): every nonlinear solve converged


def _bound(f, u, p):
    # In the state's dtype: parameters or constants of another float type in f must not
    # change the type of the carried state.
    return lambda t, y: jnp.asarray(f(t, y, u, p), y.dtype)


def _scan(start, step, x0, h, n_start, n_steps, t0, max_steps):
    """States (N+1, *x0.shape) and the final method state; `start(t0, x0)` gives the starter's
    (ys, state), `step(t, y, state)` one step. Only the step index k is a scalar, so y may
    carry a trailing batch axis."""
    ys0, state = start(t0, x0)
    y_m = ys0[-1] if n_start else x0

    def body(carry, _):
        k, y, st = carry
        y, st = step(t0 + k * h, y, st)
        return (k + 1, y, st), y

    if max_steps is None:
        count = max(n_steps - n_start, 0)
        (_, _, state), ys = lax.scan(body, (n_start, y_m, state), None, length=count)
        xs = jnp.concatenate([x0[None], ys0, ys])[: n_steps + 1]
        if n_steps < n_start:
            state = dict(state, evals=jnp.full_like(state["evals"], jnp.nan))
        return xs, state
    return _stepwise(step, x0, ys0, y_m, state, n_start, n_steps, max_steps, t0, h)


def _stepwise(step, x0, ys0, y_m, state, m, n_steps, max_steps, t0, h):
    """Run-time step count: a while loop over the steps m..n_steps-1, each writing its state
    into its row of a NaN buffer. Blocks of a fixed number of scanned steps, with the steps
    past n_steps masked, compiled and ran slower: they add a loop, and selects to every
    step."""
    # The buffer and the step index like x0, so that under shard_map the loop's carry varies
    # across devices as the steps' values do.
    buf = jnp.full_like(x0, jnp.nan, shape=(max_steps + 1,) + x0.shape)
    buf = lax.dynamic_update_slice(buf, jnp.concatenate([x0[None], ys0])[: max_steps + 1],
                                   (0,) * buf.ndim)

    def body(carry):
        k, y, st, buf = carry
        y, st = step(t0 + k * h, y, st)
        return k + 1, y, st, lax.dynamic_update_slice(buf, y[None], (k + 1,) + (0,) * x0.ndim)

    k0 = jnp.full_like(x0, m, int, shape=())
    _, _, state, buf = lax.while_loop(lambda c: c[0] < n_steps, body, (k0, y_m, state, buf))
    # The starter's rows beyond a step count below n_start are not steps taken.
    rows = jnp.arange(max_steps + 1).reshape((-1,) + (1,) * x0.ndim)
    return jnp.where(rows <= n_steps, buf, jnp.nan), state


def _integrate(method, f, x0, u, p, h, n_steps, t0, max_steps, newton=None, retry=True):
    """(One trajectory, whether a nonlinear solve failed). `method` is a Method's program and
    `newton` its run_options() (None: its own, compiled in); without `retry`, the program
    leaves the full-Newton retry out (see integrate)."""
    method = method if newton is None else method.running(newton, retry)
    fun = _bound(f, u, p)
    h = jnp.asarray(h, x0.dtype)
    xs, state = _scan(lambda t, y: method.start(fun, t, y, h),
                      lambda t, y, st: method.step(fun, t, y, h, st),
                      x0, h, method.n_start, n_steps, t0, max_steps)
    ts = t0 + h * jnp.arange(xs.shape[0])
    return (Trajectory(ts, xs, state["evals"], state["converged"]),
            state.get("unsolved", jnp.zeros((), bool)))


def _chunk(method, f, x0, u, p, h, n_steps, t0, max_steps, libm):
    """A chunk with the batch last: x0 (d, C), u (nu, C), p leaves (..., C), h (C,) or ().
    Returns xs (C, N+1, d), transposed while the chunk is in cache, evals (C,), converged
    (C,), whether a sin or cos argument reached the polynomials' bound (always False
    with `libm`), and whether a nonlinear solve failed."""
    h = jnp.asarray(h, x0.dtype)
    h_axis = -1 if jnp.ndim(h) else None

    def start(t, y, uu, pp, hh):
        return method.start(_bound(f, uu, pp), t, y, hh)

    def step(t, y, st, uu, pp, hh):
        return method.step(_bound(f, uu, pp), t, y, hh, st)

    vstart = jax.vmap(start, in_axes=(None, -1, -1, -1, h_axis), out_axes=-1)
    vstep = jax.vmap(step, in_axes=(h_axis, -1, -1, -1, -1, h_axis), out_axes=-1)
    # Unless `libm`: sin and cos as polynomials over the chunk's rows (rewritten after vmap),
    # with a flag carried through the steps. Derived from y, so that it varies across devices
    # under shard_map as the steps' flags do.
    fstart, fstep = flagged_trig(vstart), flagged_trig(vstep)

    def chunk_start(t, y):
        if libm:
            return vstart(t, y, u, p, h)
        (ys, st), far = fstart(t, y, u, p, h)
        none = jnp.zeros_like(y, bool).any()
        return ys, dict(st, far=none if far is None else far | none)

    def chunk_step(t, y, st):
        if libm:
            return vstep(t, y, st, u, p, h)
        st = dict(st)
        far = st.pop("far")
        (y, st), more = fstep(t, y, st, u, p, h)
        return y, dict(st, far=far if more is None else far | more)

    # A multistep start returns ys of shape (n_start, d, C) with the batch last as well.
    xs, state = _scan(chunk_start, chunk_step, x0, h, method.n_start, n_steps, t0, max_steps)
    far = jnp.zeros_like(state["evals"], bool).any() if libm else state["far"]
    unsolved = state["unsolved"].any() if "unsolved" in state else jnp.zeros_like(far)
    return jnp.moveaxis(xs, -1, 0), state["evals"], state["converged"], far, unsolved


def loops_native() -> bool:
    """Whether XLA, as it was started, compiles the chunks' step loops natively: XLA_FLAGS
    raise xla_cpu_small_while_loop_byte_threshold to at least a megabyte. Only read here;
    the library never sets it."""
    found = re.search(r"xla_cpu_small_while_loop_byte_threshold=(\d+)",
                      os.environ.get("XLA_FLAGS", ""))
    return found is not None and int(found.group(1)) >= 1 << 20


def chunk_size(method) -> int:
    """Trajectories per chunk of a batch of at least SMALL_BATCH (see the module doc)."""
    if method.implicit:
        return CHUNK_IMPLICIT
    return CHUNK if loops_native() else CHUNK_CALLS


def implicit_lanes(method, d: int, itemsize: int) -> int:
    """The most trajectories an implicit method's chunk of d-state ones may hold
    (SYSTEM_BYTES): its full-Newton retry factorises the whole stage system, of order
    stages x d, for a fully implicit tableau, a d x d matrix otherwise."""
    whole_system = not getattr(method.scheme, "diagonally_implicit", True)
    order = d * (method.stages if whole_system else 1)
    return max(SYSTEM_BYTES // (order * order * itemsize), 1)


def _split(a, n_chunks, size):
    """(B, ...) -> (n_chunks, ..., size), padding the batch with copies of its first row."""
    a = jnp.asarray(a)
    pad = n_chunks * size - a.shape[0]
    if pad:
        a = jnp.concatenate([a, jnp.broadcast_to(a[:1], (pad,) + a.shape[1:])])
    return jnp.moveaxis(a.reshape((n_chunks, size) + a.shape[1:]), 1, -1)


def _batch(method, f, x0, u, p, h, n_steps, t0, max_steps, libm, newton=None, retry=True):
    """(Trajectory, whether a chunk met a sin or cos argument beyond the polynomials' bound:
    then the caller runs again with `libm`, whether a nonlinear solve failed); `method`,
    `newton` and `retry` as _integrate's."""
    method = method if newton is None else method.running(newton, retry)
    x0 = jnp.asarray(x0)
    batch = x0.shape[0]
    one = lambda x, uu, pp, hh: _integrate(method, f, x, uu, pp, hh, n_steps, t0, max_steps)
    h_axis = 0 if jnp.ndim(h) else None
    if batch == 1:      # a vmap of one costs more than the plain loop
        first = jax.tree.map(lambda a: jnp.asarray(a)[0], (x0, u, p))
        tr, unsolved = one(*first, h if h_axis is None else h[0])
        return jax.tree.map(lambda a: a[None], tr), jnp.asarray(False), unsolved
    if batch < SMALL_BATCH:
        tr, unsolved = jax.vmap(one, in_axes=(0, 0, 0, h_axis))(x0, u, p, h)
        return tr, jnp.asarray(False), unsolved.any()
    devices = jax.devices()
    shards = len(devices) if batch >= SHARE * len(devices) else 1
    per_device = -(-batch // shards)
    size = chunk_size(method)
    lanes = implicit_lanes(method, x0.shape[1], x0.dtype.itemsize) if method.implicit else 0
    while size > CHUNK and size > lanes and method.implicit:
        size //= 2
    whole = method.implicit and per_device <= min(ONE_CHUNK_IMPLICIT, max(lanes, size))
    size = per_device if whole else min(size, per_device)
    if shards == 1 and not method.implicit:
        return _in_place(method, f, x0, u, p, h, n_steps, t0, max_steps, libm, size)
    n_chunks = -(-batch // (size * shards)) * shards
    args = jax.tree.map(lambda a: _split(a, n_chunks, size), (x0, u, p))
    h_chunks = _split(h, n_chunks, size) if jnp.ndim(h) else jnp.broadcast_to(h, (n_chunks,))

    def run(args, hs):
        return lax.map(lambda a: _chunk(method, f, *a[0], a[1], n_steps, t0, max_steps, libm),
                       (args, hs))

    if shards > 1:
        mesh = Mesh(np.array(devices[:shards]), ("chunks",))
        run = jax.shard_map(run, mesh=mesh, in_specs=PartitionSpec("chunks"),
                            out_specs=PartitionSpec("chunks"))
    xs, evals, converged, far, unsolved = run(args, h_chunks)
    # (chunks, C, N+1, d) -> (B, N+1, d): a reshape, no copy; a transpose of the whole output
    # would copy every state once more.
    xs = xs.reshape((n_chunks * size,) + xs.shape[2:])[:batch]
    ts = _times(t0, h, xs.shape[:2])
    return (Trajectory(ts, xs, evals.reshape(-1)[:batch], converged.reshape(-1)[:batch]),
            far.any(), unsolved.any())


def _times(t0, h, shape):
    """The (batch, rows) times of a batch's rows: h one step size or one per trajectory."""
    steps = jnp.arange(shape[1])
    return t0 + (h[:, None] * steps if jnp.ndim(h) else jnp.broadcast_to(h * steps, shape))


def _in_place(method, f, x0, u, p, h, n_steps, t0, max_steps, libm, size):
    """_batch's result for an explicit method on one device: chunks of `size` trajectories,
    each writing its rows of the output in place. The last chunk ends at the batch's last
    trajectory, overlapping the one before it, instead of padding the batch: cutting the
    padded rows off a stacked output copied every state of every trajectory once more, as
    much time as a chunk's steps take to write them. Explicit methods only: an implicit
    chunk iterates Newton in lockstep, so its lanes' work depends on their neighbours."""
    batch = x0.shape[0]
    n_chunks = -(-batch // size)
    starts = np.minimum(np.arange(n_chunks) * size, batch - size)
    lanes = starts[:, None] + np.arange(size)
    take = lambda a: jnp.moveaxis(jnp.asarray(a)[lanes], 1, -1)
    args = jax.tree.map(take, (x0, u, p))
    hs = take(h) if jnp.ndim(h) else jnp.broadcast_to(h, (n_chunks,))

    def chunk(i):
        a = jax.tree.map(lambda v: v[i], args)
        return _chunk(method, f, *a, hs[i], n_steps, t0, max_steps, libm)

    # The rows of _scan's output; evals are counted in the state's dtype (Method.init).
    rows = n_steps + 1 if max_steps is None else max_steps + 1
    out = (jnp.zeros((batch, rows) + x0.shape[1:], x0.dtype), jnp.zeros(batch, x0.dtype),
           jnp.zeros(batch, bool), jnp.zeros((), bool))

    def body(i, out):
        xs, evals, converged, far, _ = chunk(i)
        at = jnp.asarray(starts)[i]
        put = lambda whole, part: lax.dynamic_update_slice_in_dim(whole, part, at, 0)
        return (put(out[0], xs), put(out[1], evals), put(out[2], converged), out[3] | far)

    xs, evals, converged, far = lax.fori_loop(0, n_chunks, body, out)
    ts = _times(t0, h, xs.shape[:2])
    return Trajectory(ts, xs, evals, converged), far, jnp.zeros_like(far)


def use_all_cores() -> int:
    """One host device per core, so that batches of at least SHARE per device are shared
    among all cores (rk4 with fast_trig at batch 2000: 1.5x on 2 cores). Call it before the
    first JAX computation, since XLA fixes the device count when it starts (or set
    XLA_FLAGS=--xla_force_host_platform_device_count=N); returns the device count."""
    jax.config.update("jax_num_cpu_devices", os.cpu_count())
    return len(jax.devices())


_STATIC = ("method", "f", "n_steps", "max_steps")
_DYNAMIC = ("method", "f", "max_steps")
_jitted = {(fn, dyn): jax.jit(fn, static_argnames=(_DYNAMIC if dyn else _STATIC) + ("retry",) +
                              (("libm",) if fn is _batch else ()))
           for fn in (_integrate, _batch) for dyn in (False, True)}
# Programs (Method.program) a solve of which failed in this process without the full-Newton
# retry: they are run with it at once from then on.
_RETRIED: weakref.WeakSet = weakref.WeakSet()


def retry_at_once(method) -> None:
    """Have the driver run `method`'s program with the full-Newton retry from its first run
    on: for callers that expect failed solves (a sweep probing steps beyond a method's
    limit), who would otherwise compile both programs."""
    if method.solves:
        _RETRIED.add(method.program)


def _with_retry_if_needed(method, run, args):
    """run(retry) -> (result, whether a nonlinear solve failed): run first without the
    full-Newton retry compiled in, which makes the program about a third smaller to compile,
    and again with it where a solve failed and the options allow it (Method.retries). A
    trajectory whose solves all converge takes the same steps either way, so the result is
    the one the program with the retry gives. Inside a trace, and for programs that needed
    the retry before, the program with it is run at once."""
    traced = any(isinstance(a, jax.core.Tracer) for a in jax.tree.leaves(args))
    if not method.solves or traced or method.program in _RETRIED:
        return run(True)[0]
    result, unsolved = run(False)
    if bool(unsolved) and method.retries():
        _RETRIED.add(method.program)
        return run(True)[0]
    return result


def _run(fn, program, f, args, n_steps, t0, max_steps, dynamic, static):
    """fn (_integrate or _batch) jitted, on `args` (x0, u, p, h), the step count, t0 and
    max_steps, with the run-time keywords `dynamic` and the static ones `static`: through the
    programs kept across processes (kept_programs) where that is on."""
    dyn = max_steps is not None
    dynamic = dict(dynamic, t0=t0, **({"n_steps": n_steps} if dyn else {}))
    static = dict(static, max_steps=max_steps, **({} if dyn else {"n_steps": n_steps}))
    return kept_programs.call(_jitted[(fn, dyn)], f"driver.{fn.__name__}", (program, f), static,
                              args, dynamic)


def integrate(method, f, x0, u=None, p=None, h=None, n_steps=None, t0=0.0,
              max_steps=None) -> Trajectory:
    """Integrate dx/dt = f(t, x, u, p) from (t0, x0) with `n_steps` steps of size h [s].

    `method` is a zoo name (see METHODS) or a Method. x0 is a state vector (any array-like;
    a number is a one-state system, whose trajectory x then has shape (N+1,)); the work is
    in x0's float dtype. `u` (inputs) and `p` (parameters, any pytree) are passed to f
    unchanged (default None). `n_steps` is a Python int (compiled in), or, with
    `max_steps` a Python int bound, a run-time integer: then one compilation serves every
    step count up to max_steps. Bad arguments raise ValueError or TypeError naming them, and
    trajectories the process cannot allocate (arguments.check_output) raise MemoryError.

    >>> import jax.numpy as jnp
    >>> vdp = lambda t, x, u, p: jnp.stack([x[1], p * (1 - x[0] ** 2) * x[1] - x[0]])
    >>> traj = integrate("rk4", vdp, [2.0, 0.0], p=1.0, h=0.01, n_steps=1000)
    >>> traj.x.shape
    (1001, 2)
    """
    method, f, x0, scalar = _arguments(method, f, x0, h, n_steps, t0, max_steps, None)
    run = lambda retry: _run(_integrate, method.program, f, (x0, u, p, h), n_steps, t0,
                             max_steps, dict(newton=method.run_options()), dict(retry=retry))
    traj = _with_retry_if_needed(method, run, (x0, u, p, h, n_steps, t0))
    return traj._replace(x=traj.x[..., 0]) if scalar else traj


def integrate_batch(method, f, x0, u=None, p=None, h=None, n_steps=None, t0=0.0,
                    max_steps=None) -> Trajectory:
    """`integrate` vmapped over the leading axis of x0 (shape (B, d), or (B,) for one-state
    systems) and of u and p: a leaf of u or p whose leading axis has length B is one value
    per trajectory, any other leaf (a number, say) is shared by the whole batch. h is a
    number or one step size per trajectory (shape (B,)); t0 and the step count are shared.

    sin and cos run as vectorisable polynomials (see fast_trig); should an argument reach
    their bound, the batch runs again with libm's, compiled only then (inside a trace, a
    cond), so the result is libm's to a few ulp for every argument.

    >>> import jax.numpy as jnp, numpy as np
    >>> vdp = lambda t, x, u, p: jnp.stack([x[1], p * (1 - x[0] ** 2) * x[1] - x[0]])
    >>> x0 = np.array([[2.0, 0.0], [1.0, 0.0], [0.5, 0.0]])
    >>> integrate_batch("rk4", vdp, x0, p=1.0, h=0.01, n_steps=1000).x.shape
    (3, 1001, 2)
    """
    method, f, x0, scalar = _arguments(method, f, x0, h, n_steps, t0, max_steps, True)
    given = (u, p)
    u, p = arguments.shared(u, x0.shape[0]), arguments.shared(p, x0.shape[0])
    program, newton = method.program, method.run_options()

    def run(libm):
        def attempt(retry):
            traj, far, unsolved = _run(_batch, program, f, (x0, u, p, h), n_steps, t0,
                                       max_steps, dict(newton=newton),
                                       dict(libm=libm, retry=retry))
            return (traj, far), unsolved
        return _with_retry_if_needed(method, attempt, (x0, u, p, h, n_steps, t0))

    try:
        traj, far = run(False)
    except (TypeError, ValueError) as err:      # JAX's words for it name neither u nor p
        arguments.explain_batch(err, *given, x0.shape[0])
        raise
    exact = lambda: run(True)[0]
    if isinstance(far, jax.core.Tracer):
        traj = lax.cond(far, exact, lambda: traj)
    elif far:
        traj = exact()
    return traj._replace(x=traj.x[..., 0]) if scalar else traj


def _arguments(method, f, x0, h, n_steps, t0, max_steps, batched):
    """(Method, f, x0 with a state axis, whether the caller's state is a scalar), each
    argument checked; a scalar state's f is seen through a 1-vector."""
    method = arguments.resolve_method(method)
    arguments.check_rhs(f)
    x0, scalar = arguments.state(x0, bool(batched))
    arguments.check_step(h, x0.shape[0] if batched else None)
    arguments.check_steps(n_steps, max_steps)
    arguments.check_time("t0", t0)
    arguments.check_output(x0, n_steps, max_steps)
    return method, arguments.scalar_rhs(f) if scalar else f, x0, scalar
