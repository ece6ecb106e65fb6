"""The companion knows which autopilot it talks to: ArduPilot's HEARTBEAT (autopilot
ARDUPILOTMEGA) makes it read the M4 applet's telemetry frame, ask only for the streams
ArduPilot has and stop ArduPilot's own attitude and position streams; the project's FC
(autopilot GENERIC) changes nothing."""

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
    link = FakeTransport(FC_SYSTEM_ID, COMPANION_COMPONENT_ID)
    clock = [100.0]
    app = CompanionApp(CONFIG, FcLink(link), Controller(ControllerSettings.of(CONFIG)), clock=lambda: clock[0])
    parser = new_mav(None, 255, 0)
    read = 0

    def fc_sends(msgs) -> None:
        nonlocal read
        mav = new_mav(None, FC_SYSTEM_ID, FC_COMPONENT_ID)
        link.inbox.extend((msg.pack(mav), FC_ADDRESS) for msg in msgs)
        app.poll()
        sent = [m for packet in link.sent[read:] for m in parser.parse_buffer(packet) or ()]
        read = len(link.sent)
        link.inbox.extend((reply.pack(mav), FC_ADDRESS) for m in sent for reply in answers(m))

    fc_sends([heartbeat(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)])
    for _ in range(12):                            # the commands, one at a time, each answered
        fc_sends([])
    hover = [AF.hover_thrust_per_rotor_n] * 4
    for k in range(5):
        fc_sends(applet_frame(1000 + 20 * k, [AF.nominal_hip_rad] * 4, [0.0] * 4, hover, [AF.thrust_max_n] * 4))
        clock[0] += 0.02
    sent = link.sent_messages()
    intervals = {(int(m.param1), m.param2) for m in sent if m.get_type() == "COMMAND_LONG"
                 and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL}
    assert app.profile is ARDUPILOT
    assert intervals == {(mavlink.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4, 20000.0), (mavlink.MAVLINK_MSG_ID_ATTITUDE, -1.0),
                         (mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, -1.0), (mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, -1.0)}
    assert [m.time_boot_ms for m in sent if m.get_type() == "M4_SETPOINT"] == [1000, 1020, 1040, 1060, 1080]
    link.close()
