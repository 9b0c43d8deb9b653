"""The driver's programs kept across processes (integrators/kept_programs.py): a kept program
loaded from its file gives the traced program's results bit for bit, and its key changes with
everything that decides the program, while what the key cannot name is not kept."""
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stepzoo.dynamics.bicycle import _reduced
from stepzoo.dynamics.kinematic import kinematic_bicycle
from stepzoo.integrators import (arguments, integrate, integrate_batch, kept_programs,
                                 method)
from stepzoo.integrators.methods import METHODS

jax.config.update("jax_enable_x64", True)

P = {"L": 2.7, "m": 1500.0}


@pytest.fixture
def kept(tmp_path, monkeypatch):
    """Programs kept in tmp_path for the test, none loaded in this process yet."""
    monkeypatch.setattr(kept_programs, "_loaded", {})
    monkeypatch.setattr(kept_programs, "_refused", set())
    monkeypatch.setattr(kept_programs, "_keys", {})
    kept_programs.keep_in(tmp_path)
    yield tmp_path
    kept_programs.keep_in(None)


def _batch(name, batch, dtype=float):
    rng = np.random.default_rng(3)
    x0 = np.column_stack([rng.normal(size=(batch, 3)), 2 + rng.random(batch)]).astype(dtype)
    u = np.column_stack([0.3 * rng.normal(size=batch), rng.normal(size=batch)]).astype(dtype)
    return lambda: integrate_batch(name, kinematic_bicycle, x0, u, P, 0.02, 40)


def _equal(a, b):
    return all(np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True)
               for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


@pytest.mark.parametrize("name, batch", [("rk4", 5), ("rk4", 40), ("ab3", 40),
                                         ("backward_euler", 40)])
def test_a_program_loaded_from_its_file_gives_the_traced_programs_results_bit_for_bit(
        kept, monkeypatch, name, batch):
    run = _batch(name, batch)
    kept_programs.keep_in(None)
    plain = run()
    kept_programs.keep_in(kept)
    first = run()                     # traced, exported and written
    files = list(kept.glob("*.pkl"))
    assert len(files) == 1
    # A new process: nothing loaded, and nothing may be exported, so it runs from the file.
    monkeypatch.setattr(kept_programs, "_loaded", {})
    monkeypatch.setattr(kept_programs, "_export", lambda *a: pytest.fail("exported again"))
    loaded = run()
    assert _equal(plain, first) and _equal(plain, loaded)
    assert plain.x.shape == loaded.x.shape and np.isfinite(np.asarray(loaded.x)).all()


def test_one_trajectory_and_a_run_time_step_count_are_kept_and_equal_too(kept, monkeypatch):
    x0, u = np.array([0.0, 0.0, 0.1, 3.0]), np.array([0.2, 100.0])
    runs = [lambda: integrate("heun", kinematic_bicycle, x0, u, P, 0.01, 30),
            lambda: integrate("heun", kinematic_bicycle, x0, u, P, 0.01, jnp.asarray(17),
                              max_steps=30)]
    kept_programs.keep_in(None)
    plain = [run() for run in runs]
    kept_programs.keep_in(kept)
    [run() for run in runs]
    assert len(list(kept.glob("*.pkl"))) == 2
    monkeypatch.setattr(kept_programs, "_loaded", {})
    assert all(_equal(a, run()) for a, run in zip(plain, runs))


def test_what_the_key_cannot_name_is_traced_and_not_kept(kept):
    own_model = lambda t, x, u, p: -x                    # a user's right-hand side
    integrate_batch("rk4", own_model, np.ones((3, 2)), None, None, 0.1, 5)
    custom = dataclasses.replace(METHODS["rk4"], name="rk4")   # a Method not the registry's
    integrate_batch(custom, kinematic_bicycle, np.ones((3, 4)), np.zeros((3, 2)), P, 0.1, 5)
    assert list(kept.glob("*.pkl")) == []
    with pytest.raises(kept_programs.Unnamed):
        kept_programs.name_of(custom)
    assert kept_programs.name_of(METHODS["rk4"]) == "method:rk4"
    with pytest.raises(kept_programs.Unnamed):
        kept_programs.name_of(own_model)
    with pytest.raises(kept_programs.Unnamed):   # a stepzoo closure over a user's function
        kept_programs.name_of(arguments.scalar_rhs(own_model))


