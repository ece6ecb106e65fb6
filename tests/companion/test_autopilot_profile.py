"""The companion knows which autopilot it talks to: ArduPilot's HEARTBEAT (autopilot
ARDUPILOTMEGA) makes it read the M4 applet's telemetry frame, ask only for the streams
ArduPilot has and stop ArduPilot's own attitude and position streams; the project's FC
(autopilot GENERIC) is asked for what the companion reads and to stop the rest, at lock-on."""

from __future__ import annotations

import numpy as np

from m4.airframe import load_airframe
from companion.app import CompanionApp
from companion.autopilot_profile import ARDUPILOT, PROJECT_FC, profile_of
from companion.config import parse_config
from companion.controller import Controller, ControllerSettings
from companion.fc_link import FcLink
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink, new_mav
from support.fake_transport import FakeTransport
from support.fc_answers import answers

AF = load_airframe()
CONFIG = parse_config({"control": {"rate_hz": 50.0}, "link": {"fc_url": "udpin:127.0.0.1:0"}}, "test")
FC_ADDRESS = ("127.0.0.1", 9)
m = mavlink
ATT, QUAT, LOCAL = m.MAVLINK_MSG_ID_ATTITUDE, m.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, m.MAVLINK_MSG_ID_LOCAL_POSITION_NED
JOINTS, THRUSTERS, ESC = m.MAVLINK_MSG_ID_M4_JOINT_STATE, m.MAVLINK_MSG_ID_M4_THRUSTER_STATUS, \
    m.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4


def heartbeat(autopilot: int) -> mavlink.MAVLink_heartbeat_message:
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, autopilot, 0, 4, 4, 3)


def applet_frame(t_ms: int, hip_rad, hip_rate_rad_s, thrust_cmd_n, thrust_limit_n) -> list:
    """What deploy/ardupilot/scripts/m4_fc.lua sends at one instant."""
    data = [*hip_rad, *hip_rate_rad_s, *thrust_cmd_n, *thrust_limit_n, 1.0]
    return [mavlink.MAVLink_attitude_message(t_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            mavlink.MAVLink_local_position_ned_message(t_ms, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0),
            mavlink.MAVLink_debug_float_array_message(t_ms * 1000, b"M4FC", 1, data + [0.0] * (58 - len(data)))]


def wire(msgs) -> list:
    """The messages as the companion receives them: packed by the FC, parsed again."""
    mav, parser = new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID), new_mav(None, 255, 0)
    return [parsed for msg in msgs for parsed in parser.parse_buffer(msg.pack(mav))]


def test_the_heartbeat_names_the_profile():
    assert profile_of(heartbeat(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)) is ARDUPILOT
    assert profile_of(heartbeat(mavlink.MAV_AUTOPILOT_GENERIC)) is PROJECT_FC


def test_the_applets_frame_reads_as_the_m4_joint_state_and_thruster_status():
    hips, rates, thrusts, limits = [0.1, 0.2, 0.3, 0.4], [1.0, -1.0, 0.5, 0.0], [14.0, 15.0, 16.0, 0.0], [30.0] * 4
    frame = wire(applet_frame(12345, hips, rates, thrusts, limits))
    out = ARDUPILOT.translate(frame)
    assert [m.get_type() for m in out] == ["ATTITUDE", "LOCAL_POSITION_NED", "M4_JOINT_STATE", "M4_THRUSTER_STATUS"]
    joints, thrusters = out[2], out[3]
    assert joints.time_boot_ms == thrusters.time_boot_ms == 12345
    np.testing.assert_allclose(joints.hip_angle_rad, hips, rtol=1e-6)
    np.testing.assert_allclose(joints.hip_rate_rad_s, rates, rtol=1e-6)
    np.testing.assert_allclose(thrusters.thrust_cmd_n, thrusts, rtol=1e-6)
    np.testing.assert_allclose(thrusters.thrust_limit_n, limits, rtol=1e-6)
    assert PROJECT_FC.translate(frame) == frame                 # the project's FC sends no such frame


