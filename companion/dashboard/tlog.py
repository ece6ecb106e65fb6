"""The feed a flight's tlog implies, for the dashboard to replay a flight that recorded only MAVLink.

From the flight controller (component 1): ATTITUDE, LOCAL_POSITION_NED and M4_JOINT_STATE
make a state payload at each ATTITUDE (once the others have come); its thrust is what the
newest ESC_TELEMETRY_1_TO_4's speeds imply, as the live companion publishes it
(companion.core.esc_evidence.PropellerModel; null without ESC telemetry). From the companion
(component 191): M4_SETPOINT a setpoint (the commanded thrusts and hips), M4_FAULT_STATUS a
fault, carrying the text of the companion's last STATUSTEXT once a fault is confirmed, and
the NMPC's NAMED_VALUE_FLOAT of its flight log (nmpc_ms, nmpc_iter, nmpc_cost, nmpc_ok,
nmpc_fb: companion/flight_log.py) an nmpc payload (no predicted path: the log does not hold
it). The link topic has no MAVLink message: its plot stays empty. Payloads are built by
m4.feed.payloads, so a replayed tlog and a live feed have one schema; wall_time_unix_s is
the tlog's own timestamp.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from companion.core.esc_evidence import PropellerModel
from m4.airframe import Airframe
from m4.feed.payloads import FAULT_STATES, fault_payload, key_for, nmpc_payload, setpoint_payload, state_payload
from m4.mavlink import COMPANION_COMPONENT_ID, FC_COMPONENT_ID, mavlink, mavutil

_NAN4 = [math.nan] * 4
CONFIRMED = FAULT_STATES.index("confirmed")
_STATE_PARTS = ("LOCAL_POSITION_NED", "M4_JOINT_STATE")
_NMPC_LAST = "nmpc_fb"            # the last of a decision's NMPC values in the flight log
_NO_PATH = np.zeros((0, 3))


class TlogError(ValueError):
    """A tlog that cannot be replayed (the message says which file and why)."""


def tlog_samples(path: str | Path, af: Airframe, vehicle: str = "m4") -> list[tuple[str, dict[str, Any]]]:
    """(key, payload) of the feed the tlog implies, in the tlog's order."""
    path = Path(path)
    if not path.is_file():
        raise TlogError(f"{path}: no such tlog")
    propeller = PropellerModel.from_airframe(af)
    log = mavutil.mavlink_connection(str(path))
    samples: list[tuple[str, dict[str, Any]]] = []
    latest: dict[str, Any] = {}
    decided: dict[str, float] = {}
    statustext = ""
    try:
        while (msg := log.recv_match(blocking=False)) is not None:
            kind, source, wall_s = msg.get_type(), msg.get_srcComponent(), msg._timestamp
            if source == FC_COMPONENT_ID and kind in (*_STATE_PARTS, "ESC_TELEMETRY_1_TO_4"):
                latest[kind] = msg
            elif source == FC_COMPONENT_ID and kind == "ATTITUDE" and all(k in latest for k in _STATE_PARTS):
                samples.append((key_for(vehicle, "state"), _state(msg, latest, wall_s, propeller)))
            elif source == COMPANION_COMPONENT_ID and kind == "STATUSTEXT":
                statustext = msg.text
            elif source == COMPANION_COMPONENT_ID and kind == "M4_SETPOINT":
                samples.append((key_for(vehicle, "setpoint"), setpoint_payload(
                    msg.time_boot_ms / 1000.0, wall_s, thrust_n=msg.thrust_n, hip_rad=msg.hip_angle_rad,
                    hip_rate_rad_s=msg.hip_rate_rad_s, thrust_cut=bool(msg.flags & mavlink.M4_SETPOINT_FLAG_THRUST_CUT))))
            elif source == COMPANION_COMPONENT_ID and kind == "M4_FAULT_STATUS":
                samples.append((key_for(vehicle, "fault"), fault_payload(
                    msg.time_boot_ms / 1000.0, wall_s, state=msg.state, rotor=msg.rotor,
                    thrust_max_estimate_n=msg.thrust_max_estimate_n,
                    message=statustext if msg.state == CONFIRMED else "",
                    detected_at_s=msg.detected_time_boot_ms / 1000.0 if msg.detected_time_boot_ms else None)))
            elif source == COMPANION_COMPONENT_ID and kind == "NAMED_VALUE_FLOAT":
                decided[msg.name] = msg.value
                if msg.name == _NMPC_LAST:
                    samples.append((key_for(vehicle, "nmpc"), _nmpc(msg.time_boot_ms / 1000.0, wall_s, decided)))
    finally:
        log.close()
    if not samples:
        raise TlogError(f"{path}: no flight controller state nor companion messages in it")
    return samples


def _nmpc(t_s: float, wall_s: float, decided: dict[str, float]) -> dict[str, Any]:
    ok = bool(decided.get("nmpc_ok", 0.0))
    return nmpc_payload(t_s, wall_s, solve_ms=decided.get("nmpc_ms", math.nan),
                        iterations=int(decided.get("nmpc_iter", 0)), status="logged", cost=decided.get("nmpc_cost"),
                        ok=ok, fallback=bool(decided.get(_NMPC_LAST)), dt_s=None, predicted_p_ned_m=_NO_PATH,
                        disturbance_force_ned_n=[decided.get(f"dist_{axis}", math.nan) for axis in "ned"])


def _state(attitude, latest: dict[str, Any], wall_s: float, propeller: PropellerModel) -> dict[str, Any]:
    position, joints, esc = latest["LOCAL_POSITION_NED"], latest["M4_JOINT_STATE"], latest.get("ESC_TELEMETRY_1_TO_4")
    return state_payload(
        attitude.time_boot_ms / 1000.0, wall_s,
        pos_ned_m=[position.x, position.y, position.z], vel_ned_m_s=[position.vx, position.vy, position.vz],
        euler_rad=[attitude.roll, attitude.pitch, attitude.yaw],
        rates_frd_rad_s=[attitude.rollspeed, attitude.pitchspeed, attitude.yawspeed],
        hip_rad=joints.hip_angle_rad, thrust_n=_NAN4 if esc is None else propeller.thrust_n(esc.rpm))
