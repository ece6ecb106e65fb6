"""`m4-sitl`: bad input gives one error line and exit code 2, never a traceback."""

from __future__ import annotations

import gc
import os
import socket
import subprocess
import sys

import pytest

from sitl import scenarios
from sitl.cli import main


def _run(*args, timeout_s=60.0):
    return subprocess.run([sys.executable, "-m", "sitl.cli", *args], capture_output=True, text=True, timeout=timeout_s,
                          check=False)


def _one_error_line(proc) -> str:
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and lines[0].startswith("m4-sitl: error: "), proc.stderr
    return lines[0]


def test_list_prints_the_builtin_scenarios(capsys):
    assert main(["list"]) == 0
    assert capsys.readouterr().out.split() == scenarios.builtin_names()


@pytest.mark.parametrize("args, says", [
    (["serve", "--scenario", "no-such-scenario"], "unknown scenario 'no-such-scenario'"),
    (["serve", "--mavlink", "tcp:127.0.0.1:5760"], "bad MAVLink URL"),
    (["serve", "--duration", "0"], "--duration: must be a finite number > 0"),
    (["serve", "--duration", "inf"], "--duration: must be a finite number > 0"),
    (["serve", "--seed", "x"], "--seed: not an integer: 'x'"),
    (["serve", "--seed", "-1"], "--seed: must be >= 0"),
    (["fly"], "required: SCENARIO"),
    (["nope"], "invalid choice: 'nope'"),
    ([], "required: command"),
])
def test_bad_arguments_give_one_error_line_and_exit_2(capsys, args, says):
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("m4-sitl: error: ") and says in err[0]


def test_malformed_scenario_file_names_the_key(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text('name = "bad"\nduration_s = 5.0\n[start]\nned_m = [0.0, 0.0, -2.0]\nyaw = 3\n')
    assert main(["serve", "--scenario", str(path)]) == 2
    err = capsys.readouterr().err
    assert "yaw" in err and err.count("\n") == 1


def test_bad_signing_key_file_is_one_error_line(tmp_path, capsys):
    key = tmp_path / "key"
    key.write_text("not a key")
    assert main(["serve", "--signing-key", str(key)]) == 2
    assert "signing key" in capsys.readouterr().err


def test_port_in_use_is_one_error_line_and_exit_2():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        line = _one_error_line(_run("serve", "--mavlink", f"udpin:127.0.0.1:{port}"))
    assert f"udpin:127.0.0.1:{port}: cannot open" in line


def test_serve_runs_a_scenario_to_the_duration_and_exits_0(tmp_path):
    tlog = tmp_path / "x.tlog"
    proc = _run("serve", "--scenario", "hover-rotor-loss", "--duration", "0.5", "--lockstep-timeout", "0.2",
                "--mavlink", "udpin:127.0.0.1:0", "--tlog", str(tlog))
    assert proc.returncode == 0, proc.stderr
    assert "stopped at t=0.500 s" in proc.stderr and "ms per simulated second" in proc.stderr    # its CPU time
    assert tlog.exists()


def test_what_serve_built_is_frozen_out_of_the_garbage_collector_before_it_serves(monkeypatch):
    """A full collection walked the plant, the FC and the dialect: 20 ms in lockstep at
    hover-rotor-loss's 5.5 s, a stall the companion's next answer met on cold caches."""
    from sitl.serve import Server

    frozen = []                                # from none: tests/conftest.py unfreezes before each test
    monkeypatch.setattr(Server, "run", lambda self: frozen.append(gc.get_freeze_count()))
    code = main(["serve", "--scenario", "hover-rotor-loss", "--mavlink", "udpin:127.0.0.1:0"])
    assert code == 0 and frozen and frozen[0] > 10_000


def _serve_waiting(start: bytes) -> tuple[subprocess.CompletedProcess, list[bytes]]:
    """`serve --start-fd` given `start` on its pipe, then the pipe's end; what it said, and sent."""
    read_end, write_end = os.pipe()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as listener:
        listener.bind(("127.0.0.1", 0))
        cmd = [sys.executable, "-m", "sitl.cli", "serve", "--duration", "0.1", "--lockstep-timeout", "0.1",
               "--mavlink", f"udpout:127.0.0.1:{listener.getsockname()[1]}", "--start-fd", str(read_end)]
        proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, pass_fds=(read_end,))
        os.close(read_end)
        os.write(write_end, start)
        os.close(write_end)
        _, err = proc.communicate(timeout=60.0)
        listener.setblocking(False)
        sent = []
        while True:
            try:
                sent.append(listener.recv(65535))
            except BlockingIOError:
                return subprocess.CompletedProcess(cmd, proc.returncode, "", err), sent


def test_serve_told_to_start_on_its_start_fd_serves():
    proc, sent = _serve_waiting(b"start\n")
    assert proc.returncode == 0 and "stopped at t=0.100 s" in proc.stderr and sent


def test_serve_whose_start_fd_ends_unsaid_exits_without_serving():
    proc, sent = _serve_waiting(b"")
    assert proc.returncode == 0 and "serving" not in proc.stderr and not sent


def test_a_start_fd_that_is_not_open_is_one_error_line():
    assert "--start-fd 999: Bad file descriptor" in _one_error_line(_run("serve", "--start-fd", "999"))


def test_viewer_without_a_display_is_one_error_line():
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.run([sys.executable, "-m", "sitl.cli", "serve", "--viewer", "--mavlink", "udpin:127.0.0.1:0"],
                          capture_output=True, text=True, timeout=60.0, env=env, check=False)
    assert "viewer" in _one_error_line(proc)