def test_through_arducopter_the_companion_asks_for_esc_telemetry_alone_and_answers_the_applets_frames():
    fc = ScriptedFc(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    hover = [AF.hover_thrust_per_rotor_n] * 4
    for k in range(5):
        fc.sends(applet_frame(1000 + 20 * k, [AF.nominal_hip_rad] * 4, [0.0] * 4, hover, [AF.thrust_max_n] * 4))
        fc.clock[0] += 0.02
    assert fc.app.profile is ARDUPILOT
    assert set(fc.intervals()) == {(ESC, 20000.0), (ATT, -1.0), (QUAT, -1.0), (LOCAL, -1.0)}
    assert [m.time_boot_ms for m in fc.link.sent_messages() if m.get_type() == "M4_SETPOINT"] == \
        [1000, 1020, 1040, 1060, 1080]
    fc.link.close()


def test_the_project_fc_is_asked_at_lock_on_for_what_the_companion_reads_and_to_stop_the_rest():
    """ATTITUDE (not the quaternion), the position, joints, thrusters and ESC telemetry at the
    control rate, then ATTITUDE_QUATERNION, GLOBAL_POSITION_INT and ACTUATOR_OUTPUT_STATUS
    stopped on the companion's link, each command sent once and acknowledged."""
    fc = ScriptedFc(mavlink.MAV_AUTOPILOT_GENERIC)
    assert fc.app.profile is PROJECT_FC
    assert fc.intervals() == [(ATT, 20000.0), (LOCAL, 20000.0), (JOINTS, 20000.0), (THRUSTERS, 20000.0),
                              (ESC, 20000.0), (QUAT, -1.0), (mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, -1.0),
                              (mavlink.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS, -1.0)]
    health = fc.app.fc.health()
    assert (health.commands_acked, health.commands_pending) == (8 + 2, 0)      # and the two kept-state requests
    fc.link.close()


def test_arducopter_found_again_after_a_restart_has_its_own_streams_stopped_again():
    """A restarted ArduPilot (a new source port after the telemetry was lost) streams its
    defaults again: the lock-on stops them again, though the profile did not change."""
    fc = ScriptedFc(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    fc.sends(applet_frame(1000, [AF.nominal_hip_rad] * 4, [0.0] * 4, [0.0] * 4, [AF.thrust_max_n] * 4))
    before = len(fc.intervals())
    fc.clock[0] += 2.0                             # silence: the telemetry is lost
    fc.sends([])
    fc.address = ("127.0.0.1", 10)
    fc.join()
    assert set(fc.intervals()[before:]) == {(ESC, 20000.0), (ATT, -1.0), (QUAT, -1.0), (LOCAL, -1.0)}
    fc.link.close()


def test_an_fc_that_sends_only_the_quaternion_has_it_back_when_the_attitude_goes_stale_and_is_flown():
    """Lock-on stops ATTITUDE_QUATERNION; an FC that sends no ATTITUDE (and honours the stop)
    leaves the attitude stale: five periods later both attitude messages are asked for, the
    quaternion comes again and every frame from then on is answered."""
    fc = ScriptedFc(mavlink.MAV_AUTOPILOT_GENERIC)
    hover = [AF.hover_thrust_per_rotor_n] * 4
    for k in range(20):
        t_ms = 1000 + 20 * k
        quat = [mavlink.MAVLink_attitude_quaternion_message(t_ms, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, [0.0] * 4)]
        fc.sends((quat if fc.interval_of(QUAT) != -1.0 else []) + [
            mavlink.MAVLink_local_position_ned_message(t_ms, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0),
            mavlink.MAVLink_m4_joint_state_message(t_ms, [AF.nominal_hip_rad] * 4, [0.0] * 4),
            mavlink.MAVLink_m4_thruster_status_message(t_ms, hover, [AF.thrust_max_n] * 4)])
        fc.clock[0] += 0.02
    asked = fc.intervals()
    assert asked.index((QUAT, -1.0)) < asked.index((QUAT, 20000.0)) and asked[-2:] == [(ATT, 20000.0),
                                                                                      (QUAT, 20000.0)]
    answered = [m.time_boot_ms for m in fc.link.sent_messages() if m.get_type() == "M4_SETPOINT"]
    assert answered and answered == list(range(answered[0], 1400, 20)) and answered[0] <= 1200
    fc.link.close()


class ScriptedFc:
    """An FC on a fake link naming its autopilot in its HEARTBEAT and answering every command
    (support.fc_answers); `sends` delivers its messages and polls the companion once."""

    def __init__(self, autopilot: int):
        self.link = FakeTransport(FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
        self.clock = [100.0]
        self.app = CompanionApp(CONFIG, FcLink(self.link), Controller(ControllerSettings.of(CONFIG)),
                                clock=lambda: self.clock[0])
        self.address, self.autopilot = FC_ADDRESS, autopilot
        self._mav, self._parser, self._read = new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID), new_mav(None, 255, 0), 0
        self.join()

    def join(self) -> None:
        self.sends([heartbeat(self.autopilot)])
        for _ in range(12):                        # the commands, one at a time, each answered
            self.sends([])

    def sends(self, msgs) -> None:
        self.link.inbox.extend((msg.pack(self._mav), self.address) for msg in msgs)
        self.app.poll()
        sent = [m for packet in self.link.sent[self._read:] for m in self._parser.parse_buffer(packet) or ()]
        self._read = len(self.link.sent)
        self.link.inbox.extend((reply.pack(self._mav), self.address) for m in sent for reply in answers(m))

    def intervals(self) -> list[tuple[int, float]]:
        """The MAV_CMD_SET_MESSAGE_INTERVAL commands sent so far: (message id, interval in us)."""
        return [(int(m.param1), m.param2) for m in self.link.sent_messages()
                if m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL]

    def interval_of(self, msg_id: int) -> float | None:
        """The last interval asked for message msg_id (None: never)."""
        return next((us for i, us in reversed(self.intervals()) if i == msg_id), None)
