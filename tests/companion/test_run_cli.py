"""`m4-companion run`: bad input is one line and exit code 2; SIGTERM/SIGINT stop it cleanly."""

from __future__ import annotations

import gc
import logging
import os
import re
import signal
import socket
import subprocess
import sys
import time

import pytest

from companion.app import CompanionApp
from companion.cli import main
from companion.config import default_log_dir
from m4.airframe import load_airframe
from m4.mavlink.signing import load_key, write_new_key
from sitl import scenarios
from sitl.flights.flight_run import free_port
from support.full_disk import FullDisk
from support.loopback_fc import LoopbackFc


@pytest.fixture(autouse=True)
def _root_logging_restored():
    """`run` sets up logging on the stderr of the moment (captured here): undo it afterwards."""
    root = logging.getLogger()
    handlers = list(root.handlers)
    yield
    for handler in root.handlers[:]:
        if handler not in handlers:
            root.removeHandler(handler)


@pytest.fixture
def signed(tmp_path) -> list[str]:
    """The arguments that give the companion a signing key (it refuses to fly unsigned by omission)."""
    write_new_key(tmp_path / "mavlink.key")
    return ["--signing-key", str(tmp_path / "mavlink.key")]


def run_cli(capsys, *args) -> tuple[int, list[str]]:
    code = main(["run", *args])
    return code, capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize("args, says", [
    (["--config", "/nonexistent/companion.toml"], "no such file"),
    (["--fc", "udpout:127.0.0.1"], "bad MAVLink URL"),
    (["--fc", "carrier-pigeon"], "bad MAVLink URL"),
])
def test_bad_input_is_one_clear_line_and_exit_2(capsys, args, says):
    code, lines = run_cli(capsys, *args)
    assert code == 2
    assert len(lines) == 1 and lines[0].startswith("m4-companion: error:") and says in lines[0]


def test_a_config_with_an_unknown_key_names_it(capsys, tmp_path):
    config = tmp_path / "companion.toml"
    config.write_text("[control]\nrate_hz = 50.0\nratez = 3\n")
    code, lines = run_cli(capsys, "--config", str(config))
    assert code == 2 and len(lines) == 1 and "ratez" in lines[0]


@pytest.mark.parametrize("value", ["100", "-1", "40.0", '"high"'])
def test_a_bad_realtime_priority_is_one_line_naming_it(capsys, tmp_path, value):
    config = tmp_path / "companion.toml"
    config.write_text(f"[control]\nrealtime_priority = {value}\n")
    code, lines = run_cli(capsys, "--fc", "udpin:127.0.0.1:0", "--config", str(config))
    assert code == 2 and len(lines) == 1 and "realtime_priority" in lines[0], lines


def test_a_mission_file_without_a_mission_is_refused(capsys, tmp_path):
    mission = tmp_path / "mission.toml"
    mission.write_text("name = 'x'\n")
    code, lines = run_cli(capsys, "--mission", str(mission))
    assert code == 2 and len(lines) == 1 and "[mission]" in lines[0]


def test_no_c_compiler_for_the_nmpc_is_one_clear_line_and_exit_2(capsys, tmp_path, monkeypatch, signed):
    monkeypatch.setenv("M4_CACHE_DIR", str(tmp_path / "cache"))        # nothing compiled yet
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    code, lines = run_cli(capsys, "--fc", "udpin:127.0.0.1:0", *signed)
    assert code == 2 and len(lines) == 1 and "C compiler" in lines[0] and "codegen = false" in lines[0], lines


def test_a_port_in_use_is_one_clear_line_and_exit_2(capsys, signed):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        code, lines = run_cli(capsys, "--fc", f"udpin:127.0.0.1:{busy.getsockname()[1]}", *signed)
    assert code == 2 and len(lines) == 1 and "in use" in lines[0]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_the_companion_cleanly(sig, signed):
    proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--fc", "udpin:127.0.0.1:0", *signed],
                            stderr=subprocess.PIPE, text=True)
    try:
        said = []
        while "ready" not in (line := proc.stderr.readline()) and line:
            said.append(line)                                 # the start's lines: the log, the mission, the feed
        assert "ready" in line, said
        time.sleep(0.2)
        proc.send_signal(sig)
        code = proc.wait(timeout=10)
        rest = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert code == 0
    assert f"stopped by {sig.name} after 0 setpoints (no flight: the flight controller never sent telemetry)" in rest
    assert re.search(r"flight log: \S+/flight-\d{8}-\d{6}(-\d+)?\.tlog \(a new file at each arming", rest), rest
    assert "feed off: m4-companion watch and dashboard see nothing" in rest
    assert "Traceback" not in rest


def test_the_ready_line_goes_to_the_ready_fd_which_is_then_closed_while_the_companion_runs_on(signed):
    read_end, write_end = os.pipe()
    proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--fc", "udpin:127.0.0.1:0", *signed,
                             "--ready-fd", str(write_end)], pass_fds=(write_end,), stderr=subprocess.DEVNULL)
    os.close(write_end)
    try:
        with os.fdopen(read_end) as ready:
            assert ready.readline() == "ready: 50 Hz on udpin:127.0.0.1:0\n"
            assert ready.read() == ""                    # closed: nothing more will come
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_ready_fd_that_is_not_open_is_refused_before_the_nmpc_is_built(capsys):
    read_end, write_end = os.pipe()
    os.close(read_end)
    os.close(write_end)                                   # a descriptor number known to be closed now
    code, lines = run_cli(capsys, "--fc", "udpin:127.0.0.1:0", "--ready-fd", str(write_end))
    assert code == 2 and len(lines) == 1 and f"--ready-fd {write_end}" in lines[0]


