"""`stepzoo methods` and `stepzoo simulate`: output contracts and one-line errors (exit 2)."""
import csv
import io
import json
import signal
import subprocess
import sys

import numpy as np
import pytest

from stepzoo import dynamics
from stepzoo.cli import main as stepzoo


def run(args):
    return subprocess.run([sys.executable, "-m", "stepzoo", *args], capture_output=True,
                          text=True)


def test_methods_json_lists_the_zoo(capsys):
    assert stepzoo(["methods", "--format", "json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert {"rk4", "ab4", "bdf2", "gauss_legendre4"} <= {r["name"] for r in rows}
    for r in rows:
        assert {"name", "family", "order", "stages", "implicit"} <= set(r)


def test_simulate_csv_matches_the_driver(capsys):
    assert stepzoo(["simulate", "--method", "rk4", "--h", "0.01", "--T", "1", "--vx", "15",
                    "--delta", "0.785398"]) == 0
    rows = list(csv.reader(io.StringIO(capsys.readouterr().out)))
    assert rows[0] == ["t", "X", "Y", "psi", "vy", "r"]
    assert len(rows) == 102
    assert float(rows[-1][0]) == pytest.approx(1.0)
    assert float(rows[2][4]) != 0.0        # the steer excites the lateral motion


class _Writes:
    """A stdout that keeps what each write() was given."""

    def __init__(self):
        self.writes = []

    def write(self, text):
        self.writes.append(text)

    def flush(self):
        pass


def test_simulate_csv_is_written_in_blocks_never_whole(monkeypatch):
    """The third battery's case: 6e6 steps as CSV under a memory limit ended in a traceback:
    the text, several times the trajectory's memory, was built whole. Now at most
    CSV_BLOCK_ROWS rows are formatted at a time, and the rows are those of the driver."""
    from stepzoo.cli import simulate
    from stepzoo.integrators import integrate, method
    monkeypatch.setattr(simulate, "CSV_BLOCK_ROWS", 40)
    out = _Writes()
    monkeypatch.setattr(sys, "stdout", out)
    assert stepzoo(["simulate", "--method", "rk4", "--h", "0.01", "--T", "1", "--vx", "15",
                    "--delta", "0.3"]) == 0
    text = "".join(out.writes)
    assert max(w.count("\n") for w in out.writes) == 40 and len(out.writes) == 1 + 3
    rows = list(csv.reader(io.StringIO(text)))
    m = dynamics.model("dynamic5")
    x0, u = m.from_rest(15.0, 0.3)
    tr = integrate(method("rk4"), m.rhs, x0, u, m.params(None, 15.0), 0.01, 100)
    assert rows[0] == ["t", *m.states] and len(rows) == 102
    assert [[float(v) for v in r] for r in rows[1:]] == \
        np.column_stack([np.asarray(tr.t), np.asarray(tr.x)]).tolist()


def test_running_out_of_memory_is_one_line(monkeypatch, capsys):
    """Past the process's own memory limit, which no estimate saw, a command says so in one
    line and exit 2 (a MemoryError traceback before)."""
    from stepzoo.cli import simulate

    def too_much(*args):
        raise MemoryError
    monkeypatch.setattr(simulate, "write_csv", too_much)
    assert stepzoo(["simulate", "--method", "rk4", "--h", "0.01", "--T", "1", "--vx", "15",
                    "--delta", "0.3"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stepzoo simulate: error: ran out of memory;") and err.count("\n") == 1


def test_simulate_reference_json_carries_the_vehicle(capsys):
    assert stepzoo(["simulate", "--method", "reference", "--h", "0.1", "--T", "1", "--vx", "15",
                    "--delta", "0.3", "--vehicle", "notes_example", "--format", "json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["columns"] == ["t", "X", "Y", "psi", "vy", "r"]
    assert len(out["t"]) == 11 and np.array(out["x"]).shape == (11, 5)
    assert out["vehicle"]["m"] == 1500.0 and out["vehicle"]["Caf"] == 80000.0


def test_simulate_full_model_has_six_columns(capsys):
    assert stepzoo(["simulate", "--method", "rk4", "--h", "0.1", "--T", "1", "--vx", "10",
                    "--delta", "0.1", "--model", "dynamic6"]) == 0
    header = capsys.readouterr().out.splitlines()[0]
    assert header == "t,X,Y,psi,vx,vy,r"


def test_blow_up_is_written_not_raised(capsys):
    assert stepzoo(["simulate", "--method", "euler", "--h", "0.5", "--T", "20", "--vx", "2",
                    "--delta", "0.5", "--format", "json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert any(v is None or abs(v) > 1e6 for row in out["x"] for v in row)


@pytest.mark.parametrize("args,needle", [
    (["--method", "nope"], "unknown method"),
    (["--model", "nope"], "unknown model"),
    (["--vehicle", "nope"], "unknown vehicle"),
    (["--h", "0"], "--h must be a step size"),
    (["--h", "-0.1"], "--h must be a step size"),
    (["--h", "5"], "larger than the horizon"),
    (["--h", "abc"], "invalid float value"),
])
def test_bad_input_gets_one_line_and_exit_2(args, needle):
    base = {"--method": "rk4", "--h": "0.01", "--T": "1", "--vx": "15", "--delta": "0.3"}
    for flag, value in zip(args[::2], args[1::2]):
        base[flag] = value
    argv = ["simulate"] + [x for kv in base.items() for x in kv]
    proc = run(argv)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], proc.stderr
    assert proc.stdout == ""


@pytest.mark.parametrize("tyre", ["pacejka", "fiala"])
def test_simulate_takes_a_tyre_and_small_steer_stays_near_the_linear_tyre(capsys, tyre):
    """At 1 mrad the slip angles are small: each tyre's run is within 1% of the linear one
    (Fiala departs from linear at first order in |alpha|: Ca |alpha| / (3 mu Fz) = 0.7% at
    1 mrad on the front axle); the JSON names the tyre."""
    runs = {}
    for t in ("linear", tyre):
        assert stepzoo(["simulate", "--method", "rk4", "--h", "0.01", "--T", "1", "--vx", "15",
                        "--delta", "0.001", "--tyre", t, "--format", "json"]) == 0
        out = json.loads(capsys.readouterr().out)
        assert out["tyre"] == t
        runs[t] = np.array(out["x"])
    lateral = np.abs(runs["linear"][:, 3:]).max(axis=0)
    assert np.all(np.abs(runs[tyre][:, 3:] - runs["linear"][:, 3:]).max(axis=0) < 0.01 * lateral)


def test_simulate_runs_the_commonroad_single_track_model(capsys):
    assert stepzoo(["simulate", "--method", "rk4", "--h", "0.01", "--T", "1", "--vx", "15",
                    "--delta", "0.05", "--model", "st"]) == 0
    rows = list(csv.reader(io.StringIO(capsys.readouterr().out)))
    assert rows[0] == ["t", "X", "Y", "delta", "v", "psi", "r", "beta"]
    assert float(rows[-1][4]) == pytest.approx(15.0) and float(rows[-1][6]) > 0


@pytest.mark.parametrize("args,needle", [
    (["--tyre", "brush"], "unknown tyre"),
    (["--tyre", "pacejka", "--vehicle", "ge2021"], "no pacejka parameter set"),
    (["--model", "detest_a1"], "simulate runs the vehicle models"),
])
def test_bad_tyre_or_model_gets_one_line_and_exit_2(args, needle):
    base = {"--method": "rk4", "--h": "0.01", "--T": "1", "--vx": "15", "--delta": "0.3"}
    for flag, value in zip(args[::2], args[1::2]):
        base[flag] = value
    proc = run(["simulate"] + [x for kv in base.items() for x in kv])
    assert proc.returncode == 2 and proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], proc.stderr


def test_compilation_cache_serves_a_repeat_and_recompiles_for_another_method(tmp_path, capsys):
    """The command keeps its compiled programs in STEPZOO_CACHE_DIR: a repeated call compiles
    nothing new and prints the same bits; h is data of the program, so another h with the same
    step count reuses it and agrees with a fresh in-process run; another method compiles anew."""
    import os
    cache = tmp_path / "cache"
    env = dict(os.environ, STEPZOO_CACHE_DIR=str(cache))

    def simulate(method, h, T):
        proc = subprocess.run([sys.executable, "-m", "stepzoo", "simulate", "--method", method,
                               "--h", h, "--T", T, "--vx", "15", "--delta", "0.3"],
                              capture_output=True, text=True, env=env, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return proc.stdout, {p.name for p in cache.glob("*-cache")}

    first, programs = simulate("rk4", "0.01", "1")
    assert programs
    again, programs_again = simulate("rk4", "0.01", "1")
    assert (again, programs_again) == (first, programs)
    other_h, programs_h = simulate("rk4", "0.02", "2")
    assert programs_h == programs
    assert stepzoo(["simulate", "--method", "rk4", "--h", "0.02", "--T", "2", "--vx", "15",
                    "--delta", "0.3"]) == 0
    assert other_h == capsys.readouterr().out != first
    _, programs_heun = simulate("heun", "0.01", "1")
    assert programs_heun > programs


@pytest.mark.parametrize("late_hook", [False, True])
def test_a_ctrl_c_lost_in_a_gc_callback_is_raised_again(late_hook, monkeypatch):
    """A KeyboardInterrupt raised inside a garbage-collector callback (as JAX's) reaches
    sys.unraisablehook, not the command: the command's hook raises the signal again, so the
    command still stops (a sweep ran to its end and exited 0 after such a Ctrl-C). Also
    when the hook is still running as the redelivery lands (`late_hook`: a loaded machine;
    the redelivery was lost there in one run of six of this file)."""
    import gc
    import threading
    import time

    from stepzoo import cli
    raised = []
    slowed = []

    class LateTimer(threading.Timer):
        def start(self):
            super().start()
            if not slowed:              # the first: the hook descheduled past the delay
                slowed.append(True)
                time.sleep(0.5)

    if late_hook:
        monkeypatch.setattr(threading, "Timer", LateTimer)

    def callback(phase, info):
        # Once, as one Ctrl-C: a callback raising at every collection (in any thread: the
        # timer's, pytest-xdist's) had the hook deliver the signal again after the test,
        # into pytest itself, whenever a second collection came first.
        if phase == "start" and not raised:
            raised.append(True)
            raise KeyboardInterrupt

    previous = sys.unraisablehook
    # The command's process has Python's own Ctrl-C handler; an earlier test in this worker
    # may have left another (the redelivered signal then raises nothing).
    handler = signal.signal(signal.SIGINT, signal.default_int_handler)
    sys.unraisablehook = cli._redeliver_ctrl_c
    gc.callbacks.append(callback)
    try:
        with pytest.raises(KeyboardInterrupt):
            gc.collect()
            # The signal comes again a moment later (10 ms; up to 30 s on a loaded machine:
            # the wait ends as soon as it lands).
            for _ in range(3000):
                time.sleep(0.01)
    finally:
        gc.callbacks.remove(callback)
        sys.unraisablehook = previous
        signal.signal(signal.SIGINT, handler)


def test_a_ctrl_c_the_command_stopped_for_drops_a_redelivery_still_pending(monkeypatch, capsys):
    """A KeyboardInterrupt lost in a garbage-collector callback schedules a redelivery; when
    another one reaches the command first, the command stops (130) and the redelivery is
    dropped. It landed after the command, in the interpreter's exit, which then ended by
    SIGINT (status -2) after the command had said it was interrupted."""
    import gc
    import time

    from stepzoo.cli import methods
    raised = []

    def callback(phase, info):
        if phase == "start" and not raised:
            raised.append(True)
            raise KeyboardInterrupt

    def lose_one_then_stop(args):
        gc.callbacks.append(callback)
        try:
            gc.collect()                # the lost one: a redelivery is scheduled
        finally:
            gc.callbacks.remove(callback)
        raise KeyboardInterrupt        # the one the command stops for

    monkeypatch.setattr(methods, "main", lose_one_then_stop)
    previous = sys.unraisablehook
    late = []
    try:
        assert stepzoo(["methods"]) == 130
        try:
            for _ in range(50):         # well past the redelivery's delay
                time.sleep(0.01)
        except KeyboardInterrupt:
            late.append(True)
    finally:
        sys.unraisablehook = previous
    assert raised and not late
    assert capsys.readouterr().err.strip() == "stepzoo methods: interrupted"



def test_a_ctrl_c_caught_after_it_left_an_exec_of_source_text_ends_130(tmp_path):
    """`python -m stepzoo` interrupted while the command made a namedtuple or a dataclass
    (an exec() of source text, as modules are imported) ended by SIGINT (status -2) after
    saying it was interrupted: CPython marks such an interrupt unhandled even when caught.
    `stepzoo run` interrupted as its sweep stage began did so in 2 of 45 tries."""
    (tmp_path / "interrupted_in_exec.py").write_text(
        "import sys\n"
        "from stepzoo import cli\n"
        "from stepzoo.cli import methods\n"
        "methods.main = lambda args: exec('raise KeyboardInterrupt')\n"
        "sys.exit(cli.main(['methods']))\n")
    done = subprocess.run([sys.executable, "-m", "interrupted_in_exec"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip() == "stepzoo methods: interrupted"


def test_a_ctrl_c_in_a_class_being_made_is_one_line_and_130(monkeypatch, capsys):
    """A Ctrl-C that lands in a descriptor's __set_name__ while a class is made (pydantic's,
    as `stepzoo run` imports the planner's config at its tune stage) reaches the command as a
    RuntimeError caused by it on Python 3.11: it is an interruption (one line, 130), not a
    traceback and exit 1. Other RuntimeErrors still propagate."""
    from stepzoo.cli import methods

    class Named:
        def __set_name__(self, owner, name):
            raise KeyboardInterrupt

    def make_a_class(args):
        type("Made", (), {"field": Named()})

    monkeypatch.setattr(methods, "main", make_a_class)
    assert stepzoo(["methods"]) == 130
    assert capsys.readouterr().err.strip() == "stepzoo methods: interrupted"

    def fail(args):
        raise RuntimeError("not an interruption")

    monkeypatch.setattr(methods, "main", fail)
    with pytest.raises(RuntimeError, match="not an interruption"):
        stepzoo(["methods"])
