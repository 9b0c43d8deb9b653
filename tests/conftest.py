import atexit
import os
import shutil
import tempfile
from pathlib import Path

from helpers import TINY_SWEEP
from stepzoo.cli import with_xla_option

# The tests compute as the `stepzoo` command does, so that tables made in-process equal those
# of a command run in a subprocess bit for bit: the same XLA option (it changes how loops are
# compiled, hence the rounding), set before JAX starts, and float64. The library itself
# changes no JAX setting; the tests ask for these as any caller would.
os.environ["XLA_FLAGS"] = with_xla_option(os.environ.get("XLA_FLAGS", ""))
# The tests and the commands they run (in-process or as subprocesses) keep JAX's compiled
# programs in a folder of this test session, not in the user's cache: the suite neither reads
# programs an older stepzoo compiled nor leaves its own behind. The first process makes it
# and removes it at exit; pytest-xdist's workers, started from that process, inherit it, so
# a program one worker compiled the other loads.
if "STEPZOO_TEST_CACHE" not in os.environ:
    os.environ["STEPZOO_TEST_CACHE"] = tempfile.mkdtemp(prefix="stepzoo-test-cache-")
    atexit.register(shutil.rmtree, os.environ["STEPZOO_TEST_CACHE"], ignore_errors=True)
os.environ["STEPZOO_CACHE_DIR"] = os.environ["STEPZOO_TEST_CACHE"]
# A `stepzoo serve` the developer keeps for their own plans (STEPZOO_SERVER) would receive the
# tests' plans: they plan in their own process unless a test starts a server itself.
os.environ.pop("STEPZOO_SERVER", None)

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from stepzoo import dynamics  # noqa: E402
from stepzoo.bench.sweep.engine import run_sweep  # noqa: E402
from stepzoo.bench.sweep.config import load  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir", os.environ["STEPZOO_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


@pytest.fixture(scope="session")
def tiny_sweep(tmp_path_factory):
    """(config file, its finished sweep folder) of TINY_SWEEP; tests copy it, never change it."""
    base = tmp_path_factory.mktemp("tiny")
    path = base / "tiny.toml"
    path.write_text(TINY_SWEEP)
    run_sweep(load(path), base / "whole", progress=False)
    return path, base / "whole"


@pytest.fixture(scope="session")
def small_toml_sweep(tmp_path_factory):
    """The finished sweep folder of bench/configs/small.toml, made once for the files that
    read it (tuning, the stored tables, the recorded limits) instead of once by each; tests
    copy it, never change it."""
    out = tmp_path_factory.mktemp("small") / "sweep"
    run_sweep(load(Path(__file__).resolve().parents[1] / "bench" / "configs" / "small.toml"),
              out, progress=False)
    return out


@pytest.fixture
def paper_point():
    """The paper's test: vx = 15 m/s, delta = pi/4, on the default vehicle, from rest."""
    m = dynamics.model("dynamic5")
    p = m.params(None, 15.0)
    x0, u = m.from_rest(15.0, np.pi / 4)
    return m, p, x0, u


def pytest_collection_modifyitems(items):
    """The files marked slow (a module's `pytestmark = pytest.mark.slow`) first, each file's
    tests in their own order. `make test` has pytest-xdist hand out whole files in this order
    (--dist loadfile --no-loadscope-reorder): the long files start at once and the short ones
    fill the other worker behind them. xdist's own order, most tests first, left a long file
    of few tests to start last and run alone. `-m "not slow"` leaves them out of a quick run."""
    def slow(item) -> bool:
        module = item.getparent(pytest.Module)
        return module is not None and module.get_closest_marker("slow") is not None
    items.sort(key=lambda item: not slow(item))


@pytest.fixture(autouse=True)
def _no_kept_programs():
    """Each test starts with the driver's programs traced in its own process, as the library
    does by default: a command run in-process (main) keeps them (kept_programs) for its test
    only, so a test that patches a model or method is never served a program kept before."""
    from stepzoo.integrators import kept_programs
    kept_programs.keep_in(None)
    kept_programs._loaded.clear()
    kept_programs._refused.clear()
    kept_programs._keys.clear()
    yield
    kept_programs.keep_in(None)
