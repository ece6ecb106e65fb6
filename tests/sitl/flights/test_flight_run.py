"""How `fly` learns that the companion is ready: a line on a pipe, end of file if it stopped first."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import tomllib

import pytest

from sitl.flights.flight_run import FlightError, _await_ready, _start


def _companion(tmp_path, code: str):
    """A stand-in for the companion running `code` with the pipe's writing end as argv[1]."""
    stack = contextlib.ExitStack()
    read_end, write_end = os.pipe()
    stack.callback(os.close, read_end)
    log = tmp_path / "companion.log"
    try:
        with log.open("w") as stderr:
            proc = _start(stack, subprocess.Popen([sys.executable, "-c", code, str(write_end)], stderr=stderr,
                                                  pass_fds=(write_end,)))
    finally:
        os.close(write_end)
    return stack, proc, read_end, log


def test_a_companion_that_stops_before_it_is_ready_is_reported_with_its_last_words(tmp_path):
    stack, proc, ready, log = _companion(tmp_path, "import sys; sys.exit('m4-companion: error: no airframe here')")
    with stack, pytest.raises(FlightError, match="^the companion did not start: no airframe here$"):
        _await_ready(proc, ready, log)


def test_fly_waits_for_the_ready_line_however_long_the_start_takes(tmp_path):
    built = tmp_path / "nmpc-built"
    code = (f"import os, sys, time; time.sleep(0.5); open({str(built)!r}, 'w').close(); "
            "os.write(int(sys.argv[1]), b'ready\\n'); time.sleep(30)")
    stack, proc, ready, log = _companion(tmp_path, code)
    with stack:
        _await_ready(proc, ready, log)
        assert built.exists() and proc.poll() is None


def test_the_companions_priority_reaches_its_config_and_zero_leaves_the_key_out(tmp_path):
    from companion.config import load_config
    from sitl.flights.flight_run import FlightOptions, companion_config_text

    for priority in (0, 40):
        path = tmp_path / f"companion-{priority}.toml"
        path.write_text(companion_config_text(FlightOptions(companion_priority=priority), 14550, None))
        assert load_config(path).realtime_priority == priority
        assert ("realtime_priority" in path.read_text()) == bool(priority)


def test_a_sitl_priority_that_cannot_be_had_is_one_line(tmp_path, monkeypatch):
    from sitl.flights.flight_run import _real_time

    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse, raising=False)
    stack, proc, _, _ = _companion(tmp_path, "import time; time.sleep(30)")
    with stack, pytest.raises(FlightError, match="^cannot give the SITL real-time priority 45: Operation not permitted$"):
        _real_time(proc, 45)


@pytest.mark.skipif(os.geteuid() != 0, reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_a_sitl_that_started_a_thread_already_gets_the_priority_in_every_thread(tmp_path):
    """A SITL forked from its pre-loaded parent (campaigns) may have started its signing
    timestamps' thread before the flight gives it the priority: that thread must get it too."""
    from sitl.flights.flight_run import _real_time

    code = ("import os, sys, threading, time; threading.Thread(target=time.sleep, args=(30,), daemon=True).start(); "
            "os.write(int(sys.argv[1]), b'up\\n'); time.sleep(30)")
    stack, proc, up, _ = _companion(tmp_path, code)
    with stack:
        assert os.read(up, 16) == b"up\n"
        tasks = os.listdir(f"/proc/{proc.pid}/task")
        assert len(tasks) == 2
        _real_time(proc, 45)
        assert {(os.sched_getscheduler(int(tid)), os.sched_getparam(int(tid)).sched_priority) for tid in tasks} == {
            (os.SCHED_FIFO, 45)}


def test_pin_puts_every_thread_of_a_process_on_its_cpus_and_the_ones_it_starts_later(tmp_path):
    """What python -m benchmarks.fly --companion-cpus/--sitl-cpus do to a flight's processes:
    a thread started before the pin and one started after it both run on the CPU given."""
    from sitl.flights.flight_run import pin

    cpu = max(os.sched_getaffinity(0))
    code = ("import os, sys, threading, time; threading.Thread(target=time.sleep, args=(30,), daemon=True).start(); "
            "os.write(int(sys.argv[1]), b'up\\n'); sys.stdin.readline(); "
            "threading.Thread(target=time.sleep, args=(30,), daemon=True).start(); "
            "os.write(int(sys.argv[1]), b'two\\n'); time.sleep(30)")
    read_end, write_end = os.pipe()
    proc = subprocess.Popen([sys.executable, "-c", code, str(write_end)], stdin=subprocess.PIPE, pass_fds=(write_end,))
    os.close(write_end)
    try:
        assert os.read(read_end, 16) == b"up\n"
        pin(proc.pid, frozenset({cpu}), "the SITL")
        proc.stdin.write(b"go\n")
        proc.stdin.flush()
        assert os.read(read_end, 16) == b"two\n"
        tasks = os.listdir(f"/proc/{proc.pid}/task")
        assert len(tasks) == 3 and {frozenset(os.sched_getaffinity(int(tid))) for tid in tasks} == {frozenset({cpu})}
    finally:
        proc.kill()
        proc.wait()
        os.close(read_end)


def test_a_pin_that_cannot_be_had_is_one_line(tmp_path, monkeypatch):
    from sitl.flights.flight_run import pin

    def refuse(*_):
        raise OSError(22, "Invalid argument")

    monkeypatch.setattr(os, "sched_setaffinity", refuse)
    stack, proc, _, _ = _companion(tmp_path, "import time; time.sleep(30)")
    with stack, pytest.raises(FlightError, match="^cannot pin the companion to CPU 0,1: Invalid argument$"):
        pin(proc.pid, frozenset({1, 0}), "the companion")


def test_both_ends_of_a_flight_sign_with_the_flights_own_key(tmp_path):
    """As on the robot: the companion's config names the key the SITL is given (run_flight writes
    a new one into the flight's folder for every flight)."""
    from companion.config import load_config
    from sitl.flights.flight_run import FlightFiles, FlightOptions, companion_config_text

    files = FlightFiles(tmp_path)
    files.companion_config.write_text(companion_config_text(FlightOptions(), 14550, None))
    key, _ = load_config(files.companion_config).link.signing_files()
    assert key == files.signing_key


def test_the_sitl_starts_alongside_the_companion_and_waits_on_its_start_pipe(tmp_path, monkeypatch):
    """By the time fly waits for the companion's ready line, the SITL is started too, waiting on
    its start pipe."""
    from m4.scenario import load_scenario
    from sitl import scenarios
    from sitl.flights import flight_run

    started: list[list[str]] = []
    at_ready: list[list[str]] = []

    def start(program, args, log_path, pass_fd):
        started.append([program, *args, *map(str, pass_fd)])
        return subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])

    def ready(*_):
        at_ready.extend(started)
        raise FlightError("the companion did not start: stand-in")

    monkeypatch.setattr(flight_run, "_await_ready", ready)
    path = scenarios.scenario_path("hover-rotor-loss")
    with pytest.raises(FlightError, match="stand-in"):
        flight_run.run_flight(load_scenario(path), path.read_text(), tmp_path / "flight",
                              flight_run.FlightOptions(record_feed=False), start=start)
    assert [cmd[0] for cmd in at_ready] == ["companion.cli", "sitl.cli"] and "--start-fd" in at_ready[1]


