"""What a caller gives `integrate`, `integrate_batch` and `reference`, checked and converted in
Python before the compiled call: a method by name or object, array-likes and scalars for x0,
the work dtype (x0's), unbatched parameters shared by a batch. Each mistake is one ValueError
or TypeError that names the argument; values traced by an enclosing `jax.jit` are left to it."""
import functools
import math
from numbers import Integral, Real

import jax
import jax.numpy as jnp
import numpy as np

from stepzoo.validate import GIB, memory_room

X64_HINT = "enable float64 first with jax.config.update('jax_enable_x64', True)"


def _traced(value) -> bool:
    return isinstance(value, jax.core.Tracer)


def resolve_method(method):
    """The Method named `method` (or `method` itself if it is one)."""
    from stepzoo.integrators.methods import METHODS, Method
    if isinstance(method, Method):
        return method
    if isinstance(method, str):
        if method not in METHODS:
            raise ValueError(f"method {method!r} is not in the zoo; choose one of "
                             f"{', '.join(METHODS)}")
        return METHODS[method]
    raise TypeError(f"method must be a method name such as 'rk4' or a Method, got "
                    f"{type(method).__name__}")


def check_rhs(f):
    if not callable(f):
        raise TypeError(f"f must be a function f(t, x, u, p) -> dx/dt, got {type(f).__name__}")


def state(x0, batched: bool):
    """(x0 as an array of a float dtype with a trailing state axis, whether the caller's state
    is a scalar). Lists and numbers take JAX's default float dtype; arrays keep theirs."""
    if not hasattr(x0, "dtype"):
        try:
            x0 = np.asarray(x0, dtype=jnp.result_type(float))
        except (TypeError, ValueError):
            raise TypeError("x0 must be a number, a list of numbers or an array, got "
                            f"{type(x0).__name__}") from None
    dtype = np.dtype(x0.dtype)
    if dtype == np.float64 and not jax.config.read("jax_enable_x64"):
        raise TypeError(f"x0 is float64 but JAX computes in float32; {X64_HINT}, or give x0 "
                        "as float32")
    # dtype kinds, not np.issubdtype: this runs on every call, and issubdtype walks the type tree.
    if dtype.kind != "f" and dtype.name != "bfloat16":
        if dtype.kind not in "iub":
            raise TypeError(f"x0 must hold real numbers, got dtype {dtype}")
        x0 = np.asarray(x0, dtype=jnp.result_type(float))
    lead = 1 if batched else 0
    if x0.ndim not in (lead, lead + 1):
        want = "(B, d), or (B,) for a batch of scalars" if batched else "(d,), or a scalar"
        raise ValueError(f"x0 must have shape {want}; got shape {tuple(x0.shape)}")
    if batched and x0.shape[0] == 0:
        raise ValueError("x0 holds no trajectory (a batch of 0); give at least one row")
    scalar = x0.ndim == lead
    return (x0[..., None] if scalar else x0), scalar


@functools.lru_cache(maxsize=256)
def scalar_rhs(f):
    """f of a scalar state as f of a 1-vector; cached so that the compiled driver, which
    takes f as a static argument, compiles once per f."""
    return lambda t, x, u, p: jnp.reshape(f(t, x[0], u, p), (1,))


def check_step(h, batch: int | None):
    """h: a finite step > 0 [s]; in a batch also one per trajectory, shape (B,)."""
    if type(h) is float:
        if not (math.isfinite(h) and h > 0):          # the common case, without numpy
            raise ValueError(f"h must be a finite step size > 0 [s], got {h!r}")
        return
    if _traced(h):
        return
    if isinstance(h, Real) and not isinstance(h, bool):
        values = np.asarray(float(h))
    elif hasattr(h, "dtype") and np.dtype(h.dtype).kind == "f":
        values = np.asarray(h)
        shapes = [()] if batch is None else [(), (batch,)]
        if values.shape not in shapes:
            each = '' if batch is None else ' or one per trajectory'
            raise ValueError(f"h must be a number{each}"
                             f" (shape {' or '.join(map(str, shapes))}), got shape {values.shape}")
    else:
        raise TypeError(f"h must be a step size in seconds (a number), got {h!r}")
    if not np.all(np.isfinite(values) & (values > 0)):
        raise ValueError(f"h must be a finite step size > 0 [s], got {h!r}")


