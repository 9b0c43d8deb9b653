"""A `stepzoo plan` sent to a `stepzoo serve` process over a Unix socket, and what comes back:
one JSON line asking (the command's arguments, folder and command line), then JSON lines of
its stdout and stderr as they are written and its exit status. Standard library only: the
asking process never imports JAX."""
from __future__ import annotations

import json
import os
import socket
import sys
from pathlib import Path

import stepzoo
from stepzoo.errors import UsageError
from stepzoo.safe_parse import json_loads

ENV = "STEPZOO_SERVER"       # the socket `stepzoo plan` sends to, and `stepzoo serve` listens on
MAX_LINE = 1 << 20           # [bytes] longest message line read (a request is a few hundred)
# Writes to a peer that has gone raise an OSError instead of killing the writer with SIGPIPE
# (the `stepzoo` command restores SIGPIPE's default action for `stepzoo ... | head`).
NO_SIGPIPE = getattr(socket, "MSG_NOSIGNAL", 0)


def default_socket() -> Path:
    """Where `stepzoo serve` listens unless told: $STEPZOO_SERVER, else the user's runtime
    folder ($XDG_RUNTIME_DIR, private to the user), else the user's cache folder."""
    if os.environ.get(ENV):
        return Path(os.environ[ENV])
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime:
        return Path(runtime) / "stepzoo-plan.sock"
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "stepzoo" / "plan.sock"


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
        self.sock, self.buffer, self.lines = sock, b"", []

    def next(self) -> dict | None:
        while not self.lines:
            chunk = self.sock.recv(65536)
            if not chunk:
                return None
            *self.lines, self.buffer = (self.buffer + chunk).split(b"\n")
            if len(self.buffer) > MAX_LINE:
                raise ValueError(f"a message line longer than {MAX_LINE} bytes")
        return json_loads(self.lines.pop(0))


def request(path, argv: list[str], platform: str | None = None) -> int:
    """Run `stepzoo` with the arguments `argv` (a plan) in the server listening at `path`,
    in this process's folder and with its command line: its stdout and stderr are written
    here as they come, and its exit status is returned; a missing server is a UsageError.
    Ctrl-C cancels the plan on the server and waits for it to stop; a second Ctrl-C stops
    waiting. `platform` (the --platform flag) is refused: the server has its own. E.g.
    `request("/tmp/plan.sock", ["plan", "street", "--out", "plan"])`."""
    if platform:
        raise UsageError("--platform does not go with --server: the server computes on the "
                         "platform it was started with (`stepzoo serve --platform NAME`)")
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
        send(sock, {"argv": list(argv), "cwd": os.getcwd(), "command_line": list(sys.argv),
                    "stepzoo": identity()})
        answers, cancelled = Messages(sock), False
        while True:
            try:
                answer = answers.next()
            except ValueError:
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
