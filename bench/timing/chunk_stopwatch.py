"""Where a sweep chunk's time goes: one stopwatch passed to every part of the engine, the one
place its timing keys (the chunk's row of the timing table, summed into the manifest's
"timing") are accumulated, with JAX's compiling kept apart from the computing."""
from __future__ import annotations

from contextlib import contextmanager

from stepzoo.bench.timing import compile_clock as jit_clock

# The timing table's columns of one chunk [s]: compile_s is JAX's compiling of the method's
# runs (and of the Jacobians), ref_compile_s of the references'; the rest are computing.
KEYS = ("compile_s", "ref_compile_s", "reference_s", "integration_s", "stability_s",
        "metrics_s")


class Stopwatch:
    """Seconds per key of KEYS [s]."""

    def __init__(self):
        self.seconds = dict.fromkeys(KEYS, 0.0)

    def add(self, key: str, seconds: float) -> None:
        self.seconds[key] += seconds

    @contextmanager
    def clock(self, key: str):
        """Charges the block's wall time to `key`, less JAX's compiling in it, which goes to
        ref_compile_s for the references (reference_s) and compile_s otherwise."""
        with jit_clock.split() as took:
            yield
        self.add(key, took["wall"] - took["compile"])
        self.add("ref_compile_s" if key == "reference_s" else "compile_s", took["compile"])

    @contextmanager
    def split(self):
        """Yields a dict that gets the block's `run` seconds [s] when it ends; its compiling goes
        to compile_s, and the caller charges the run to a key of its choosing."""
        out = {}
        with jit_clock.split() as took:
            yield out
        self.add("compile_s", took["compile"])
        out["run"] = took["wall"] - took["compile"]