def check_steps(n_steps, max_steps):
    """n_steps: a whole number >= 0, compiled in; or, with max_steps, up to max_steps."""
    whole = lambda v: type(v) is int or isinstance(v, Integral) and not isinstance(v, bool)
    if max_steps is None:
        if not whole(n_steps) or n_steps < 0:
            raise ValueError(f"n_steps must be a whole number of steps >= 0, got {n_steps!r}")
        return
    if not whole(max_steps) or max_steps < 1:
        raise ValueError(f"max_steps must be a whole number >= 1, got {max_steps!r}")
    if _traced(n_steps):
        return
    n = np.asarray(n_steps)
    if n.shape != () or n.dtype.kind not in "iu" or not 0 <= n <= max_steps:
        raise ValueError(f"n_steps must be a whole number in [0, max_steps={max_steps}], got "
                         f"{n_steps!r}")


# Below this [bytes] the trajectories are not priced: reading the limits takes a fraction of a
# millisecond, as long as a small batch's whole integration.
UNCHECKED_BYTES = 2 ** 26


def check_output(x0, n_steps, max_steps):
    """MemoryError, before any work, if the trajectories (x0's shape and dtype, over
    `max_steps` or `n_steps` steps) cannot be held three times (the output, the loop's own
    buffer of it, and the runtime's and compiler's growth after this check) in what the
    process can still allocate (validate.memory_room: physical memory, a container's limit,
    ulimit -v): past a hard limit XLA's allocation waits forever instead of failing."""
    rows = (n_steps if max_steps is None else max_steps) + 1
    need = 3.0 * rows * math.prod(x0.shape) * x0.dtype.itemsize
    if need < UNCHECKED_BYTES:          # the planner's and the timer's calls, unslowed
        return
    room, bound = memory_room()
    if need > room:
        raise MemoryError(f"the trajectories ({rows} rows of x0's shape {tuple(x0.shape)}, "
                          f"{x0.dtype}, held three times) need {need / GIB:.3g} GiB, past {bound}, "
                          f"{room / GIB:.3g} GiB; take fewer steps or a smaller batch")


def check_time(name: str, value):
    if type(value) is float and math.isfinite(value):
        return
    if not _traced(value) and not (isinstance(value, Real) and math.isfinite(value)):
        raise ValueError(f"{name} must be a finite time [s], got {value!r}")


def shared(tree, batch: int):
    """`tree` (u or p) with every leaf that has no leading axis of length `batch` broadcast
    to one: such leaves are shared by every trajectory of the batch."""
    if tree is None or (hasattr(tree, "shape") and tree.shape[:1] == (batch,)):
        return tree
    if isinstance(tree, dict) and all(np.shape(a)[:1] == (batch,) for a in tree.values()):
        return tree                # every leaf batched: the hot path of the planner's batches
    def leaf(a):
        shape = np.shape(a)
        if len(shape) and shape[0] == batch:
            return a
        if isinstance(a, jax.Array):
            return jnp.broadcast_to(a, (batch,) + shape)
        return np.broadcast_to(np.asarray(a), (batch,) + shape)
    return jax.tree.map(leaf, tree)


def explain_batch(err: Exception, u, p, batch: int):
    """After a batch failed with `err` while JAX traced it: a ValueError naming the first leaf
    of u or p whose leading axis is not the batch's, the likely cause (such a leaf is shared:
    every trajectory gets all of it, and f then computes with an array of the wrong shape);
    nothing where every leaf has the batch's length or none."""
    for name, tree in (("u", u), ("p", p)):
        for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
            shape = tuple(np.shape(leaf))
            if shape and shape[0] != batch:
                raise ValueError(f"{name}{jax.tree_util.keystr(path)} has shape {shape}, not one "
                                 f"value per trajectory ({batch}, ...): a leaf without the "
                                 "batch's leading axis is shared, every trajectory gets all of "
                                 f"it, and f fails on it ({str(err).splitlines()[0]}); give "
                                 f"{name} one row per row of x0") from None


def check_tolerance(rtol, atol, dtype):
    """rtol and atol > 0, and rtol within reach of the work dtype's precision."""
    for name, value in (("rtol", rtol), ("atol", atol)):
        if not (isinstance(value, Real) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a number > 0, got {value!r}")
    floor = 10 * float(np.finfo(dtype).eps)
    if rtol < floor:
        raise ValueError(f"rtol {rtol:g} is below what {np.dtype(dtype).name} resolves "
                         f"(>= {floor:.2g}); give rtol >= {floor:.2g}"
                         + ("" if dtype == np.float64 else f", or {X64_HINT} and give x0 as "
                            "float64"))
