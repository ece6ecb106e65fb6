"""A scripted flight controller on a real loopback UDP socket: it sends the companion
heartbeats and telemetry frames (as the SITL's FC does) and reads what comes back. Like a real
FC it reports as commanded the thrusts of the last setpoint it read (hover before any), and
answers every command it reads (support.fc_answers: `kept`, its kept M4_FAULT_STATUS;
`standard_mode`, its mode)."""

from __future__ import annotations

import time

from m4.airframe import Airframe
from m4.mavlink import FC_COMPONENT_ID, FC_SYSTEM_ID, mavlink
from m4.mavlink.link import UdpLink
from support.fc_answers import answers


class LoopbackFc:
    def __init__(self, companion_port: int, af: Airframe, key: bytes | None = None):
        self.af = af
        self.link = UdpLink(f"udpout:127.0.0.1:{companion_port}", FC_SYSTEM_ID, FC_COMPONENT_ID, key=key)
        self.commanded_n = [af.hover_thrust_per_rotor_n] * 4
        self.kept: mavlink.MAVLink_m4_fault_status_message | None = None
        self.standard_mode = mavlink.MAV_STANDARD_MODE_POSITION_HOLD

    @property
    def port(self) -> int:
        return self.link.local_port

    def heartbeat(self) -> None:
        self.link.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                         0, 0, mavlink.MAV_STATE_ACTIVE, 3))

    def frame(self, t_ms: int, roll_rad: float = 0.0, z_ned_m: float = -2.0) -> None:
        """One telemetry frame at FC instant t_ms: a hover (rolled by roll_rad) at z_ned_m."""
        af = self.af
        self.link.send_all([
            mavlink.MAVLink_attitude_message(t_ms, roll_rad, 0.0, 0.0, 0.0, 0.0, 0.0),
            mavlink.MAVLink_local_position_ned_message(t_ms, 0.0, 0.0, z_ned_m, 0.0, 0.0, 0.0),
            mavlink.MAVLink_m4_joint_state_message(t_ms, [af.nominal_hip_rad] * 4, [0.0] * 4),
            mavlink.MAVLink_m4_thruster_status_message(t_ms, self.commanded_n, [af.thrust_max_n] * 4)])

    def join(self, app, timeout_s: float = 1.0) -> list[mavlink.MAVLink_message]:
        """HEARTBEAT, then `app` polled until it has had the answers to what it asks the FC it
        finds (as the SITL's FC answers within a millisecond); what it sent meanwhile."""
        self.heartbeat()
        got, deadline = [], time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            time.sleep(0.002)
            app.poll()
            got += self.received()
            if app.fc.locked and not app.fc.kept_state_pending():
                break
        return got

    def received(self) -> list[mavlink.MAVLink_message]:
        msgs = self.link.receive()
        for m in msgs:
            if m.get_type() == "M4_SETPOINT":
                self.commanded_n = list(m.thrust_n)
            replies = answers(m, self.kept, self.standard_mode)
            if replies:
                self.link.send_all(replies)
        return msgs

    def close(self) -> None:
        self.link.close()
