"""A pre-loaded parent that forks a child per run of its program (for campaigns: many short runs).

A program's fork server (`python -m companion.forks FD`, `python -m sitl.forks FD`) imports
what its command imports, then `serve(FD)` waits for requests on FD. Each request (an argument
list, a folder, the run's stderr and at most one descriptor to pass) forks a child, and in the
child `serve` returns: the child sets up what a new process would have (stdin and stdout
/dev/null, stderr the run's, the folder, its own signal handlers, `sys.argv`) and the server's
`__main__` runs the command line with it, `sys.exit(main(argv))`, as `python -m PROGRAM ARGV`
would, its interpreter's exit included. What the child does not pay: the interpreter's start
and the imports (the companion's CasADi, Zenoh and MAVLink dialect, the SITL's MuJoCo: most
of a flight's start but the NMPC's build).

Fork before any thread: a server must have started none (OpenBLAS's idle workers are the one
exception: OpenBLAS stops them at a fork and starts them again when needed). The server
reaps its children and says each one's exit code to the run's own status socket; it exits
when its client closes the request socket, terminating the runs still going.

`ForkServer(module)` is the client: it starts the server and gives a `Run` for each request,
which a caller waits for, polls and signals as it would a `subprocess.Popen`.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

REQUEST_MAX_BYTES = 1 << 16
STATUS_MAX_BYTES = 64
RESERVED_FD = 100              # the server's own descriptors sit at or above it, out of a child's way
LOST_EXIT_CODE = 255           # a run whose server vanished before saying how it ended
END_WAIT_S = 10.0              # for the runs to stop when the client is gone, before they are killed
EXIT_WAIT_S = 1.0              # for a server found unreachable to be seen exited
START_TIMEOUT_S = 300.0        # for the server's answer to a request (its first: after its imports, under load)
PR_SET_PDEATHSIG = 1           # Linux prctl: the signal a process gets when its parent dies


class ForkServerError(RuntimeError):
    """The fork server could not be started or reached (one line)."""


# --------------------------------------------------------------------------- the server

def serve(control_fd: int) -> list[str]:
    """Serve requests on `control_fd` until the client closes it (then exit); returns only in a
    forked child, with that run's argument list."""
    control = socket.socket(fileno=_moved_high(control_fd))
    wake_r, wake_w = (_moved_high(fd) for fd in os.pipe())
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)      # a handler, so that SIGCHLD wakes the loop
    signal.signal(signal.SIGINT, signal.SIG_IGN)        # Ctrl-C is for the runs; the client ends the server
    runs: dict[int, socket.socket] = {}                 # pid -> that run's status socket
    while True:
        readable = select.select([control, wake_r], [], [])[0]
        if wake_r in readable:
            os.read(wake_r, 4096)
            _reap(runs)
        if control in readable:
            request = _receive(control)
            if request is None:
                _end(runs)
            argv, child = _fork(request, runs)
            if child:
                for own in (control, *runs.values()):
                    own.close()
                for fd in (wake_r, wake_w):
                    os.close(fd)
                return argv


def _moved_high(fd: int) -> int:
    high = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, RESERVED_FD)
    os.close(fd)
    return high


def _receive(control: socket.socket) -> tuple[dict, list[int]] | None:
    try:
        data, fds, _, _ = socket.recv_fds(control, REQUEST_MAX_BYTES, 3)
    except ConnectionResetError:
        return None
    if not data:
        return None
    return json.loads(data), fds


