"""benchmarks.frame_read: a recorded flight's telemetry datagrams read as the companion reads them."""

from __future__ import annotations

import math

from benchmarks.frame_read import main, telemetry_datagrams
from m4.airframe import load_airframe
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink, new_mav
from m4.mavlink.signing import setup_signing, write_new_key
from m4.mavlink.tlog import TlogWriter

AF = load_airframe()


def _frame(t_ms: int) -> list:
    hip, thrust = [AF.nominal_hip_rad] * 4, [AF.hover_thrust_per_rotor_n] * 4
    return [mavlink.MAVLink_attitude_message(t_ms, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0),
            mavlink.MAVLink_local_position_ned_message(t_ms, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0),
            mavlink.MAVLink_m4_joint_state_message(t_ms, hip, [0.0] * 4),
            mavlink.MAVLink_m4_thruster_status_message(t_ms, thrust, [math.nan] * 4)]


def _flight(directory, frames: int) -> None:
    """A signed flight's tlog: a telemetry frame, the companion's heartbeat, and so on."""
    key = write_new_key(directory / "mavlink.key")
    fc, companion = new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID), new_mav(None, FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    setup_signing(fc, key)
    setup_signing(companion, key)
    answer = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, 0, 0, 0, 0, 3)
    with TlogWriter(directory / "flight.tlog") as tlog:
        for k in range(frames):
            for msg in _frame(20 * k):
                tlog.record(msg.pack(fc))
            tlog.record(answer.pack(companion))


def test_each_run_of_the_fcs_packets_is_a_datagram_read_warm_and_cold(tmp_path, capsys):
    _flight(tmp_path, 30)
    assert [len(packets) for packets in telemetry_datagrams(tmp_path / "flight.tlog")] == [4] * 30
    assert main([str(tmp_path), "--repeat", "1"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("30 telemetry datagrams (signed), median 4 packets each")
    assert [line.split(":")[0].strip() for line in out[1:]] == ["warm", "cold"]
    assert all("read" in line and "snapshot and ROM state" in line for line in out[1:])


def test_a_directory_without_a_flight_is_named(tmp_path, capsys):
    assert main([str(tmp_path)]) == 2
    assert "flight.tlog: no such file" in capsys.readouterr().err


def test_a_tlog_cut_short_is_read_up_to_its_last_whole_packet(tmp_path):
    _flight(tmp_path, 3)
    tlog = tmp_path / "flight.tlog"
    tlog.write_bytes(tlog.read_bytes()[:-20])          # the last heartbeat cut: its frame's run never ends
    assert [len(packets) for packets in telemetry_datagrams(tlog)] == [4, 4]
