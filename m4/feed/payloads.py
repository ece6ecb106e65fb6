"""The Zenoh feed's payloads, built from plain data: the schema a dashboard reads.

Every payload is a JSON object with `t_s` (the flight controller's clock, seconds; null
before the first telemetry) and `wall_time_unix_s` (the companion's wall clock when the
payload was built). Units and frames are in the field names; angles a person reads are in
degrees, rates the controller uses stay in rad/s. Arrays become lists; a value that is not
finite (the flight controller reports NaN for what it cannot tell) becomes null, so every
payload is strict JSON. Rotors are numbered 1..4 here, as a person reads them.

Key expressions: `m4/<vehicle>/<topic>` for the topics in TOPICS.
"""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from m4.airframe import ROTOR_COUNT

TOPICS = ("state", "setpoint", "fault", "nmpc", "link")
FAULT_STATES = ("healthy", "suspect", "confirmed")   # M4_FAULT_STATUS.state 0, 1, 2
KEY_PREFIX = "m4"

_VEHICLE_NAME = re.compile(r"[A-Za-z0-9_-]+")


def check_vehicle(vehicle: str) -> str:
    """A vehicle name usable as one chunk of a key expression (no '/', '*', '$', '#', '?')."""
    if not isinstance(vehicle, str) or not _VEHICLE_NAME.fullmatch(vehicle):
        raise ValueError(f"vehicle name must be letters, digits, '_' or '-', got {vehicle!r}")
    return vehicle


def key_for(vehicle: str, topic: str) -> str:
    """The key expression of one topic: m4/<vehicle>/<topic>."""
    if topic not in TOPICS:
        raise ValueError(f"unknown feed topic {topic!r}; topics: {', '.join(TOPICS)}")
    return f"{KEY_PREFIX}/{check_vehicle(vehicle)}/{topic}"


def state_payload(t_s: float | None, wall_time_unix_s: float, *, pos_ned_m, vel_ned_m_s,
                  euler_rad, rates_frd_rad_s, hip_rad, thrust_n) -> dict[str, Any]:
    """The estimated state: centre of mass position and velocity (NED), attitude, hips, thrusts.

    euler_rad is (roll, pitch, yaw), ZYX; thrust_n is the thrust each rotor's ESC-reported
    speed implies (k_t w^2), rotors 1..4 (null without ESC telemetry).
    """
    return {
        **_stamp(t_s, wall_time_unix_s),
        "pos_ned_m": _floats("pos_ned_m", pos_ned_m, 3),
        "vel_ned_m_s": _floats("vel_ned_m_s", vel_ned_m_s, 3),
        "euler_deg": _floats("euler_rad", euler_rad, 3, scale=math.degrees(1.0)),
        "rates_frd_rad_s": _floats("rates_frd_rad_s", rates_frd_rad_s, 3),
        "hip_deg": _floats("hip_rad", hip_rad, ROTOR_COUNT, scale=math.degrees(1.0)),
        "thrust_n": _floats("thrust_n", thrust_n, ROTOR_COUNT),
    }


def setpoint_payload(t_s: float | None, wall_time_unix_s: float, *, thrust_n, hip_rad,
                     hip_rate_rad_s, thrust_cut: bool) -> dict[str, Any]:
    """The setpoint sent to the flight controller (M4_SETPOINT); t_s is the instant it answers."""
    return {
        **_stamp(t_s, wall_time_unix_s),
        "thrust_n": _floats("thrust_n", thrust_n, ROTOR_COUNT),
        "hip_deg": _floats("hip_rad", hip_rad, ROTOR_COUNT, scale=math.degrees(1.0)),
        "hip_rate_deg_s": _floats("hip_rate_rad_s", hip_rate_rad_s, ROTOR_COUNT,
                                  scale=math.degrees(1.0)),
        "thrust_cut": _flag("thrust_cut", thrust_cut),
    }


