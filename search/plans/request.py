"""A `stepzoo plan` sent to a `stepzoo serve` process over a Unix socket, and what comes back:
one JSON line asking (the command's arguments, folder and command line), then JSON lines of
its stdout and stderr as they are written and its exit status. Standard library only: the
asking process never imports JAX."""
from __future__ import annotations

import json
import os
import socket
import stat
import struct
import sys
import time
from pathlib import Path

import stepzoo
from stepzoo.errors import UsageError
from stepzoo.safe_parse import json_loads

ENV = "STEPZOO_SERVER"       # the socket `stepzoo plan` sends to, and `stepzoo serve` listens on
MAX_LINE = 1 << 20           # [bytes] longest message line read (a request is a few hundred)
# Writes to a peer that has gone raise an OSError instead of killing the writer with SIGPIPE
# (the `stepzoo` command restores SIGPIPE's default action for `stepzoo ... | head`).
NO_SIGPIPE = getattr(socket, "MSG_NOSIGNAL", 0)
# [s] the asker waits this long for the server to take its plan (its first message): a
# socket that accepts and never answers, or a server stuck, is then said, not waited on.
SERVER_WAIT_S = 300.0
MAX_WAIT_S = 86400.0


def default_socket() -> Path:
    """Where `stepzoo serve` listens unless told: $STEPZOO_SERVER, else the user's runtime
    folder ($XDG_RUNTIME_DIR) when it is private, else the user's cache folder's stepzoo/
    (which `stepzoo serve` makes private: no other user can put a socket there)."""
    if os.environ.get(ENV):
        return Path(os.environ[ENV])
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime and not not_private(runtime):
        return Path(runtime) / "stepzoo-plan.sock"
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "stepzoo" / "plan.sock"


def not_private(folder) -> str | None:
    """Why `folder` is not a private one of this user (None: it is): a folder, not a link,
    owned by this user, that no other user may write into (so none can replace a socket
    there)."""
    try:
        st = os.lstat(folder)
    except OSError as err:
        return f"it cannot be read ({err.strerror})"
    if not stat.S_ISDIR(st.st_mode):
        return "it is not a folder"
    if st.st_uid != os.geteuid():
        return f"it belongs to another user (uid {st.st_uid})"
    if st.st_mode & 0o022:
        return "other users may write into it"
    return None


def peer_uid(sock: socket.socket, path) -> int:
    """The user id of the process at the other end of the Unix socket `sock`: its
    credentials as the kernel recorded them (SO_PEERCRED, Linux); elsewhere the owner of the
    socket file `path`, whose mode lets no one else connect."""
    if hasattr(socket, "SO_PEERCRED"):
        size = struct.calcsize("3i")
        _, uid, _ = struct.unpack("3i", sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED,
                                                        size))
        return uid
    return os.stat(path).st_uid


def check_request(asked) -> str | None:
    """What is wrong with the request `asked` (None: nothing): a JSON object with "argv" (a
    list of strings), "cwd" (an absolute path), "stepzoo" (the asker's identity) and,
    optionally, "command_line" (a list of strings); no string holds a NUL byte."""
    if not isinstance(asked, dict):
        return "a request is a JSON object"

    def strings(value):
        return isinstance(value, list) and all(isinstance(a, str) and "\0" not in a
                                               for a in value)
    if not strings(asked.get("argv")):
        return '"argv" must be a list of strings (the arguments of `stepzoo`)'
    cwd = asked.get("cwd")
    if not (isinstance(cwd, str) and "\0" not in cwd and os.path.isabs(cwd)):
        return '"cwd" must be an absolute path (the asking process\'s folder)'
    if "command_line" in asked and not strings(asked["command_line"]):
        return '"command_line" must be a list of strings'
    theirs = asked.get("stepzoo")
    if not (isinstance(theirs, dict) and all(isinstance(theirs.get(k), str)
                                             for k in ("version", "package"))):
        return '"stepzoo" must name the asker\'s version and package'
    return None


def identity() -> dict:
    """This stepzoo's version and folder: a server answers only its own installation, whose
    code is what it has loaded."""
    return {"version": stepzoo.__version__,
            "package": str(Path(stepzoo.__file__).resolve().parent)}


def send(sock: socket.socket, message: dict) -> None:
    """One message as a JSON line."""
    sock.sendall(json.dumps(message).encode() + b"\n", NO_SIGPIPE)


