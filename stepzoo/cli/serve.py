"""`stepzoo serve`: a long-lived planner process. It plans once to warm up (JAX imported, the
planner's programs compiled, the connection's solver built, the plotting library loaded), then
answers `stepzoo plan ... --server SOCKET` requests on a Unix socket, one at a time in order of
arrival, each run as that command would run in the asking process: in its folder, with its
command line, its stdout and stderr sent back as written, and its exit status. It serves
only its own user (the peer's credentials, SO_PEERCRED), gives each connection a deadline for
its whole request, and answers a bad request with one line and serves on."""
import io
import os
import select
import shlex
import signal
import socket
import stat
import sys
import tempfile
import threading
import time
import traceback
import _thread
from pathlib import Path

from stepzoo import cli
from stepzoo.errors import UsageError
from stepzoo.search.plans.request import (ENV, Messages, check_request, default_socket,
                                         identity, not_private, peer_uid, send)

WARM_UP_SCENARIO = "open_field"   # planned at start-up unless told: it compiles what plans use
# The signal by which a plan is stopped when its asker goes: its handler raises what Ctrl-C
# raises. Not SIGINT itself, which a server started in the background may ignore.
STOP = signal.SIGUSR1
REQUEST_S = 10.0                  # [s] a connection has to send its whole request line
MAX_REQUEST_S = 3600.0            # [s] beyond it, a request's deadline protects no one
LINGER_S = 1.0                    # [s] a refused connection is read (and dropped) at most


def add_arguments(p):
    p.add_argument("--socket", metavar="PATH", help="Unix socket to listen on (default: "
                   f"${ENV}, else $XDG_RUNTIME_DIR/stepzoo-plan.sock, else "
                   "~/.cache/stepzoo/plan.sock, in a folder made private); only this user "
                   "may connect")
    p.add_argument("--request-timeout", type=float, default=REQUEST_S, metavar="S",
                   help="seconds a connection has to send its whole request, however slowly "
                   f"it sends (default {REQUEST_S:g}); then it is cut off and the next served")
    p.add_argument("--config", metavar="FILE", help="planner config TOML to warm up with "
                   "(default: the shipped one); requests may name any config")
    p.add_argument("--warm-up", metavar="SCENARIO", default=WARM_UP_SCENARIO,
                   help="built-in scenario or scenario .toml file planned at start-up, so that "
                   "plans like it (vehicle, goal speed) find everything compiled (default: "
                   f"{WARM_UP_SCENARIO})")


def main(args) -> int:
    if not 0 < args.request_timeout <= MAX_REQUEST_S:
        raise UsageError(f"--request-timeout must be a number of seconds in (0, "
                         f"{MAX_REQUEST_S:g}] (a client that sends nothing holds the server "
                         f"that long), got {args.request_timeout}")
    given = args.socket or os.environ.get(ENV)
    path = Path(given or default_socket()).absolute()
    if not given:
        _private(path.parent)
    listener, inode = _listen(path)
    signal.signal(STOP, _interrupt)
    # `kill` (SIGTERM) ends the server as Ctrl-C does, through the `finally` that removes the
    # socket file; a plan it interrupts is answered by no exit status.
    signal.signal(signal.SIGTERM, _exit)
    try:
        started = time.perf_counter()
        _warm_up(args.warm_up, args.config)
        sys.stdout.write(f"stepzoo serve: planning for `stepzoo plan ... --server {path}` (or "
                         f"{ENV}={path}); pid {os.getpid()}, warmed up in "
                         f"{time.perf_counter() - started:.1f} s; Ctrl-C stops\n")
        sys.stdout.flush()
        while True:
            connection, _ = listener.accept()
            with connection:
                uid = peer_uid(connection, path)
                if uid != os.geteuid():
                    _refuse(connection, f"this server serves only its own user (uid "
                                        f"{os.geteuid()}), not uid {uid}")
                    continue
                _answer(connection, args.request_timeout)
    finally:
        listener.close()
        if path.exists() and path.stat().st_ino == inode:   # not a successor's socket
            path.unlink()


def _private(folder: Path) -> None:
    """Make `folder` (the default socket's) a private folder of this user: created with mode
    0700 where missing; UsageError where it is another user's or others may write into it,
    since whoever may write there may put a socket of their own in the server's place."""
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    why = not_private(folder)
    if why:
        raise UsageError(f"{folder}, the default socket's folder, is not private: {why}; "
                         "give --socket PATH in a folder only you may write")


