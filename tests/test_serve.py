"""`stepzoo serve` and `stepzoo plan --server`: a served plan writes the very plan an in-process
one writes and prints the same line; bad input is the same one line with exit status 2; the
asking process imports only the standard library; a server that is not there is one line. The
server survives its clients: a request has a deadline for the whole of it, a bad request is
answered in one line, and each side talks only to a peer of its own user."""
import functools
import json
import os
import pwd
import re
import select
import shutil
import socket
import subprocess
import sys
import tempfile

from pathlib import Path

import numpy as np
import pytest

from stepzoo.cli import main
from stepzoo.search.plans.request import Messages, identity, send
from stepzoo.search.planner.config import load_config

# The asking side as a user runs it, then what it imported beyond the interpreter's start and
# the standard library, written to the file named first.
ASK = """
import json, sys
before = set(sys.modules)
from stepzoo.cli import main
code = main(sys.argv[2:])
extra = {m.split(".")[0] for m in set(sys.modules) - before} - set(sys.stdlib_module_names)
open(sys.argv[1], "w").write(json.dumps(sorted(extra - {"stepzoo"})))
sys.exit(code)
"""
SECONDS = re.compile(r"\d+\.\d+ s\b")       # timings: the one thing two runs print differently
TIMINGS = {"search_s", "connect_s", "warmup_s", "first_solution_s", "solution_s", "progress"}
REQUEST_S = 3.0                             # the test server's deadline for a whole request


def _other_user():
    """The uid of `nobody`, as whom a child of this root process acts; else skip."""
    if os.geteuid() != 0:
        pytest.skip("acting as another user needs root (os.setuid in a child)")
    try:
        uid = pwd.getpwnam("nobody").pw_uid
    except KeyError:
        pytest.skip("no user `nobody` to act as")
    if not _can_become(uid):
        pytest.skip("this root cannot change its user id here (no CAP_SETUID/CAP_SETGID)")
    return uid


@functools.cache
def _can_become(uid: int) -> bool:
    return subprocess.run([sys.executable, "-c", AS_USER, str(uid), "pass"],
                          capture_output=True, timeout=60).returncode == 0


# A program that starts as root, imports what it needs (root's interpreter may sit in a folder
# another user cannot read), then becomes the user argv[1] and runs argv[2]'s code.
AS_USER = """
import json, os, socket, sys
uid = int(sys.argv[1])
os.setgroups([]); os.setgid(uid); os.setuid(uid)
exec(sys.argv[2])
"""


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
                                        "[planner]\nmax_expansions = 600\n")
    # The server warms up on the test's own map (a small one) and config.
    (folder / "query.toml").write_text('map = "grid.npy"\ncell_size = 0.5\nspeed = 5.0\n'
                                       "start = [4.0, 10.0, 0.0]\ngoal = [36.0, 10.0, 0.0]\n")
    # The socket's own folder (mode 0700), which a test opens to another user.
    home = Path(tempfile.mkdtemp(prefix="stepzoo-serve-"))
    sock = home / "plan.sock"
    proc = subprocess.Popen([sys.executable, "-m", "stepzoo", "serve", "--socket", str(sock),
                             "--config", "budget.toml", "--warm-up", "query.toml",
                             "--request-timeout", str(REQUEST_S)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=folder)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 600)
        line = proc.stdout.readline() if ready else ""
        assert "stepzoo serve: planning" in line, proc.stderr.read() if proc.poll() else line
        yield sock, folder
    finally:
        proc.terminate()
        proc.wait(timeout=60)
        cleaned = not sock.exists()
        shutil.rmtree(home)
    assert proc.returncode == 0 and cleaned             # a stopped server cleans up


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


def answers_to(sock, payload: bytes) -> list:
    """Every message the server sends a connection that sends `payload` and waits."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as conn:
        conn.settimeout(120)                     # a bound: the test never hangs
        conn.connect(str(sock))
        conn.sendall(payload)
        out, answers = [], Messages(conn)
        while (answer := answers.next()) is not None:
            out.append(answer)
        return out


def test_a_request_dripped_byte_by_byte_is_cut_off_and_the_next_is_served(server):
    """The issue's case: a byte every quarter second, no newline. The deadline is the whole
    request's, so the server cuts it off and serves the client that waited behind it."""
    sock, folder = server
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as drip, \
            socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as behind:
        drip.connect(str(sock))
        drip.sendall(b"{")
        behind.connect(str(sock))              # waits until the dripping one is done
        send(behind, {"argv": ["plan", "nosuch", "--out", "x"], "cwd": str(folder),
                      "command_line": ["stepzoo"], "stepzoo": identity()})
        sent = 1
        # Each wait is shorter than the per-read limit the server used to have; the loop's
        # bound (15 times the deadline) only keeps a broken server from hanging the test.
        while sent < 4 * 15 * REQUEST_S and not select.select([drip], [], [], 0.25)[0]:
            drip.sendall(b" ")
            sent += 1
        drip.settimeout(60)
        cut = Messages(drip)
        assert cut.next() == {"refused": f"no whole request line within {REQUEST_S:g} s; "
                                         "ask with `stepzoo plan ... --server SOCKET`"}
        assert cut.next() is None
        assert sent > 4                         # it was still sending when cut off
        behind.settimeout(120)
        served = []
        answers = Messages(behind)
        while (answer := answers.next()) is not None:
            served.append(answer)
    assert served[-1] == {"exit": 2}
    assert "unknown scenario 'nosuch'" in "".join(a.get("stderr", "") for a in served)


