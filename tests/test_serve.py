"""`stepzoo serve` and `stepzoo plan --server`: a served plan writes the very plan an in-process
one writes and prints the same line; bad input is the same one line with exit status 2; the
asking process imports only the standard library; a server that is not there is one line."""
import json
import re
import select
import socket
import subprocess
import sys

import numpy as np
import pytest

from stepzoo.bench.cli import main
from stepzoo.search.plan_request import Messages, identity, send
from stepzoo.search.planner_config import load_config

# The asking side as a user runs it, then what it imported beyond the interpreter's start and
# the standard library, written to the file named first.
ASK = """
import json, sys
before = set(sys.modules)
from stepzoo.bench.cli import main
code = main(sys.argv[2:])
extra = {m.split(".")[0] for m in set(sys.modules) - before} - set(sys.stdlib_module_names)
open(sys.argv[1], "w").write(json.dumps(sorted(extra - {"stepzoo"})))
sys.exit(code)
"""
SECONDS = re.compile(r"\d+\.\d+ s\b")       # timings: the one thing two runs print differently
TIMINGS = {"search_s", "connect_s", "warmup_s", "first_solution_s", "solution_s", "progress"}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """(socket, folder with a map and a budgeted config) of a running `stepzoo serve`."""
    folder = tmp_path_factory.mktemp("serve")
    occupied = np.zeros((40, 80), bool)
    occupied[10:30, 36:44] = True            # a 4 x 10 m block between start and goal
    np.save(folder / "grid.npy", occupied)
    shipped = load_config()
    # An expansion budget: the plan cannot depend on how fast the machine is.
    (folder / "budget.toml").write_text(f'method = "{shipped.method}"\nh = {shipped.h!r}\n'
                                        "[planner]\nmax_expansions = 60\n")
    # The server warms up on the test's own map (a small one) and config.
    (folder / "query.toml").write_text('map = "grid.npy"\ncell_size = 0.5\nspeed = 5.0\n'
                                       "start = [4.0, 10.0, 0.0]\ngoal = [36.0, 10.0, 0.0]\n")
    sock = folder / "plan.sock"
    proc = subprocess.Popen([sys.executable, "-m", "stepzoo", "serve", "--socket", str(sock),
                             "--config", "budget.toml", "--warm-up", "query.toml"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=folder)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 600)
        line = proc.stdout.readline() if ready else ""
        assert "stepzoo serve: planning" in line, proc.stderr.read() if proc.poll() else line
        yield sock, folder
    finally:
        proc.terminate()
        proc.wait(timeout=60)
    assert proc.returncode == 0 and not sock.exists()       # a stopped server cleans up


def ask(folder, *argv):
    proc = subprocess.run([sys.executable, "-c", ASK, str(folder / "imported.json"), *argv],
                          capture_output=True, text=True, cwd=folder, timeout=600)
    return proc, json.loads((folder / "imported.json").read_text())


def test_a_served_plan_is_the_in_process_plan_and_the_asker_imports_no_library(
        server, monkeypatch, capsys):
    sock, folder = server
    query = ["plan", "--map", "grid.npy", "--cell-size", "0.5", "--start", "4,10,0", "--goal",
             "36,10,0", "--config", "budget.toml", "--seed", "4"]
    served, imported = ask(folder, *query, "--out", "out_served", "--server", str(sock))
    assert imported == []
    monkeypatch.chdir(folder)
    code = main([*query, "--out", "out_here"])
    here = capsys.readouterr()
    assert (served.returncode, served.stderr) == (code, here.err)
    assert SECONDS.sub("", served.stdout) == SECONDS.sub("", here.out).replace("out_here",
                                                                              "out_served")
    plans = [json.loads((folder / f / "plan.json").read_text())
             for f in ("out_served", "out_here")]
    assert plans[0]["stats"]["budget_bound"] in (None, "max_expansions")
    assert plans[0]["status"] == "exact" and len(plans[0]["path"]) > 100
    for plan in plans:
        for key in TIMINGS:
            plan["stats"].pop(key)
        plan["reason"] = SECONDS.sub("", plan["reason"])
    assert plans[0] == plans[1]              # path and tree bit for bit, and every other key
    manifest = json.loads((folder / "out_served" / "manifest.json").read_text())
    assert manifest["command_line"].endswith(f"--out out_served --server {sock}")


def test_bad_input_served_is_the_same_line_and_exit_2(server, monkeypatch, capsys):
    sock, folder = server
    served, _ = ask(folder, "plan", "--map", "nowhere.npy", "--cell-size", "0.5", "--start",
                    "4,10,0", "--goal", "36,10,0", "--out", "bad", "--server", str(sock))
    monkeypatch.chdir(folder)
    code = main(["plan", "--map", "nowhere.npy", "--cell-size", "0.5", "--start", "4,10,0",
                 "--goal", "36,10,0", "--out", "bad"])
    here = capsys.readouterr()
    assert (served.returncode, served.stdout, served.stderr) == (code, here.out, here.err)
    assert code == 2 and here.err.count("\n") == 1 and "nowhere.npy" in here.err
    assert not (folder / "bad").exists()


def test_closing_the_asking_side_stops_the_plan_and_the_server_serves_on(server):
    sock, folder = server
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as asker:
        asker.connect(str(sock))
        send(asker, {"argv": ["plan", "--all", "--out", "stopped", "--config", "budget.toml"],
                     "cwd": str(folder), "command_line": ["stepzoo"], "stepzoo": identity()})
        asker.shutdown(socket.SHUT_WR)          # what Ctrl-C in `stepzoo plan` does
        answers, last = Messages(asker), None
        while (answer := answers.next()) is not None:
            last = answer
    assert last == {"exit": 130} and not (folder / "stopped").exists()
    again, _ = ask(folder, "plan", "nosuch", "--out", "x", "--server", str(sock))
    assert again.returncode == 2 and "unknown scenario 'nosuch'" in again.stderr


def test_no_server_is_one_line_and_exit_2(tmp_path):
    proc, imported = ask(tmp_path, "plan", "open_field", "--out", "x", "--server",
                         str(tmp_path / "none.sock"))
    assert proc.returncode == 2 and imported == []
    assert proc.stderr == (f"stepzoo plan: error: no stepzoo server listens at "
                           f"{tmp_path / 'none.sock'}; start one with `stepzoo serve --socket "
                           f"{tmp_path / 'none.sock'}`, or plan here without --server (and "
                           "without STEPZOO_SERVER)\n")
    assert not (tmp_path / "x").exists()