@pytest.mark.parametrize("feed", [
    'zenoh_config = "/etc/m4/no-such-zenoh-companion.json5"',            # the deploy default's path, not installed
    'mode = "client"\nconnect = "tcp/127.0.0.1:{port}"',                  # no router there
])
def test_a_companion_whose_feed_cannot_reach_zenoh_says_so_once_and_flies(tmp_path, feed, signed):
    config = tmp_path / "companion.toml"
    config.write_text("[feed]\n" + feed.format(port=free_port(socket.SOCK_STREAM)) + "\n")
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "run", "--config", str(config),
                             "--fc", f"udpin:127.0.0.1:{port}", *signed], stderr=subprocess.PIPE, text=True)
    fc = LoopbackFc(port, load_airframe(), key=load_key(tmp_path / "mavlink.key"))
    try:
        said = []
        while "ready" not in (line := proc.stderr.readline()) and line:
            said.append(line)
        assert "ready" in line, said
        setpoints = 0
        for k in range(50):                                   # one second of telemetry at 50 Hz
            fc.heartbeat()
            fc.frame(20 * k)
            time.sleep(0.02)
            setpoints += sum(m.get_type() == "M4_SETPOINT" for m in fc.received())
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=10)
        said += proc.stderr.readlines()
    finally:
        fc.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert code == 0 and setpoints >= 25, (code, setpoints, said)
    assert len([line for line in said if "feed down" in line]) == 1, said
    assert "Traceback" not in "".join(said)


def test_a_disk_full_when_the_flight_ends_neither_changes_the_exit_code_nor_hides_the_final_statistics(
        capsys, caplog, monkeypatch, signed):
    disk = FullDisk(default_log_dir(), monkeypatch)           # where the tests' companions log

    def flight(app):                                          # the link's packets go to the log, then the disk fills
        app.fc.statustext(6, "companion: flying")
        app.flight_log.pack()                                 # as at the end of each poll
        while app.flight_log.records == 0:
            time.sleep(0.01)
        disk.full = True
        app.fc.statustext(6, "companion: landed")

    monkeypatch.setattr(CompanionApp, "run", flight)
    with caplog.at_level(logging.INFO, logger="m4-companion"):
        code, lines = run_cli(capsys, "--fc", "udpout:127.0.0.1:9", *signed)
    said = [r.getMessage() for r in caplog.records]
    assert code == 0 and not lines, lines
    assert said[-1].startswith("stopped after 0 setpoints") and any("No space left on device" in m for m in said)


@pytest.mark.parametrize("setting, key", [
    ("[control]\nrate_hz = 1e-300", "rate_hz"),                   # was an OverflowError on connect
    ("[nmpc]\ndt_s = 1e30", "dt_s"),                               # flew, and flipped the robot
    ("[link]\ntelemetry_timeout_s = 1e-9", "telemetry_timeout_s"),
])
def test_an_extreme_setting_is_refused_at_start_in_one_line_naming_its_key(capsys, tmp_path, monkeypatch, setting,
                                                                           key):
    monkeypatch.setattr(CompanionApp, "run", lambda app: pytest.fail("the companion started flying"))
    config = tmp_path / "companion.toml"
    config.write_text(setting + "\n")
    code, lines = run_cli(capsys, "--fc", "udpin:127.0.0.1:0", "--config", str(config))
    assert code == 2 and len(lines) == 1 and lines[0].startswith("m4-companion: error:") and key in lines[0], lines


def test_a_scenario_given_as_the_mission_is_checked_whole_before_the_companion_starts(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(CompanionApp, "run", lambda app: pytest.fail("the companion started flying"))
    scenario = scenarios.scenario_path("hover-rotor-loss").read_text()
    mission = tmp_path / "mission.toml"
    mission.write_text(scenario.replace("rotor = 4", "rotor = 7"))          # a malformed [[fault]]
    code, lines = run_cli(capsys, "--fc", "udpin:127.0.0.1:0", "--mission", str(mission))
    assert code == 2 and len(lines) == 1 and "[[fault]] #1 rotor must be <= 4" in lines[0], lines


def test_what_was_built_before_the_loop_is_frozen_out_of_the_garbage_collector(monkeypatch, capsys, signed):
    """A full collection walks every object alive: with the NMPC, the dialect and the links built,
    hundreds of milliseconds on this machine, in the middle of some control step."""
    frozen = []                                # from none: tests/conftest.py unfreezes before each test
    monkeypatch.setattr(CompanionApp, "run", lambda self: frozen.append(gc.get_freeze_count()))
    code, _ = run_cli(capsys, "--fc", "udpin:127.0.0.1:0", *signed)
    assert code == 0 and frozen and frozen[0] > 10_000


def test_a_command_line_builds_the_parser_of_the_subcommand_it_names_alone():
    """Every flight starts `m4-companion run`: the other subcommands' modules (the dashboard's loads
    pymavlink's tlog reader and its dialects) stay out of its start."""
    code = ("import sys; from companion.cli import main\ntry:\n    main(['run', '--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('companion.dashboard.command', 'companion.watch', 'pymavlink.mavutil') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "--ready-fd" in out and out.splitlines()[-1] == "[]"
