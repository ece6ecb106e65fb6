"""The companion's flight log: every packet both ways and its decisions, one tlog per flight,
rotated by size, the folder kept under its cap; an unwritable folder does not stop a flight, a
full disk pauses the log until space returns."""

from __future__ import annotations

import logging
import os
import re
import threading
import time
from types import SimpleNamespace

import numpy as np

from companion import flight_log as flight_log_module
from companion.config import LogSettings, parse_config
from companion.flight_log import FlightLog, open_flight_log
from m4.mavlink import COMPANION_COMPONENT_ID, mavlink, mavutil, new_mav
from support.full_disk import FullDisk
from support.packets import packed


class _Packets:
    def __init__(self):
        self.packets = []

    def write(self, packet):
        self.packets.append(bytes(packet))


def _packets_of(*msgs, component=1):
    out = _Packets()
    mav = new_mav(out, 1, component)
    for msg in msgs:
        mav.send(msg)
    return out.packets


def _heartbeat(armed: bool):
    base = mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0
    msg = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC, base, 0, 4, 3)
    packet = _packets_of(msg)[0]
    return new_mav(None, 1, 191).parse_char(packet), packet


def _read(path):
    conn = mavutil.mavlink_connection(str(path), dialect="m4")
    out = []
    while (msg := conn.recv_match()) is not None:
        out.append(msg)
    conn.close()
    return out


def _step(nmpc=True):
    reference = np.zeros((6, 20))
    reference[0, :3] = (0.0, 0.0, -2.0)
    result = SimpleNamespace(solve_ms=1.25, iterations=3, cost=0.5, ok=True, fallback=False,
                             altitude_first=False) if nmpc else None
    return SimpleNamespace(state=np.array([0.1, 0.2, -1.9] + [0.0] * 17), reference=reference, nmpc=result,
                           disturbance=np.array([-3.5, 1.25, 0.5, 0.0, 0.0, 0.0]))


def _poll(flight_log, packets, msgs, fc_rebooted=False):
    """As the control loop does: the packets of a poll recorded as the link reads them, then observed."""
    since = flight_log.position()
    for packet in packets:
        flight_log.record(packet)
    flight_log.observe(msgs, since, fc_rebooted)


def _sent(flight_log, packet):
    """A packet recorded as the link sends it, then packed as the loop does at the end of its poll."""
    flight_log.record(packet)
    flight_log.pack()


def _frame_packet(t_ms):
    return _packets_of(mavlink.MAVLink_attitude_message(t_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))[0]


def test_a_rebooted_fc_starts_a_new_flight_with_the_first_packet_of_its_new_run(tmp_path):
    """A companion kept running while the FC powers off and on again (three flights of m4-sitl
    serve): one file a flight, each with its own clock from its first packet."""
    flight_log = FlightLog(LogSettings(dir=tmp_path)).start()
    armed, armed_packet = _heartbeat(True)
    for run in range(3):
        _poll(flight_log, [armed_packet, _frame_packet(0)], [armed], fc_rebooted=run > 0)
        for k in range(1, 5):
            _poll(flight_log, [_frame_packet(20 * k)], [])
            time.sleep(0.02 * (run == 1))             # the writer drains between polls, or not
    flight_log.close()
    assert len(flight_log.files) == 3
    for path in flight_log.files:
        msgs = _read(path)
        assert msgs[0].get_type() == "HEARTBEAT"
        assert [m.time_boot_ms for m in msgs if m.get_type() == "ATTITUDE"] == [0, 20, 40, 60, 80]


