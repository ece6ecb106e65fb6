"""Telemetry of the simulated flight controller: MAVLink messages built from the plant state.

Every builder takes a `Snapshot` (the FC's clock, its view of the plant, its mode) and
returns one message; the stream schedule (sitl/fc/streams.py) decides when. Positions are the
hull centre (the IMU), local NED around a fixed home; GLOBAL_POSITION_INT and HOME_POSITION
place that local frame on the WGS-84 ellipsoid (m4.home).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from m4.airframe import Airframe
from m4.home import Home
from m4.mavlink import mavlink
from sitl.fc import modes
from sitl.fc.esc_telemetry import EscReport
from sitl.plant.state import PlantState

_SENSORS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
            | mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
            | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS)
# parameters as ArduPilot sends them: values cast to float (m4/mavlink/param_service.py)
_CAPABILITIES = (mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                 | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
                 | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT)
FLIGHT_SW_VERSION = 0x000100FF      # major, minor, patch, type: 0.1.0, FIRMWARE_VERSION_TYPE_OFFICIAL


@dataclass(frozen=True)
class Snapshot:
    """What the FC reports at one instant."""
    t_ms: int
    state: PlantState          # as the FC measures it
    custom_mode: int
    armed: bool
    landed: bool
    esc: EscReport | None = None     # what the ESCs reported (None: the FC has no ESC telemetry)
    intended_mode: int = 0           # the mode selected (custom_mode: the one in force; 0: unknown)


def _f4(v) -> list[float]:
    """Python floats (a numpy array's own tolist() is the cheaper way to them)."""
    return v.tolist() if isinstance(v, np.ndarray) else [float(x) for x in v]


class Telemetry:
    def __init__(self, airframe: Airframe, home: Home | None = None, esc_telemetry: bool = False):
        self.airframe = airframe
        self.home = home or Home()
        m = mavlink
        self._builders = {
            m.MAVLINK_MSG_ID_HEARTBEAT: self.heartbeat,
            m.MAVLINK_MSG_ID_CURRENT_MODE: self.current_mode,
            m.MAVLINK_MSG_ID_SYS_STATUS: self.sys_status,
            m.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.extended_sys_state,
            m.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self.global_position_int,
            m.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS: self.actuator_output_status,
            m.MAVLINK_MSG_ID_HOME_POSITION: self.home_position,
            m.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self.autopilot_version,
            m.MAVLINK_MSG_ID_ATTITUDE: self.attitude,
            m.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self.attitude_quaternion,
            m.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.local_position_ned,
            m.MAVLINK_MSG_ID_M4_JOINT_STATE: self.joint_state,
            m.MAVLINK_MSG_ID_M4_THRUSTER_STATUS: self.thruster_status,
        }
        if esc_telemetry:
            self._builders[m.MAVLINK_MSG_ID_ESC_TELEMETRY_1_TO_4] = self.esc_telemetry_1_to_4

    def add(self, msg_id: int, build) -> None:
        """A stream built elsewhere (e.g. MISSION_CURRENT, from the FC's mission): build(snapshot)."""
        self._builders[msg_id] = build

    def can_build(self, msg_id: int) -> bool:
        return msg_id in self._builders

    def build(self, msg_id: int, snap: Snapshot) -> mavlink.MAVLink_message:
        return self._builders[msg_id](snap)

    def heartbeat(self, snap: Snapshot):
        base = modes.base_mode(snap.custom_mode, snap.armed)        # sitl/fc/modes.py
        status = mavlink.MAV_STATE_ACTIVE if snap.armed else mavlink.MAV_STATE_STANDBY
        return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC,
                                                 base, snap.custom_mode, status, 3)

    def current_mode(self, snap: Snapshot):
        return modes.current_mode(snap.custom_mode, snap.intended_mode)

    def sys_status(self, snap: Snapshot):
        """The power module's pack voltage and current; the charge left assumes a full pack at boot."""
        s, capacity = snap.state, self.airframe.battery_capacity_mah
        remaining = max(0, round(100.0 * (1.0 - s.battery_consumed_mah / capacity)))
        return mavlink.MAVLink_sys_status_message(_SENSORS, _SENSORS, _SENSORS, 0, round(1000.0 * s.battery_voltage_v),
                                                  round(100.0 * float(np.sum(s.esc_current_a))), remaining,
                                                  0, 0, 0, 0, 0, 0)

    def esc_telemetry_1_to_4(self, snap: Snapshot):
        return snap.esc.message()

    def extended_sys_state(self, snap: Snapshot):
        landed = mavlink.MAV_LANDED_STATE_ON_GROUND if snap.landed else mavlink.MAV_LANDED_STATE_IN_AIR
        return mavlink.MAVLink_extended_sys_state_message(mavlink.MAV_VTOL_STATE_MC, landed)

    def global_position_int(self, snap: Snapshot):
        s = snap.state
        lat, lon, alt = self.home.geodetic(s.pos_ned_m)
        v_cm_s = [round(100.0 * v) for v in s.vel_ned_m_s]
        hdg_cdeg = round(math.degrees(s.euler_rad[2]) * 100.0) % 36000
        return mavlink.MAVLink_global_position_int_message(
            snap.t_ms, round(lat * 1e7), round(lon * 1e7), round(alt * 1000.0),
            round(-s.pos_ned_m[2] * 1000.0), *v_cm_s, hdg_cdeg)

    def actuator_output_status(self, snap: Snapshot):
        outputs = np.zeros(32)
        n = len(snap.state.thrust_cmd_n)
        outputs[:n] = np.asarray(snap.state.thrust_cmd_n) / np.asarray(snap.state.thrust_rated_max_n)
        return mavlink.MAVLink_actuator_output_status_message(snap.t_ms * 1000, (1 << n) - 1, _f4(outputs))

    def home_position(self, snap: Snapshot):
        h = self.home
        return mavlink.MAVLink_home_position_message(
            round(h.lat_deg * 1e7), round(h.lon_deg * 1e7), round(h.alt_amsl_m * 1000.0),
            0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, snap.t_ms * 1000)

    def autopilot_version(self, snap: Snapshot):
        return mavlink.MAVLink_autopilot_version_message(_CAPABILITIES, FLIGHT_SW_VERSION, 0, 0, 0,
                                                         [0] * 8, [0] * 8, [0] * 8, 0, 0, 0)

    def attitude(self, snap: Snapshot):
        s = snap.state
        return mavlink.MAVLink_attitude_message(snap.t_ms, *_f4(s.euler_rad), *_f4(s.rates_frd_rad_s))

    def attitude_quaternion(self, snap: Snapshot):
        s = snap.state
        return mavlink.MAVLink_attitude_quaternion_message(snap.t_ms, *_f4(s.quat_wxyz), *_f4(s.rates_frd_rad_s),
                                                           [0.0, 0.0, 0.0, 0.0])

    def local_position_ned(self, snap: Snapshot):
        s = snap.state
        return mavlink.MAVLink_local_position_ned_message(snap.t_ms, *_f4(s.pos_ned_m), *_f4(s.vel_ned_m_s))

    def joint_state(self, snap: Snapshot):
        s = snap.state
        return mavlink.MAVLink_m4_joint_state_message(snap.t_ms, _f4(s.hip_rad), _f4(s.hip_rate_rad_s))

    def thruster_status(self, snap: Snapshot):
        s = snap.state
        return mavlink.MAVLink_m4_thruster_status_message(snap.t_ms, _f4(s.thrust_cmd_n), _f4(s.thrust_rated_max_n))


def statustext(severity: int, text: str) -> mavlink.MAVLink_statustext_message:
    return mavlink.MAVLink_statustext_message(severity, text.encode("ascii", "replace")[:50])