class Messages:
    """The JSON messages arriving on a socket, one per line; `next()` is None once the peer
    stops sending. A read interrupted by Ctrl-C loses nothing: reading again goes on."""

    def __init__(self, sock: socket.socket):
        self.sock, self.buffer = sock, b""
        self.lines: list[bytes] = []

    def next(self, deadline: float | None = None) -> dict | None:
        """The next message; `deadline` (time.monotonic() [s]): TimeoutError once it
        passes, however slowly the peer sends."""
        while not self.lines:
            if deadline is not None:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError("no whole message line before the deadline")
                self.sock.settimeout(left)
            chunk = self.sock.recv(65536)
            if not chunk:
                return None
            *self.lines, self.buffer = (self.buffer + chunk).split(b"\n")
            if len(self.buffer) > MAX_LINE:
                raise ValueError(f"a message line longer than {MAX_LINE} bytes")
        return json_loads(self.lines.pop(0))


def request(path, argv: list[str], platform: str | None = None,
            wait_s: float = SERVER_WAIT_S) -> int:
    """Run `stepzoo` with the arguments `argv` (a plan) in the server listening at `path`,
    in this process's folder and with its command line: its stdout and stderr are written
    here as they come, and its exit status is returned; a missing server is a UsageError.
    Ctrl-C cancels the plan on the server and waits for it to stop; a second Ctrl-C stops
    waiting. A server that sends nothing for `wait_s` seconds [s] after the request (its
    first message says it took the plan) is a UsageError. `platform` (the --platform flag)
    is refused: the server has its own. E.g.
    `request("/tmp/plan.sock", ["plan", "street", "--out", "plan"])`."""
    if platform:
        raise UsageError("--platform does not go with --server: the server computes on the "
                         "platform it was started with (`stepzoo serve --platform NAME`)")
    if not 0 < wait_s <= MAX_WAIT_S:
        raise UsageError(f"--server-timeout must be a number of seconds in (0, "
                         f"{MAX_WAIT_S:g}], got {wait_s!r}")
    path = str(path)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    with sock:
        try:
            sock.connect(path)
        except (FileNotFoundError, ConnectionRefusedError):
            raise UsageError(f"no stepzoo server listens at {path}; start one with `stepzoo "
                             f"serve --socket {path}`, or plan here without --server (and "
                             f"without {ENV})") from None
        except OSError as err:
            raise UsageError(f"cannot reach a stepzoo server at {path}: "
                             f"{err.strerror or err}") from None
        uid = peer_uid(sock, path)
        if uid != os.geteuid():
            # Nothing is sent: the request names this process's folder and arguments.
            raise UsageError(f"the server at {path} runs as another user (uid {uid}), not "
                             "as you; a plan is sent only to a server of your own: start "
                             "one with `stepzoo serve` (its default socket is in a folder "
                             "only you may write) and give its socket")
        send(sock, {"argv": list(argv), "cwd": os.getcwd(), "command_line": list(sys.argv),
                    "stepzoo": identity()})
        answers, cancelled = Messages(sock), False
        deadline: float | None = time.monotonic() + wait_s
        while True:
            try:
                answer = answers.next(deadline)
                # An exit status is one a stepzoo command gives: a byte's worth at most.
                if not (answer is None or isinstance(answer, dict) and
                        type(answer.get("exit", 0)) is int and 0 <= answer.get("exit", 0)
                        <= 255):
                    raise ValueError("not an answer")
                if deadline is not None:      # the server has the plan: its budget
                    deadline = None           # bounds it
                    sock.settimeout(None)
            except TimeoutError:
                raise UsageError(f"the stepzoo server at {path} has not taken the plan in "
                                 f"{wait_s:g} s (busy, stuck, or not a stepzoo server); see "
                                 "its output, or wait longer with --server-timeout S") from None
            except (ValueError, RecursionError):
                raise UsageError(f"{path} answered something that is not a stepzoo server's "
                                 "answer; check that it is a `stepzoo serve` socket") from None
            except KeyboardInterrupt:
                if cancelled:
                    raise
                # Closing our side asks the server to stop the plan; its answer follows.
                sock.shutdown(socket.SHUT_WR)
                cancelled = True
                continue
            if answer is None:
                break
            if "exit" in answer:
                return int(answer["exit"])
            if "refused" in answer:
                raise UsageError(answer["refused"])
            stream = sys.stdout if "stdout" in answer else sys.stderr
            stream.write(answer.get("stdout", answer.get("stderr", "")))
            if stream is sys.stderr:
                stream.flush()
    raise UsageError(f"the stepzoo server at {path} stopped before the plan ended; see the "
                     "server's own output")