BAD_REQUESTS = {
    b"plan street\n": "a request is one line of JSON",
    b"\xff\xfe\n": "a request is one line of JSON",
    b"[" * 100_000 + b"\n": "a request is one line of JSON",
    b"[1, 2]\n": "a request is a JSON object",
    b'{"argv": ["plan", "street"], "stepzoo": {}}\n': '"cwd" must be an absolute path',
    b'{"argv": "plan street", "cwd": "/"}\n': '"argv" must be a list of strings',
    b'{"argv": ["plan", 1], "cwd": "/"}\n': '"argv" must be a list of strings',
    b'{"argv": ["plan"], "cwd": 7}\n': '"cwd" must be an absolute path',
    b'{"argv": ["plan"], "cwd": "relative"}\n': '"cwd" must be an absolute path',
    b'{"argv": ["plan"], "cwd": "/\\u0000"}\n': '"cwd" must be an absolute path',
    b'{"argv": ["plan"], "cwd": "/", "command_line": "stepzoo"}\n':
        '"command_line" must be a list of strings',
    b'{"argv": ["plan"], "cwd": "/", "stepzoo": "0.1"}\n': '"stepzoo" must name',
}


def test_every_bad_request_is_answered_in_one_line_and_the_server_serves_on(server):
    sock, folder = server
    for payload, said in BAD_REQUESTS.items():
        answers = answers_to(sock, payload)
        assert len(answers) == 1 and said in answers[0]["refused"], (payload[:40], answers)
    # The asking command prints a refusal as its one line, exit status 2.
    again, _ = ask(folder, "plan", "nosuch", "--out", "x", "--server", str(sock))
    assert again.returncode == 2 and "unknown scenario 'nosuch'" in again.stderr


def test_the_server_serves_only_its_own_user(server, tmp_path):
    """A client of another user, let through the socket's folder and mode on purpose, is
    refused by its credentials before its request is read: nothing is planned for it."""
    uid = _other_user()
    sock, _ = server
    out = tmp_path / "theirs"
    # The server may close before the request is sent (a broken pipe): its answer is there.
    client = ("c = socket.socket(socket.AF_UNIX); c.settimeout(60); c.connect(sys.argv[3])\n"
              "try: c.sendall(json.dumps({'argv': ['plan', 'open_field', '--out', sys.argv[4]], "
              "'cwd': '/', 'stepzoo': json.loads(sys.argv[5])}).encode() + b'\\n')\n"
              "except BrokenPipeError: pass\n"
              "print(c.makefile().read(), end='')")
    modes = sock.parent.stat().st_mode, sock.stat().st_mode
    sock.parent.chmod(0o711)
    sock.chmod(0o666)
    try:
        proc = subprocess.run([sys.executable, "-c", AS_USER, str(uid), client, str(sock),
                               str(out), json.dumps(identity())],
                              capture_output=True, text=True, timeout=120)
    finally:
        sock.parent.chmod(modes[0])
        sock.chmod(modes[1])
    assert proc.returncode == 0, proc.stderr
    assert [json.loads(line) for line in proc.stdout.splitlines()] == [{"refused": (
        f"this server serves only its own user (uid 0), not uid {uid}; ask with `stepzoo "
        "plan ... --server SOCKET`")}]
    assert not out.exists()


