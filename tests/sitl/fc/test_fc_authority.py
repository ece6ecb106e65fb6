"""The simulated FC flies its paired companion's setpoints only (issue 10): setpoints from anyone
else are refused and counted, while commands are a ground station's to give too (issue 22,
tests/sitl/fc/test_fc_ground_stations.py); setpoints are judged by the instant they answer; with signing, replies go to the signed peer only and a replay across a restart fails;
a second sender using the companion's ids is reported (issue 20). All over real loopback sockets."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from m4.mavlink import mavlink
from m4.mavlink.link import UdpLink
from m4.scenario import Scenario
from sitl.serve import ServeOptions, Server
from sitl.standin_companion import StandInCompanion, served
from tests.support.packets import packed

m = mavlink
KEY = bytes(range(7, 39))
HOVER = Scenario(name="hover", duration_s=60.0)



def _packet(msg, system=1, component=191, key=None) -> bytes:
    """`msg` packed as `system/component` would send it (signed with `key`)."""
    return packed([msg], system, component, key)[0]


def _setpoint(t_ms, period_ms=20, thrust=14.7):
    return m.MAVLink_m4_setpoint_message(1, 1, t_ms, period_ms, [thrust] * 4, [0.78] * 4, [0.0] * 4, 0)


def _command(command, *params):
    p = [float(x) for x in params] + [0.0] * (7 - len(params))
    return m.MAVLink_command_long_message(1, 1, command, 0, *p)


def _send_to_fc(server, packet: bytes) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(packet, ("127.0.0.1", server.links[0].local_port))


def _now_ms(companion) -> int:
    return companion.of_type("ATTITUDE")[-1].time_boot_ms


def _realtime(companion):
    return served(companion, ServeOptions(scenario=HOVER, realtime=True))


def test_setpoints_and_fault_status_from_another_system_are_refused_and_counted():
    companion = StandInCompanion()
    with _realtime(companion) as server:
        companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms >= 200)
        fc = server.vehicle.fc
        _send_to_fc(server, _packet(_setpoint(_now_ms(companion), period_ms=65535, thrust=0.0), system=99))
        _send_to_fc(server, _packet(_setpoint(_now_ms(companion), thrust=0.0), system=42, component=190))
        _send_to_fc(server, _packet(m.MAVLink_m4_fault_status_message(
            0, 4, [0.0] * 4, 0, m.M4_FAULT_STATE_CONFIRMED, 0, 0, 0, 0, [0.0] * 3, 0, [0.0] * 3), system=99))
        t_ms = _now_ms(companion)
        assert companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms >= t_ms + 200, 3.0)
        assert fc.counters.refused_foreign == 3
        assert fc.counters.setpoints_dropped == 0 and fc.fault_status is None
    last = companion.of_type("M4_THRUSTER_STATUS")[-1]
    assert min(last.thrust_cmd_n) > 10.0                  # no rotor stopped, the companion still flies


@pytest.mark.parametrize("shift_ms, period_ms, reason", [
    (-400, 20, "too old"), (+5000, 20, "future"), (0, 0, "period"), (0, 1001, "period"), (-60, 20, None),
])
def test_setpoints_are_judged_by_the_instant_they_answer(shift_ms, period_ms, reason):
    companion = StandInCompanion(until_ms=300)             # then silent: only ours arrive
    with _realtime(companion) as server:
        companion.wait_for("ATTITUDE", lambda a: a.time_boot_ms >= 400)
        fc = server.vehicle.fc
        before, dropped_before = fc.counters.setpoints_accepted, fc.counters.dropped_by_reason.copy()
        companion.send(_setpoint(_now_ms(companion) + shift_ms, period_ms))
        time.sleep(0.1)
        accepted = fc.counters.setpoints_accepted - before
        dropped = dict(fc.counters.dropped_by_reason - dropped_before)
    assert (accepted, dropped) == ((1, {}) if reason is None else (0, {reason: 1}))


def _udpin_server(**options):
    server = Server(ServeOptions(scenario=HOVER, realtime=True, mavlink_urls=("udpin:127.0.0.1:0",), **options))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    return server, thread


def _stop(server, thread):
    server.stop()
    thread.join()
    server.close()


def _count_received(sock: socket.socket, seconds: float) -> int:
    sock.settimeout(0.05)
    n, end = 0, time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            sock.recv(65535)
            n += 1
        except TimeoutError:
            pass
    return n


def test_with_signing_an_unsigned_heartbeat_does_not_redirect_the_telemetry():
    server, thread = _udpin_server(signing_key=KEY)
    port = server.links[0].local_port
    companion = UdpLink(f"udpout:127.0.0.1:{port}", 1, 191, key=KEY)
    heartbeat = m.MAVLink_heartbeat_message(m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
    try:
        companion.send(heartbeat)
        time.sleep(0.2)
        assert len(companion.receive()) > 10              # the FC answers the signed companion
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as forger:
            forger.bind(("127.0.0.1", 0))
            forger.sendto(_packet(heartbeat), ("127.0.0.1", port))      # ids of the companion, unsigned
            stolen = _count_received(forger, 0.3)
        assert stolen == 0
        assert len(companion.receive()) > 10              # and still the companion
    finally:
        companion.close()
        _stop(server, thread)


def _lockstep_fc(tmp_path, **options):
    """A lockstep FC waiting at t = 0 for a setpoint; signing with KEY."""
    server = Server(ServeOptions(scenario=HOVER, signing_key=KEY, mavlink_urls=("udpout:127.0.0.1:9",),
                                 lockstep_timeout_s=30.0, duration_s=0.1, **options))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    return server, thread


def _wait(predicate, timeout_s=3.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.01)
    return predicate()


@pytest.mark.parametrize("persisted", [True, False])
def test_a_captured_signed_setpoint_replayed_into_a_restarted_fc_is_refused(tmp_path, persisted):
    options = {"signing_state_path": tmp_path / "fc.timestamps"} if persisted else {}
    captured = _packet(_setpoint(0), key=KEY)
    first, thread = _lockstep_fc(tmp_path, **options)
    _send_to_fc(first, captured)
    assert _wait(lambda: first.vehicle.fc.counters.setpoints_accepted == 1)
    _stop(first, thread)

    restarted, thread = _lockstep_fc(tmp_path, **options)
    _send_to_fc(restarted, captured)
    refused = _wait(lambda: restarted.links[0].signing_counters().bad_signature == 1, 1.0)
    accepted = restarted.vehicle.fc.counters.setpoints_accepted
    _stop(restarted, thread)
    if persisted:
        assert refused and accepted == 0
    else:                  # what the persisted timestamps prevent: pymavlink alone takes the replay
        assert not refused and accepted == 1


# -- the probes of issue 20: a second sender using the companion's ids, from another UDP port --------
FORCE_DISARM = (m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)


def _second_sender_texts(companion) -> list[str]:
    return [s.text for s in companion.of_type("STATUSTEXT")
            if s.severity == m.MAV_SEVERITY_WARNING and "second sender" in s.text]


def _in_flight(key=None):
    companion = StandInCompanion(key=key)
    return companion, served(companion, ServeOptions(scenario=HOVER, realtime=True, signing_key=key))


@pytest.mark.parametrize("attack", ["force disarm", "zero thrust"])
def test_with_signing_a_spoofed_disarm_or_zero_thrust_from_another_port_is_refused_and_reported(attack):
    """Before signing by default: one unsigned force-disarm (or zero-thrust setpoint) claiming
    1/191 from any port grounded the robot in flight, and the FC said nothing of it."""
    companion, serving = _in_flight(KEY)
    with serving as server:
        companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms >= 300)
        forged = _command(*FORCE_DISARM) if attack == "force disarm" else _setpoint(_now_ms(companion), thrust=0.0)
        for _ in range(3):
            _send_to_fc(server, _packet(forged))                      # ids of the companion, unsigned
        assert _wait(lambda: _second_sender_texts(companion), 3.0)
        t_ms = _now_ms(companion)
        companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms >= t_ms + 200, 3.0)
        fc = server.vehicle.fc
        assert fc.armed and fc.second_sender.count == 3
    assert _second_sender_texts(companion) == ["FC: second sender as 1/191 (unsigned)"]     # once: rate-limited
    assert min(companion.of_type("M4_THRUSTER_STATUS")[-1].thrust_cmd_n) > 10.0


def test_with_signing_a_captured_signed_command_replayed_from_another_port_is_refused_and_reported():
    companion, serving = _in_flight(KEY)
    with serving as server:
        companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms >= 300)
        captured = _packet(_command(m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_AUTOPILOT_VERSION), key=KEY)
        before = server.links[0].signing_counters().bad_signature
        _send_to_fc(server, captured)                                 # taken once (the first time) ...
        _send_to_fc(server, captured)                                 # ... and then replayed
        assert _wait(lambda: _second_sender_texts(companion), 3.0)
        assert _wait(lambda: server.links[0].signing_counters().bad_signature == before + 1, 3.0)
    # One report (rate-limited): the replay's, or the first copy's when the FC heard it from
    # another address while the companion's was live (seen on a loaded machine).
    assert _second_sender_texts(companion) in (["FC: second sender as 1/191 (replayed)"],
                                               ["FC: second sender as 1/191 (other address)"])


def test_unsigned_by_choice_a_second_sender_is_still_obeyed_but_no_longer_silently():
    """What signing by default prevents: without a key the force-disarm grounds the robot."""
    companion, serving = _in_flight()
    with serving as server:
        companion.wait_for("M4_THRUSTER_STATUS", lambda s: s.time_boot_ms >= 300)
        _send_to_fc(server, _packet(_command(*FORCE_DISARM)))
        assert _wait(lambda: _second_sender_texts(companion), 3.0)
        fc = server.vehicle.fc
        assert not fc.armed and fc.second_sender.count == 1
    assert _second_sender_texts(companion) == ["FC: second sender as 1/191 (other address)"]