def _listen(path: Path) -> tuple[socket.socket, int]:
    """A socket listening at `path` that only this user may connect to, and its inode. A
    socket file left by a server of this user that died is replaced; anything else there is
    kept, and another user's file is refused (a squatted path: the server's clients would
    find that user's socket)."""
    if path.is_symlink() or path.exists():
        owner = path.lstat().st_uid
        if owner != os.geteuid():
            raise UsageError(f"{path} belongs to another user (uid {owner}); a server there "
                             "would not be yours, and your plans would not reach you: give "
                             "--socket in a folder only you may write (or leave it out: the "
                             "default is private)")
        if not stat.S_ISSOCK(path.lstat().st_mode):
            raise UsageError(f"{path} exists and is not a socket; give another --socket")
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        with probe:
            try:
                probe.connect(str(path))
            except ConnectionRefusedError:
                path.unlink()
            else:
                raise UsageError(f"a stepzoo server already listens at {path}; stop it first "
                                 "or give another --socket")
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    umask = os.umask(0o177)          # the file is born rw for the user only: no window open
    try:
        listener.bind(str(path))
    except OSError as err:
        listener.close()
        if err.errno is None:        # e.g. "AF_UNIX path too long"
            raise UsageError(f"cannot listen at {path}: {err}; give a shorter --socket") \
                from None
        raise UsageError(f"cannot listen at {path}: {err.strerror}; give another --socket") \
            from None
    finally:
        os.umask(umask)
    listener.listen()
    return listener, path.stat().st_ino


def _warm_up(scenario: str, config) -> None:
    """Plan `scenario` (with `config`) into a temporary folder, nothing printed; a bad
    scenario or config is the one line its plan would print."""
    with tempfile.TemporaryDirectory(prefix="stepzoo-serve-") as folder:
        argv = ["plan", scenario, "--out", folder, "--quiet"]
        errors = io.StringIO()
        stdout, stderr = sys.stdout, sys.stderr
        sys.stdout, sys.stderr = io.StringIO(), errors
        try:
            code = _plan(argv + (["--config", config] if config else []))
        finally:
            sys.stdout, sys.stderr = stdout, stderr
    if code not in (0, 1):
        said = errors.getvalue().strip()
        line = said.splitlines()[-1] if said else f"status {code}"
        raise UsageError(f"the warm-up plan failed: {line.removeprefix('stepzoo plan: error: ')}")


def _plan(argv: list[str]) -> int:
    """`stepzoo` with the arguments `argv`, a plan, in this process."""
    try:
        args = cli.build_parser("plan").parse_args(argv)
    except SystemExit as done:       # a bad flag, or --help: argparse has said so
        return done.code if isinstance(done.code, int) else 2
    if args.command != "plan":
        sys.stderr.write(f"stepzoo {args.command}: error: a stepzoo server runs plans only\n")
        return 2
    args.server = None
    return cli.dispatch(args, argv)