def _hover(tmp_path, name: str, lockstep_timeout_s: float):
    from m4.scenario import parse_scenario
    from sitl.flights.flight_run import FlightOptions, run_flight

    text = f'name = "{name}"\nduration_s = 0.5\n\n[start]\nned_m = [0.0, 0.0, -3.0]\n'
    options = FlightOptions(record_feed=False, lockstep_timeout_s=lockstep_timeout_s)
    return run_flight(parse_scenario(tomllib.loads(text), name), text, tmp_path / name, options)


def test_a_flight_whose_lockstep_wait_ran_out_is_flagged_stalled(tmp_path):
    """A companion later than the SITL's wait (1 ms: later than any answer can come) leaves the
    FC in its failsafe: the flight is flagged stalled; with the campaign's wait it is not."""
    from sitl.campaigns.detection_campaign import LOCKSTEP_TIMEOUT_S
    from sitl.flights.flight_run import stalled

    late = _hover(tmp_path, "late", 0.001)
    assert "no setpoint for 0.001 s" in late.sitl_log.read_text() and stalled(late)
    assert not stalled(_hover(tmp_path, "patient", LOCKSTEP_TIMEOUT_S))


def test_in_lockstep_the_companion_calls_no_wall_clock_silence_a_lost_link_before_10_s(tmp_path):
    """The FC's clock waits for the companion in lockstep: a silence there is the machine's load.
    In real time the companion's own 0.3 s stands."""
    from companion.config import load_config
    from sitl.flights.flight_run import FlightOptions, companion_config_text

    for realtime, timeout_s in ((False, 10.0), (True, 0.3)):
        path = tmp_path / f"companion-{realtime}.toml"
        path.write_text(companion_config_text(FlightOptions(realtime=realtime), 14550, None))
        assert load_config(path).link.telemetry_timeout_s == timeout_s


def test_a_port_another_flight_took_between_the_pick_and_the_bind_is_picked_again(tmp_path, monkeypatch):
    """Parallel campaign workers pick their ports at once: the companion finds its port taken
    ("Address already in use") and the flight starts again on a new one."""
    from sitl.flights import flight_run
    from sitl.flights.fly import fly

    pick, picked = flight_run.free_port, []

    def first_pick_taken(kind=socket.SOCK_DGRAM):
        port = taken.getsockname()[1] if kind == socket.SOCK_DGRAM and not picked else pick(kind)
        picked.append(port)
        return port

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        monkeypatch.setattr(flight_run, "free_port", first_pick_taken)
        metrics = fly("hover-rotor-loss", tmp_path / "out", figures=False, progress=False)
        assert metrics["completed"] and picked[0] == taken.getsockname()[1] and len(picked) >= 3   # UDP, TCP, UDP
