"""Which autopilot the flight controller runs, and what that changes for the companion.

The FC's HEARTBEAT names its autopilot. MAV_AUTOPILOT_ARDUPILOTMEGA is stock ArduPilot with
the M4 applet (deploy/ardupilot/scripts/m4_fc.lua, docs/ardupilot.md); anything else is the
project's FC (MAV_AUTOPILOT_GENERIC).

The project's FC streams at its defaults (sitl/fc/streams.py) on every link; the companion asks
on its own link for what it reads, at the control rate: ATTITUDE, LOCAL_POSITION_NED,
M4_JOINT_STATE, M4_THRUSTER_STATUS and ESC_TELEMETRY_1_TO_4 (companion.telemetry.REQUESTED), and
stops ATTITUDE_QUATERNION (the same attitude: ATTITUDE is read first at a shared instant),
GLOBAL_POSITION_INT and ACTUATOR_OUTPUT_STATUS (never read). A ground station on its own link
keeps the defaults. A profile's stops go out after its streams' requests, at lock-on, at the
profile's change and when telemetry comes back. When the attitude goes stale both attitude
messages are asked for again (companion.stream_watch; the profile's `spare`), so an FC that
sends only ATTITUDE_QUATERNION has it back five periods after lock-on stopped it, and flies.

ArduPilot cannot send the M4 dialect (a script sends only messages compiled into the
firmware). The applet sends its telemetry frame as ATTITUDE, LOCAL_POSITION_NED and
DEBUG_FLOAT_ARRAY "M4FC", all stamped with one instant; `translate` turns the last into the
M4_JOINT_STATE and M4_THRUSTER_STATUS the companion reads, in that order (the thruster status
ends a frame). Its data, by index: hip angles 0..3 (rad: what the applet commands, followed at
the servos' rate limit: ArduPilot has no hip feedback), hip rates 4..7 (rad/s), thrusts
commanded 8..11 (N: the motors' outputs through the thrust model), thrust limits 12..15 (N).
Streams asked for: ESC_TELEMETRY_1_TO_4 alone (ArduPilot sends it with bidirectional DShot);
the applet sends the rest at its own rate. ArduPilot's own ATTITUDE, ATTITUDE_QUATERNION and
LOCAL_POSITION_NED on the companion's port are stopped: the applet's frames alone say that
telemetry flows (they come only while the applet is engaged), and no sample off the frame's
instant comes between them.
"""

from __future__ import annotations

from dataclasses import dataclass

from m4.airframe import ROTOR_COUNT
from m4.mavlink import mavlink
from companion.telemetry import ATTITUDE, ATTITUDE_QUATERNION, ESC_TELEMETRY, LOCAL_POSITION, REQUESTED

APPLET_FRAME_NAME = "M4FC"
_HIP, _HIP_RATE, _THRUST_CMD, _THRUST_LIMIT = (slice(i * ROTOR_COUNT, (i + 1) * ROTOR_COUNT) for i in range(4))


@dataclass(frozen=True)
class AutopilotProfile:
    name: str
    streams: tuple[int, ...]          # the message ids whose intervals the companion asks for
    stopped: tuple[int, ...]          # the message ids the FC is asked not to stream (at lock-on too)
    spare: tuple[int, ...]            # asked for as well when what they carry goes stale
    applet_frames: bool               # telemetry frames come as the ArduPilot applet's

    def asked_again(self, stale_ids: tuple[int, ...]) -> list[int]:
        """Of the messages companion.stream_watch asks for again, those this FC is asked for."""
        return [i for i in stale_ids if i in self.streams or i in self.spare]

    def translate(self, messages: list) -> list:
        """The FC's messages as the companion reads them (the applet's frame in the M4 dialect)."""
        if not self.applet_frames:
            return messages
        out = []
        for msg in messages:
            if msg.get_msgId() == mavlink.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY and msg.name == APPLET_FRAME_NAME:
                out.extend(_m4_frame(msg))
            else:
                out.append(msg)
        return out


PROJECT_FC = AutopilotProfile("the project's flight controller", REQUESTED,
                              (ATTITUDE_QUATERNION, mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                               mavlink.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS), (ATTITUDE_QUATERNION,),
                              applet_frames=False)
ARDUPILOT = AutopilotProfile("ArduPilot with the M4 applet", (ESC_TELEMETRY,),
                             (ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION), (), applet_frames=True)


def profile_of(heartbeat) -> AutopilotProfile:
    """The profile for the autopilot a HEARTBEAT of the FC names."""
    return ARDUPILOT if heartbeat.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA else PROJECT_FC


def _m4_frame(msg) -> list:
    time_ms = int(msg.time_usec // 1000)
    data = [float(x) for x in msg.data]
    return [mavlink.MAVLink_m4_joint_state_message(time_ms, data[_HIP], data[_HIP_RATE]),
            mavlink.MAVLink_m4_thruster_status_message(time_ms, data[_THRUST_CMD], data[_THRUST_LIMIT])]
