"""The programs' fork servers (m4/fork_server.py; companion/forks.py, sitl/forks.py): a forked run is
started, waited for, polled and signalled as a new process is, in the client's folder, with its
stderr and the one descriptor it is passed; the servers fork without a thread of their own.
The flights they fly: tests/flights/test_determinism.py."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from m4.fork_server import LOST_EXIT_CODE, ForkServer, ForkServerError

WAIT_S = 120.0          # a server's first run waits for its imports (MuJoCo, CasADi), on a loaded machine


@pytest.fixture(scope="module")
def sitl_forks():
    server = ForkServer("sitl.forks")
    yield server
    server.close()


def _waiting_serve(server: ForkServer, log: Path, *args: str):
    """A forked `m4-sitl serve` waiting on its start pipe, and the pipe's writing end."""
    read_end, write_end = os.pipe()
    try:
        run = server.start(["serve", "--duration", "1", *args], log, ("--start-fd", read_end))
    finally:
        os.close(read_end)
    return run, write_end


def test_a_runs_bad_input_is_its_one_line_in_its_log_and_exit_2(sitl_forks, tmp_path):
    log = tmp_path / "sitl.log"
    run = sitl_forks.start(["serve", "--scenario", "no-such-scenario"], log)
    assert run.wait(WAIT_S) == 2 and run.poll() == 2
    lines = log.read_text().splitlines()
    assert len(lines) == 1 and lines[0].startswith("m4-sitl: error:") and "no-such-scenario" in lines[0]


def test_a_run_gets_its_descriptor_works_in_the_clients_folder_and_ends_as_told(sitl_forks, tmp_path, monkeypatch):
    """The end of its start pipe, unsaid, tells `serve` to exit without serving (exit 0)."""
    monkeypatch.chdir(tmp_path)
    run, start = _waiting_serve(sitl_forks, tmp_path / "sitl.log", "--tlog", "flight.tlog")
    with pytest.raises(subprocess.TimeoutExpired):
        run.wait(0.5)
    assert run.poll() is None
    os.close(start)
    assert run.wait(WAIT_S) == 0
    assert (tmp_path / "flight.tlog").exists()


@pytest.mark.parametrize("stop, code", [("terminate", -signal.SIGTERM), ("kill", -signal.SIGKILL)])
def test_a_run_stopped_by_a_signal_says_so_as_a_process_does(sitl_forks, tmp_path, stop, code):
    run, start = _waiting_serve(sitl_forks, tmp_path / "sitl.log")
    try:
        getattr(run, stop)()
        assert run.wait(WAIT_S) == code
    finally:
        os.close(start)


def test_a_closed_client_ends_its_server_and_the_runs_still_going(tmp_path):
    server = ForkServer("sitl.forks")
    run, start = _waiting_serve(server, tmp_path / "sitl.log")
    try:
        server.close()
        assert run.wait(WAIT_S) == -signal.SIGTERM
    finally:
        os.close(start)


def _gone(pid: int) -> bool:
    """Exited (a zombie waiting for init counts as gone)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"
    except FileNotFoundError:
        return True


def test_a_server_killed_outright_takes_its_runs_with_it_and_the_next_run_gets_a_new_one(tmp_path):
    server = ForkServer("sitl.forks")
    run, start = _waiting_serve(server, tmp_path / "sitl.log")
    try:
        killed = server.pid
        os.kill(killed, signal.SIGKILL)
        assert run.wait(WAIT_S) == LOST_EXIT_CODE
        deadline = time.monotonic() + WAIT_S
        while not _gone(run.pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _gone(run.pid)                      # not left waiting on its start pipe with nobody to stop it
        again, start_again = _waiting_serve(server, tmp_path / "sitl-again.log")
        os.close(start_again)                      # end of file: the run is called off and exits 0
        assert server.pid != killed and again.wait(WAIT_S) == 0
    finally:
        os.close(start)
        server.close()


def test_the_companions_server_forks_without_a_thread_of_its_own(tmp_path):
    """A thread started before a fork (Zenoh's, a BLAS pool) is missing in the child, and a lock it
    held stays held there: the pre-loaded companion must have none."""
    server = ForkServer("companion.forks")
    try:
        log = tmp_path / "companion.log"
        run = server.start(["run", "--config", str(tmp_path / "missing.toml")], log)
        threads = len(os.listdir(f"/proc/{server.pid}/task"))
        assert run.wait(WAIT_S) == 2 and "missing.toml" in log.read_text()
    finally:
        server.close()
    assert threads == 1


def test_a_server_that_cannot_start_is_one_line_at_each_run(tmp_path):
    server = ForkServer("m4.no_such_fork_server")
    try:
        for _ in range(2):
            with pytest.raises(ForkServerError, match="^the fork server m4.no_such_fork_server .*: it exited with code 1$"):
                server.start(["serve"], tmp_path / "sitl.log")
    finally:
        server.close()
