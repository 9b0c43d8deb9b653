"""Seconds JAX spends compiling in the calling thread: tracing, lowering and XLA's compilation
(or loading the program from the persistent compilation cache), read from JAX's own monitoring
events, so that a timed section can be split into compiling and running."""
from __future__ import annotations

import threading
import time
from contextlib import contextmanager

_EVENTS = ("/jax/core/compile/jaxpr_trace_duration",
           "/jax/core/compile/jaxpr_to_mlir_module_duration",
           "/jax/core/compile/backend_compile_duration")
_local = threading.local()
_lock = threading.Lock()
_listening = False


def _on_span(event, start, end, **_):
    if event not in _EVENTS:
        return
    spans = getattr(_local, "spans", None)
    if spans is None:
        spans = _local.spans = []
        _local.total = 0.0
    # A jit traced inside another's trace reports its span first; the outer one covers it.
    while spans and spans[-1][0] >= start:
        s, e = spans.pop()
        _local.total -= e - s
    spans.append((start, end))
    del spans[:-32]
    _local.total += end - start


def _listen():
    global _listening
    with _lock:
        if not _listening:
            from jax import monitoring
            monitoring.register_event_time_span_listener(_on_span)
            _listening = True


def compiled_s() -> float:
    """JAX's compile seconds in this thread since the first call of this module."""
    _listen()
    return getattr(_local, "total", 0.0)


@contextmanager
def split():
    """Yields a dict that gets `wall` and `compile` [s] of the block when it ends."""
    out = {}
    c0, t0 = compiled_s(), time.perf_counter()
    try:
        yield out
    finally:
        out["wall"] = time.perf_counter() - t0
        out["compile"] = min(compiled_s() - c0, out["wall"])