def fault_payload(t_s: float | None, wall_time_unix_s: float, *, state: str | int, rotor: int | None,
                  thrust_max_estimate_n, message: str,
                  detected_at_s: float | None = None) -> dict[str, Any]:
    """The fault status: state, rotor 1..4 (None or 0: none), per-rotor thrust limit estimate.

    state is a name in FAULT_STATES or its M4_FAULT_STATUS number (0, 1, 2; an IntEnum such
    as the fault detector's FaultState works). `message` is the very text of the STATUSTEXT
    the companion sent ("thrust loss rotor 4"), or "" when there is nothing to say, so the
    feed and the ground station agree word for word. detected_at_s is on the t_s clock.
    """
    if rotor is not None and (isinstance(rotor, bool) or not isinstance(rotor, (int, np.integer))
                              or not 0 <= rotor <= ROTOR_COUNT):
        raise ValueError(f"fault rotor must be 1..{ROTOR_COUNT}, 0 or None, got {rotor!r}")
    if not isinstance(message, str):
        raise ValueError(f"fault message must be a string, got {message!r}")
    return {
        **_stamp(t_s, wall_time_unix_s),
        "state": _fault_state(state),
        "rotor": int(rotor) if rotor else None,
        "thrust_max_estimate_n": _floats("thrust_max_estimate_n", thrust_max_estimate_n, ROTOR_COUNT),
        "detected_at_s": _optional_float("detected_at_s", detected_at_s),
        "message": message,
    }


def nmpc_payload(t_s: float | None, wall_time_unix_s: float, *, solve_ms: float, iterations: int,
                 status: str, cost: float, ok: bool, fallback: bool, dt_s: float, altitude_first: bool = False,
                 predicted_p_ned_m, lead_s: float | None = None, overruns: int = 0,
                 rate_hz: float | None = None, disturbance_force_ned_n=None,
                 disturbance_torque_frd_n_m=None) -> dict[str, Any]:
    """One NMPC solve: time, iterations, solver status, cost, and the predicted positions.

    predicted_p_ned_m has one NED position per shooting node (k = 0..N), dt_s apart, from
    lead_ms after t_s (the state was predicted to when the setpoint acts at the FC).
    `fallback` is true when the setpoint did not come from this solve; `altitude_first` when it
    was solved with the horizontal weights scaled down (its rotors saturated); status "time_budget":
    the solve stopped iterating to keep its deadline. overruns: control steps so far that took
    longer than the control period; rate_hz: control steps in the last second.
    disturbance_force_ned_n, disturbance_torque_frd_n_m: the companion's estimate of what its
    model does not explain (wind, mass and thrust errors), handed to this solve; None: unknown.
    """
    predicted = np.asarray(predicted_p_ned_m, dtype=float)
    if predicted.ndim != 2 or predicted.shape[1] != 3:
        raise ValueError(f"predicted_p_ned_m must have shape (N + 1, 3), got {predicted.shape}")
    return {
        **_stamp(t_s, wall_time_unix_s),
        "solve_ms": _optional_float("solve_ms", solve_ms),
        "iterations": _count("iterations", iterations),
        "status": str(status),
        "cost": _optional_float("cost", cost),
        "ok": _flag("ok", ok),
        "fallback": _flag("fallback", fallback),
        "altitude_first": _flag("altitude_first", altitude_first),
        "dt_s": _optional_float("dt_s", dt_s),
        "predicted_p_ned_m": [_floats("predicted_p_ned_m", row, 3) for row in predicted],
        "lead_ms": _optional_ms("lead_s", lead_s),
        "overruns": _count("overruns", overruns),
        "rate_hz": _optional_float("rate_hz", rate_hz),
        "disturbance_force_ned_n": _optional_floats("disturbance_force_ned_n", disturbance_force_ned_n, 3),
        "disturbance_torque_frd_n_m": _optional_floats("disturbance_torque_frd_n_m", disturbance_torque_frd_n_m, 3),
    }