def _key(f=kinematic_bicycle, name="rk4", x0=None, static=None):
    x0 = np.zeros((3, 4)) if x0 is None else x0
    static = {"n_steps": 5, "max_steps": None, "libm": False, "retry": True} \
        if static is None else static
    return kept_programs.key("driver._batch", (method(name).program, f), static,
                             ((x0, np.zeros((3, 2)), P, 0.1), {"t0": 0.0}))


def test_the_key_changes_with_the_method_the_model_its_captured_values_and_the_arguments():
    base = _key()
    assert _key() == base
    assert _key(name="heun") != base
    assert _key(f=_reduced("linear")) != base
    # One function of the library's, made twice with other captured values (the tyre model).
    assert kept_programs.name_of(_reduced("linear")) != kept_programs.name_of(_reduced("fiala"))
    assert _key(x0=np.zeros((4, 4))) != base
    assert _key(x0=np.zeros((3, 4), np.float32)) != base
    assert _key(static={"n_steps": 6, "max_steps": None, "libm": False, "retry": True}) != base
    assert kept_programs.name_of(0.1) != kept_programs.name_of(np.nextafter(0.1, 1.0))


def test_the_source_digest_changes_when_a_module_changes(tmp_path):
    (tmp_path / "dynamics").mkdir()
    model = tmp_path / "dynamics" / "model.py"
    model.write_text("def f(t, x, u, p):\n    return -x\n")
    before = kept_programs.source_digest([tmp_path])
    assert kept_programs.source_digest([tmp_path]) == before
    model.write_text("def f(t, x, u, p):\n    return -2 * x\n")
    changed = kept_programs.source_digest([tmp_path])
    model.rename(tmp_path / "dynamics" / "other.py")
    assert len({before, changed, kept_programs.source_digest([tmp_path])}) == 3


def test_the_planners_shootings_from_a_kept_program_are_the_traced_ones(kept, monkeypatch):
    """integrate_together (the tree's moves in one call) through a kept program: the same
    trajectories bit for bit, loaded in a 'new process' without exporting again."""
    from stepzoo.search.planner.pathfinder import PathFinder
    from stepzoo.search.planner.config import load_config
    from stepzoo.search.planner.shooting import integrate_together
    from stepzoo.search.world.scenarios import load_scenario
    scenario = load_scenario("wall_between")
    finder = PathFinder(scenario.omap, load_config(None), scenario.vehicle, scenario.speed)
    rng = np.random.default_rng(5)
    batch = finder.shooter.batch
    start = np.column_stack([rng.normal(size=(batch, 2)) * 3, rng.normal(size=batch),
                             np.zeros((batch, 2))])
    shooters = [finder.shooter, finder.tight_shooter]
    requests = [(s, start, 0.3 * rng.normal(size=batch), np.zeros(batch)) for s in shooters]
    kept_programs.keep_in(None)
    plain = integrate_together(requests)
    kept_programs.keep_in(kept)
    first = integrate_together(requests)
    assert len(list(kept.glob("*.pkl"))) == 1
    monkeypatch.setattr(kept_programs, "_loaded", {})
    monkeypatch.setattr(kept_programs, "_export", lambda *a: pytest.fail("exported again"))
    loaded = integrate_together(requests)
    assert all(np.array_equal(a, b, equal_nan=True) and np.array_equal(a, c, equal_nan=True)
               for a, b, c in zip(plain, first, loaded))