def _fork(request: tuple[dict, list[int]], runs: dict[int, socket.socket]) -> tuple[list[str], bool]:
    """Fork the request's run; in the parent keep its status socket, in the child set it up."""
    fields, fds = request
    stderr_fd, status_fd, *passed = fds
    status = socket.socket(fileno=status_fd)
    sys.stdout.flush()
    sys.stderr.flush()
    server_pid = os.getpid()
    try:
        pid = os.fork()
    except OSError as e:                 # no memory or process left for it: this run fails, the server serves on
        for fd in (stderr_fd, *passed):
            os.close(fd)
        with contextlib.suppress(OSError):
            status.sendall(json.dumps({"error": f"cannot fork ({e.strerror or e})"}).encode())
        status.close()
        return [], False
    if pid:
        os.close(stderr_fd)
        for fd in passed:
            os.close(fd)
        runs[pid] = status
        with contextlib.suppress(OSError):            # a client gone: its end of the requests says so next
            status.sendall(json.dumps({"pid": pid}).encode())
        return [], False
    status.close()
    _die_with(server_pid)
    signal.set_wakeup_fd(-1)
    for sig in (signal.SIGCHLD, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    null = os.open(os.devnull, os.O_RDWR)
    for fd, onto in ((null, 0), (null, 1), (stderr_fd, 2)):
        os.dup2(fd, onto)
    for fd in (null, stderr_fd):
        os.close(fd)
    os.chdir(fields["cwd"])
    argv = list(fields["argv"])
    if passed:
        argv += [fields["fd_option"], str(passed[0])]
    sys.argv = [sys.argv[0], *argv]
    return argv, True


def _die_with(server_pid: int) -> None:
    """A run is killed when its server dies (Linux: PR_SET_PDEATHSIG), so a server killed outright
    leaves no run that nobody would stop; where prctl is missing the run goes on alone."""
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return
    prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != server_pid:      # the server died before prctl took effect
        os._exit(LOST_EXIT_CODE)


def _reap(runs: dict[int, socket.socket]) -> None:
    while runs:
        try:
            pid, wait_status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        status = runs.pop(pid, None)
        if status is not None:
            with contextlib.suppress(OSError):
                status.sendall(json.dumps({"exit": os.waitstatus_to_exitcode(wait_status)}).encode())
            status.close()


def _end(runs: dict[int, socket.socket]) -> None:
    """The client is gone: its runs still going are terminated (killed after END_WAIT_S) and
    reaped, and the server exits."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in runs:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
        deadline = time.monotonic() + END_WAIT_S
        while runs and time.monotonic() < deadline:
            _reap(runs)
            time.sleep(0.01)
    raise SystemExit(0)


# --------------------------------------------------------------------------- the client

class Run:
    """A forked run, waited for, polled and signalled as a `subprocess.Popen`."""

    def __init__(self, pid: int, status: socket.socket, args: list[str]):
        self.pid = pid
        self.args = args
        self.returncode: int | None = None
        self._status = status

    def poll(self) -> int | None:
        if self.returncode is None and select.select([self._status], [], [], 0)[0]:
            self._read_exit()
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None:
            if not select.select([self._status], [], [], timeout)[0]:
                raise subprocess.TimeoutExpired(self.args, timeout)
            self._read_exit()
        return self.returncode  # type: ignore[return-value]

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def _read_exit(self) -> None:
        data = self._status.recv(STATUS_MAX_BYTES)
        self.returncode = json.loads(data)["exit"] if data else LOST_EXIT_CODE
        self._status.close()


class ForkServer:
    """The client of `python -m MODULE FD`'s fork server, started at the first run."""

    def __init__(self, module: str):
        self.module = module
        self._control: socket.socket | None = None
        self._server: subprocess.Popen | None = None

    def start(self, argv: list[str], stderr_path: Path, pass_fd: tuple[str, int] | None = None) -> Run:
        """Run `python -m MODULE ARGV` in a fork of the server, stderr to `stderr_path`; `pass_fd`:
        (option, descriptor), the descriptor passed and named to the run by the option."""
        control = self._connected()
        fields = {"argv": argv, "cwd": os.getcwd(), "fd_option": pass_fd[0] if pass_fd else None}
        with stderr_path.open("wb") as stderr:
            status, status_there = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
            fds = [stderr.fileno(), status_there.fileno(), *([pass_fd[1]] if pass_fd else [])]
            try:
                socket.send_fds(control, [json.dumps(fields).encode()], fds)
            except OSError as e:
                status.close()
                raise ForkServerError(f"the fork server {self.module} cannot be reached ({e.strerror or e}): "
                                      f"{self._said()}") from None
            finally:
                status_there.close()
        reply = status.recv(STATUS_MAX_BYTES) if select.select([status], [], [], START_TIMEOUT_S)[0] else b""
        if not reply:
            status.close()
            raise ForkServerError(f"the fork server {self.module} did not start the run: {self._said()}")
        answer = json.loads(reply)
        if "error" in answer:
            status.close()
            raise ForkServerError(f"the fork server {self.module} did not start the run: {answer['error']}")
        return Run(answer["pid"], status, argv)

    @property
    def pid(self) -> int | None:
        """The server's process id (None before its first run)."""
        return None if self._server is None else self._server.pid

    def close(self) -> None:
        """End the server (and the runs still going)."""
        if self._control is not None:
            self._control.close()
            self._control = None
        if self._server is not None:
            self._server.wait()
            self._server = None

    def _connected(self) -> socket.socket:
        if self._server is not None and self._server.poll() is not None:    # it died: a new one serves on
            self._control.close()
            self._control, self._server = None, None
        if self._control is None:
            ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
            with theirs:
                self._server = subprocess.Popen([sys.executable, "-m", self.module, str(theirs.fileno())],
                                                pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL,
                                                stdout=subprocess.DEVNULL)
            self._control = ours
        return self._control

    def _said(self) -> str:
        """Whether the server is still running (waited for a moment: it may be exiting)."""
        try:
            return f"it exited with code {self._server.wait(EXIT_WAIT_S)}"  # type: ignore[union-attr]
        except subprocess.TimeoutExpired:
            return "it is still running"