def link_payload(t_s: float | None, wall_time_unix_s: float, *, connected: bool,
                 last_msg_age_s: float | None, msgs_per_s: float, bad_crc: int, bad_signature: int,
                 dropped_foreign: int, feed_errors: int, setpoint_lead_s: float | None = None,
                 round_trip_s: float | None = None, control_rate_hz: float | None = None,
                 overruns: int = 0, flight_log_paused: bool = False, flight_log_gaps: int = 0,
                 stale_streams: tuple[str, ...] = ()) -> dict[str, Any]:
    """Health of the MAVLink link to the flight controller, of this feed itself and of the flight log.

    last_msg_age_s: wall-clock seconds since the last message from the flight controller
    (null before the first); dropped_foreign: packets from systems/components not ours;
    feed_errors: publications of this feed that failed (built or sent) since it opened;
    setpoint_lead_ms: how long after the telemetry instant it answers a setpoint reaches the
    flight controller (its clock; TIMESYNC), round_trip_ms: the TIMESYNC round trip on the
    companion's clock (null until measured); control_rate_hz: setpoints sent in the last
    second; overruns: control steps so far that took longer than the control period;
    flight_log_paused: the flight log cannot write (a full disk) and drops what comes until a
    new file can be written; flight_log_gaps: times it paused so far; stale_streams: the
    telemetry streams the controller needs that have stopped coming ("attitude", "position",
    "joints", "thrusters", "ESC"; while one of the first four is stale no setpoint goes out).
    """
    return {
        **_stamp(t_s, wall_time_unix_s),
        "connected": _flag("connected", connected),
        "last_msg_age_s": _optional_float("last_msg_age_s", last_msg_age_s),
        "msgs_per_s": _optional_float("msgs_per_s", msgs_per_s),
        "bad_crc": _count("bad_crc", bad_crc),
        "bad_signature": _count("bad_signature", bad_signature),
        "dropped_foreign": _count("dropped_foreign", dropped_foreign),
        "feed_errors": _count("feed_errors", feed_errors),
        "setpoint_lead_ms": _optional_ms("setpoint_lead_s", setpoint_lead_s),
        "round_trip_ms": _optional_ms("round_trip_s", round_trip_s),
        "control_rate_hz": _optional_float("control_rate_hz", control_rate_hz),
        "overruns": _count("overruns", overruns),
        "flight_log_paused": _flag("flight_log_paused", flight_log_paused),
        "flight_log_gaps": _count("flight_log_gaps", flight_log_gaps),
        "stale_streams": _names("stale_streams", stale_streams),
    }


def _names(name: str, values) -> list[str]:
    if isinstance(values, str) or not all(isinstance(v, str) for v in values):
        raise ValueError(f"{name} must be a list of names, got {values!r}")
    return list(values)


def _optional_ms(name: str, seconds) -> float | None:
    value = _optional_float(name, seconds)
    return None if value is None else 1000.0 * value


def _fault_state(state: str | int) -> str:
    if isinstance(state, str) and state in FAULT_STATES:
        return state
    if isinstance(state, (int, np.integer)) and not isinstance(state, bool) and 0 <= state < len(FAULT_STATES):
        return FAULT_STATES[int(state)]
    raise ValueError(f"fault state must be one of {', '.join(FAULT_STATES)} or 0..{len(FAULT_STATES) - 1}, "
                     f"got {state!r}")


def _stamp(t_s: float | None, wall_time_unix_s: float) -> dict[str, Any]:
    return {"t_s": _optional_float("t_s", t_s),
            "wall_time_unix_s": _optional_float("wall_time_unix_s", wall_time_unix_s)}


def _floats(name: str, value, length: int, scale: float = 1.0) -> list[float | None]:
    array = np.asarray(value, dtype=float).reshape(-1)
    if array.size != length:
        raise ValueError(f"{name} must have {length} values, got {array.size}")
    return [v * scale if math.isfinite(v) else None for v in array.tolist()]


def _optional_floats(name: str, value, length: int) -> list[float | None]:
    return [None] * length if value is None else _floats(name, value, length)


def _optional_float(name: str, value) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number or None, got {value!r}")
    return float(value) if math.isfinite(value) else None


def _count(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    return int(value)


def _flag(name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be true or false, got {value!r}")
    return bool(value)