def test_a_client_sends_nothing_to_a_server_of_another_user(tmp_path, capsys):
    """The issue's squatted socket: another user listens where the asker looks. The asker
    checks the listener's credentials and refuses in one line before it sends its request
    (arguments and folder); the listener receives nothing."""
    uid = _other_user()
    home = Path(tempfile.mkdtemp(prefix="stepzoo-squat-"))
    try:
        home.chmod(0o777)
        sock = home / "plan.sock"
        squatter = ("s = socket.socket(socket.AF_UNIX); s.bind(sys.argv[3]); s.listen(); "
                    "print('ready', flush=True); s.settimeout(60); c, _ = s.accept(); "
                    "c.settimeout(60); got = b''\n"
                    "while (b := c.recv(65536)): got += b\n"
                    "print(len(got))")
        proc = subprocess.Popen([sys.executable, "-c", AS_USER, str(uid), squatter, str(sock)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert proc.stdout.readline() == "ready\n", proc.stderr.read()
            out = tmp_path / "plan"
            code = main(["plan", "open_field", "--out", str(out), "--server", str(sock)])
            received, err = proc.communicate(timeout=60)
        finally:
            proc.kill()
            proc.wait()
    finally:
        shutil.rmtree(home)
    assert code == 2 and received == "0\n", err
    assert capsys.readouterr().err == (
        f"stepzoo plan: error: the server at {sock} runs as another user (uid {uid}), not as "
        "you; a plan is sent only to a server of your own: start one with `stepzoo serve` (its "
        "default socket is in a folder only you may write) and give its socket\n")
    assert not out.exists()


def test_serve_refuses_a_socket_path_of_another_user_in_one_line(tmp_path, capsys):
    """A socket file another user left (or listens on) at the given path: named, not taken
    for a server of one's own, not removed."""
    uid = _other_user()
    path = tmp_path / "squat.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.bind(str(path))
    os.chown(path, uid, uid)
    assert main(["serve", "--socket", str(path)]) == 2
    assert capsys.readouterr().err == (
        f"stepzoo serve: error: {path} belongs to another user (uid {uid}); a server there would "
        "not be yours, and your plans would not reach you: give --socket in a folder only you "
        "may write (or leave it out: the default is private)\n")
    assert path.lstat().st_uid == uid


def test_the_default_socket_is_in_a_private_folder(tmp_path, monkeypatch, capsys):
    """$XDG_RUNTIME_DIR when it is the user's own and no one else may write there; else the
    cache folder's stepzoo/, made 0700, and refused when others may write into it."""
    from stepzoo.search.plans.request import default_socket
    monkeypatch.delenv("STEPZOO_SERVER", raising=False)
    runtime, cache = tmp_path / "run", tmp_path / "cache"
    runtime.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(runtime))
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
    assert default_socket() == runtime / "stepzoo-plan.sock"
    runtime.chmod(0o777)                     # shared: anyone could put a socket there
    assert default_socket() == cache / "stepzoo" / "plan.sock"
    (cache / "stepzoo").mkdir(parents=True, mode=0o777)
    (cache / "stepzoo").chmod(0o777)
    assert main(["serve", "--warm-up", "nosuch"]) == 2    # refused before it warms up
    assert capsys.readouterr().err == (
        f"stepzoo serve: error: {cache / 'stepzoo'}, the default socket's folder, is not "
        "private: other users may write into it; give --socket PATH in a folder only you may "
        "write\n")
    (cache / "stepzoo").rmdir()
    from stepzoo.cli.serve import _private
    _private(cache / "stepzoo")
    assert (cache / "stepzoo").stat().st_mode & 0o777 == 0o700


def test_a_request_timeout_out_of_range_is_refused(capsys):
    for value in ("0", "nan", "inf"):
        assert main(["serve", "--request-timeout", value, "--warm-up", "nosuch"]) == 2
        assert capsys.readouterr().err.startswith(
            "stepzoo serve: error: --request-timeout must be a number of seconds in (0, 3600]")


def _fake_server(path: Path, answer: bytes | None):
    """A socket at `path` that accepts one connection, reads its request line and sends
    `answer` (None: nothing, ever, until the test ends); returns (thread, listening socket)."""
    listening = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listening.bind(str(path))
    listening.listen()

    def serve():
        conn, _ = listening.accept()
        with conn:
            conn.settimeout(60)
            Messages(conn).next()
            if answer is not None:
                conn.sendall(answer)
            else:
                conn.recv(1)                    # the asker giving up closes its side
    import threading
    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return thread, listening


@pytest.mark.parametrize("answer, said", [
    (None, "has not taken the plan in 1 s"),
    (b'{"exit": 1000}\n', "not a stepzoo server's answer"),
    (b'{"exit": -1}\n', "not a stepzoo server's answer"),
    (b'{"exit": true}\n', "not a stepzoo server's answer")])
def test_a_socket_that_never_answers_or_answers_no_exit_status_is_one_line(tmp_path, answer,
                                                                           said):
    """The asker has its own deadline for the server to take the plan, and takes as an exit
    status only a byte's worth (1000 used to end it with status 232, -1 with 255)."""
    thread, listening = _fake_server(tmp_path / "fake.sock", answer)
    with listening:
        proc = subprocess.run([sys.executable, "-m", "stepzoo", "plan", "street", "--out",
                               str(tmp_path / "x"), "--server", str(tmp_path / "fake.sock"),
                               "--server-timeout", "1"], capture_output=True, text=True,
                              timeout=120)
        thread.join(60)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and said in lines[0], proc.stderr
    assert not (tmp_path / "x").exists()