def _answer(connection: socket.socket, request_s: float) -> None:
    """Read one request from `connection` within `request_s` seconds, run its plan here, send
    back what it printed and its exit status. Its folder is the asking process's for the
    duration, and closing the asking side stops the plan as Ctrl-C would (exit status 130).
    A request that is late, not JSON or not a request is refused in one line."""
    try:
        # The deadline is the whole request's, not each read's: a peer that sends a byte
        # now and then without ending its line holds the server no longer than one that
        # says nothing.
        asked = Messages(connection).next(time.monotonic() + request_s)
    except TimeoutError:
        _refuse(connection, f"no whole request line within {request_s:g} s")
        return
    except (ValueError, RecursionError):
        _refuse(connection, "a request is one line of JSON")
        return
    except OSError:
        return                        # the peer has gone: nobody is left to tell
    connection.settimeout(None)
    if asked is None:
        return                        # connected and closed without a word
    problem = check_request(asked)
    if problem:
        _refuse(connection, f"not a stepzoo request: {problem}")
        return
    mine = identity()
    if asked["stepzoo"] != mine:
        theirs = asked["stepzoo"]
        _send(connection, {"refused": (
            f"the server at {connection.getsockname()} runs stepzoo {mine['version']} from "
            f"{mine['package']}, this is stepzoo {theirs.get('version')} from "
            f"{theirs.get('package')}; start a server of this installation")})
        return
    home, started = os.getcwd(), time.perf_counter()
    try:
        os.chdir(asked["cwd"])
    except OSError as err:
        _send(connection, {"refused": f"the server cannot enter {asked['cwd']}: "
                                      f"{err.strerror}; plan from a folder it can read"})
        return
    _send(connection, {"stderr": ""})     # the plan is taken: the asker stops its clock
    saved = sys.stdout, sys.stderr, sys.argv
    sys.stdout, sys.stderr = _Forward(connection, "stdout"), _Forward(connection, "stderr")
    sys.argv = asked.get("command_line") or ["stepzoo"]
    watch = _Watch(connection)
    try:
        code = _stoppable(list(asked["argv"]), watch)
    finally:
        sys.stdout, sys.stderr, sys.argv = saved
        os.chdir(home)
    _send(connection, {"exit": code})
    sys.stderr.write(f"stepzoo serve: {shlex.join(asked['argv'])}: exit {code} in "
                     f"{time.perf_counter() - started:.2f} s"
                     f"{' (stopped by the asker)' if watch.stopped else ''}\n")
    if code == cli.INTERRUPTED and not watch.stopped:
        raise KeyboardInterrupt       # Ctrl-C on the server itself: stop serving


def _stoppable(argv: list[str], watch) -> int:
    """_plan(argv) while `watch` may interrupt it; every interrupt it asks for lands here."""
    try:
        try:
            watch.start()             # inside: an asker gone already is seen at once
            code = _plan(argv)
        except Exception:            # a bug: reported to the asker, as its own run would
            sys.stderr.write(traceback.format_exc())
            code = 1
        watch.stop()
        _nothing()                   # an interrupt the watch asked for before it stopped
    except KeyboardInterrupt:        # a stop that landed outside the command's own handler
        watch.stop()
        code = cli.INTERRUPTED
    return code


def _refuse(connection, why: str) -> None:
    """Answer `why` in one line (the asker prints it, exit status 2), and log it here. What
    the asker still sends is read and dropped for up to LINGER_S: a socket closed with bytes
    unread resets the connection, and the asker would lose the line."""
    _send(connection, {"refused": f"{why}; ask with `stepzoo plan ... --server SOCKET`"})
    sys.stderr.write(f"stepzoo serve: refused a connection: {why}\n")
    sys.stderr.flush()
    deadline = time.monotonic() + LINGER_S
    try:
        connection.shutdown(socket.SHUT_WR)
        connection.settimeout(LINGER_S)
        while time.monotonic() < deadline and connection.recv(65536):
            pass
    except OSError:
        pass                          # gone, or still sending at the end: closed anyway


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _exit(signum, frame):
    raise SystemExit(0)


def _nothing() -> None:
    """A call: Python runs the handlers of pending signals (and interrupts) at calls."""


def _send(connection, message) -> None:
    try:
        send(connection, message)
    except OSError:
        pass                          # the asker has gone; nobody is left to tell


class _Forward(io.TextIOBase):
    """A text stream whose writes go to the asker as messages of `key` ("stdout", "stderr");
    once the asker has gone they are dropped (its closing also stops the plan)."""

    encoding = "utf-8"

    def __init__(self, connection, key: str):
        super().__init__()
        self.connection, self.key, self.gone = connection, key, False

    def write(self, text: str) -> int:
        if text and not self.gone:
            try:
                send(self.connection, {self.key: text})
            except OSError:
                self.gone = True
        return len(text)

    def writable(self) -> bool:
        return True


class _Watch(threading.Thread):
    """Watches the asker's side of a connection while its plan runs: if it closes (Ctrl-C,
    or the asking process died), the plan is interrupted as Ctrl-C interrupts a plan."""

    def __init__(self, connection):
        super().__init__(daemon=True)
        self.connection, self.lock = connection, threading.Lock()
        self.done, self.stopped = threading.Event(), False

    def run(self):
        while not self.done.is_set():
            readable, _, _ = select.select([self.connection], [], [], 0.1)
            if readable:
                with self.lock:
                    if not self.done.is_set():
                        self.stopped = True
                        _thread.interrupt_main(STOP)
                return

    def stop(self):
        with self.lock:
            self.done.set()
        self.join()