def test_packets_and_decisions_land_in_one_tlog_per_flight(tmp_path):
    flight_log = FlightLog(LogSettings(dir=tmp_path)).start()
    armed, armed_packet = _heartbeat(True)
    disarmed, disarmed_packet = _heartbeat(False)
    setpoint = _packets_of(mavlink.MAVLink_m4_setpoint_message(1, 1, 20, 20, [14.7] * 4, [0.78] * 4, [0.0] * 4, 0),
                           component=COMPANION_COMPONENT_ID)[0]
    for packet, msgs in ((armed_packet, [armed]), (setpoint, []), (disarmed_packet, [disarmed])):
        _poll(flight_log, [packet], msgs)
    flight_log.decision(20, _step(), latency_s=0.0021)
    _poll(flight_log, [armed_packet], [armed])      # armed again: a second flight, from this packet on
    flight_log.decision(40, _step(nmpc=False), latency_s=0.001)
    flight_log.close()

    assert len(flight_log.files) == 2 and sorted(tmp_path.glob("flight-*.tlog")) == sorted(flight_log.files)
    first, second = (_read(p) for p in flight_log.files)
    assert [m.get_type() for m in first[:3]] == ["HEARTBEAT", "M4_SETPOINT", "HEARTBEAT"]
    decided = {m.name: m.value for m in first if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert decided["nmpc_ms"] == 1.25 and decided["nmpc_iter"] == 3 and decided["nmpc_ok"] == 1.0
    assert decided["alt_first"] == 0.0                   # the plan kept its place
    assert abs(decided["step_ms"] - 2.1) < 1e-4 and abs(decided["com_d"] + 1.9) < 1e-6 and decided["ref_d"] == -2.0
    assert [decided[f"dist_{axis}"] for axis in "ned"] == [-3.5, 1.25, 0.5]      # the force it planned with
    assert {m.time_boot_ms for m in first if m.get_type() == "NAMED_VALUE_FLOAT"} == {20}
    assert all(m.get_srcComponent() == COMPANION_COMPONENT_ID for m in first if m.get_type() == "NAMED_VALUE_FLOAT")
    assert second[0].get_type() == "HEARTBEAT"
    assert "nmpc_ms" not in {m.name for m in second if m.get_type() == "NAMED_VALUE_FLOAT"}    # no solve ran


class _StampsBy:
    """The tlog stamp's struct, saying which threads packed with it."""

    def __init__(self, struct):
        self._struct, self.threads = struct, set()

    def pack(self, *values):
        self.threads.add(threading.current_thread().name)
        return self._struct.pack(*values)


def test_the_records_are_made_by_the_loop_after_its_send_and_the_writer_only_writes_them(tmp_path, monkeypatch,
                                                                                         wait_until):
    """The loop's compiled calls give the interpreter's lock up, and a writer that made its batch's
    records held it there for 1-2 ms, in the middle of an answer: the loop makes them (pack, at
    the end of its poll) and wakes the writer thread, which only writes."""
    stamps = _StampsBy(flight_log_module.TLOG_TIME)
    monkeypatch.setattr(flight_log_module, "TLOG_TIME", stamps)
    flight_log = FlightLog(LogSettings(dir=tmp_path)).start()
    for k in range(5):
        _poll(flight_log, [_frame_packet(20 * k)], [])
        flight_log.decision(20 * k, _step(), latency_s=0.001)
        flight_log.pack()
    assert wait_until(lambda: flight_log.records == 5 * (1 + 16))      # written before the close
    flight_log.close()
    assert stamps.threads == {threading.current_thread().name}
    assert [m.time_boot_ms for m in _read(flight_log.files[0]) if m.get_type() == "ATTITUDE"] == [0, 20, 40, 60, 80]


def test_the_loops_pack_wakes_the_writer_as_the_loop_goes_to_wait_not_a_timer_of_its_own(tmp_path, monkeypatch,
                                                                                        wait_until):
    """A writer on a timer of its own woke in the middle of answers (in real time 11 of 400),
    each delayed by its taking the interpreter's lock."""
    monkeypatch.setattr(flight_log_module, "FLUSH_S", 60.0)
    monkeypatch.setattr(flight_log_module, "IDLE_FLUSH_S", 60.0)
    flight_log = FlightLog(LogSettings(dir=tmp_path)).start()
    _sent(flight_log, _frame_packet(0))
    assert wait_until(lambda: flight_log.records == 1)
    _sent(flight_log, _frame_packet(20))                 # within FLUSH_S of the last wake: written later
    time.sleep(0.1)
    assert flight_log.records == 1
    flight_log.close()
    assert [m.time_boot_ms for m in _read(flight_log.files[0])] == [0, 20]


def test_a_datagram_sent_through_a_link_is_logged_at_one_time(tmp_path):
    """The link hands a datagram's packets over together (TlogWriter.record_all's interface)."""
    import socket

    from m4.mavlink.link import UdpLink

    flight_log = FlightLog(LogSettings(dir=tmp_path)).start()
    clock = iter(range(10**9, 2 * 10**9, 10**6))          # a clock that moves 1 ms at every read
    flight_log._clock_ns = lambda: next(clock)
    armed, armed_packet = _heartbeat(True)
    _poll(flight_log, [armed_packet], [armed])
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        link = UdpLink(f"udpout:127.0.0.1:{rx.getsockname()[1]}", 1, COMPANION_COMPONENT_ID, tlog=flight_log)
        link.send_all([mavlink.MAVLink_m4_setpoint_message(1, 1, t, 20, [14.7] * 4, [0.78] * 4, [0.0] * 4, 0)
                       for t in (20, 40)])
        link.close()
    flight_log.close()
    setpoints = [m for m in _read(flight_log.files[0]) if m.get_type() == "M4_SETPOINT"]
    assert [m.time_boot_ms for m in setpoints] == [20, 40]
    assert setpoints[0]._timestamp == setpoints[1]._timestamp


def test_a_long_flight_goes_on_in_new_files_and_the_folder_stays_under_its_cap(tmp_path):
    old = [tmp_path / f"flight-2020010{i}-000000.tlog" for i in range(1, 4)]
    for i, path in enumerate(old):
        path.write_bytes(b"\0" * 4000)
        os.utime(path, (1e9 + i, 1e9 + i))
    flight_log = FlightLog(LogSettings(dir=tmp_path, max_file_mb=0.002, max_total_mb=0.009)).start()
    packet = _packets_of(mavlink.MAVLink_m4_setpoint_message(1, 1, 20, 20, [14.7] * 4, [0.78] * 4, [0.0] * 4, 0))[0]
    for _ in range(200):                              # about 15 kB
        flight_log.record(packet)
    flight_log.close()
    assert len(flight_log.files) >= 7
    left = sorted(tmp_path.glob("flight-*.tlog"))
    assert sum(p.stat().st_size for p in left) <= 9000
    assert not any(p.exists() for p in old)           # the oldest went first
    assert flight_log.files[-1].exists()
    assert sum(len(_read(p)) for p in left) > 0


def test_an_unwritable_folder_is_said_and_the_flight_goes_on(tmp_path, caplog):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    with caplog.at_level(logging.ERROR, logger="m4-companion"):
        flight_log = open_flight_log(LogSettings(dir=blocker / "logs"))
    assert not flight_log.enabled
    flight_log.record(b"\xfd")
    flight_log.close()
    assert "flight log off: cannot write" in caplog.text and "[log] dir" in caplog.text


def test_the_log_table_is_read_and_checked(tmp_path):
    config = parse_config({"log": {"dir": "logs", "max_file_mb": 10, "max_total_mb": 100}}, "c.toml", tmp_path)
    assert config.log == LogSettings(enabled=True, dir=tmp_path / "logs", max_file_mb=10.0, max_total_mb=100.0)
    assert parse_config({}, "defaults").log.dir.name      # a default folder ($M4_LOG_DIR in the tests)
    assert not parse_config({"log": {"enabled": False}}, "c.toml").log.enabled


def test_a_value_beyond_float32_is_logged_as_infinity_and_the_log_goes_on(tmp_path):
    flight_log = FlightLog(LogSettings(dir=tmp_path)).start()
    step = _step()
    step.nmpc.cost = 1e40                             # a diverging solve
    flight_log.decision(20, step, latency_s=0.001)
    flight_log.decision(40, _step(), latency_s=0.001)
    flight_log.close()
    costs = [(m.time_boot_ms, m.value) for m in _read(flight_log.files[0]) if m.get_type() == "NAMED_VALUE_FLOAT"
             and m.name == "nmpc_cost"]
    assert costs == [(20, float("inf")), (40, 0.5)]


def _text(text: str) -> bytes:
    return packed([mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, text.encode())])[0]


def _texts(path) -> list[str]:
    return [m.text for m in _read(path) if m.get_type() == "STATUSTEXT"]


def test_a_full_disk_pauses_the_log_which_goes_on_in_a_new_file_when_space_returns(tmp_path, monkeypatch, caplog,
                                                                                    wait_until):
    disk = FullDisk(tmp_path, monkeypatch)
    monkeypatch.setattr(flight_log_module, "RETRY_S", 0.1)
    flight_log = FlightLog(LogSettings(dir=tmp_path)).start()
    with caplog.at_level(logging.WARNING, logger="m4-companion"):
        _sent(flight_log, _text("before"))
        assert wait_until(lambda: flight_log.records == 1)
        disk.full = True
        assert wait_until(lambda: _sent(flight_log, _text("during")) or flight_log.paused)
        for _ in range(10):                                 # several tries at a new file fail meanwhile
            _sent(flight_log, _text("during"))
            time.sleep(0.05)
        assert flight_log.paused
        assert wait_until(lambda: not flight_log._packed)   # the writer dropped them (a loaded machine runs it late)
        disk.full = False
        assert wait_until(lambda: _sent(flight_log, _text("after")) or not flight_log.paused)
        flight_log.close()
    assert len(flight_log.files) == 2 and sorted(tmp_path.glob("flight-*.tlog")) == sorted(flight_log.files)
    assert _texts(flight_log.files[0]) == ["before"]
    assert "after" in _texts(flight_log.files[1]) and "during" not in _texts(flight_log.files[1])
    assert flight_log.gaps == 1 and len(flight_log.notices) == 2
    assert flight_log.notices[0] == "companion: log paused: No space left on device"
    assert re.fullmatch(r"companion: log resumed after a \d+\.\d s gap", flight_log.notices[1])
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 2 and said[0].startswith("flight log paused") and said[1].startswith("flight log resumed")


def test_a_disk_full_at_the_end_of_a_flight_is_said_and_closing_the_log_does_not_raise(tmp_path, monkeypatch,
                                                                                       caplog, wait_until):
    disk = FullDisk(tmp_path, monkeypatch)
    flight_log = FlightLog(LogSettings(dir=tmp_path)).start()
    _sent(flight_log, _text("before"))
    assert wait_until(lambda: flight_log.records == 1)
    disk.full = True
    _sent(flight_log, _text("last"))
    with caplog.at_level(logging.WARNING, logger="m4-companion"):
        flight_log.close()
    assert "No space left on device" in caplog.text and _texts(flight_log.files[0]) == ["before"]
