"""ArduPilot SITL's JSON physics interface (libraries/SITL/examples/JSON/readme.md), both ways.

SITL sends a binary servo packet, little-endian `<HHI` + PWM: magic 18458 with 16 channels,
29569 with 32 (SERVO_32_ENABLE = 1), the frame rate (Hz: the time step it asks for) and a
frame count. The physics answers one JSON object on a line: timestamp (s), imu.gyro (rad/s,
body FRD), imu.accel_body (specific force, m/s^2, body FRD), position and velocity (local
NED, m and m/s), quaternion (body FRD -> NED, w x y z) and, optionally, the battery.

How the M4's outputs sit on the channels (deploy/ardupilot/m4.parm sets them so):
- channels 1..4: motors 1..4, ArduPilot's QUAD X order, which is the M4's rotor order (1
  front-right, 2 rear-left, 3 front-left, 4 rear-right). PWM 1000..2000 us (MOT_PWM_MIN/MAX)
  is the ESC's throttle 0..1, linear: the ESC drives its motor at throttle x pack voltage.
- channels 9..12: hips 1..4, PWM 1000..2000 us across the joint range (hip_min..hip_max),
  so 1500 us is the middle (45 deg, the nominal posture). A channel outside 500..2500 us
  (0: nothing assigned yet) leaves its hip where it was told last.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe

MAGIC_16 = 18458
MAGIC_32 = 29569
_HEADER = struct.Struct("<HHI")
_CHANNELS = {MAGIC_16: 16, MAGIC_32: 32}
PWM_MIN_US, PWM_MAX_US = 1000, 2000            # MOT_PWM_MIN, MOT_PWM_MAX; the hips' SERVOn_MIN, _MAX
PWM_VALID_US = (500, 2500)                     # a hip channel outside this carries no command
MOTOR_CHANNELS = tuple(range(1, ROTOR_COUNT + 1))
HIP_CHANNELS = tuple(range(9, 9 + ROTOR_COUNT))


class BadPacket(ValueError):
    """A datagram that is not a servo packet (one line naming what is wrong)."""


@dataclass(frozen=True)
class ServoPacket:
    frame_rate_hz: int
    frame_count: int
    pwm_us: tuple[int, ...]          # channel 1 first (16 or 32)

    def channel(self, n: int) -> int:
        """PWM (us) of channel n, 1-based."""
        return self.pwm_us[n - 1]


def parse_servo_packet(data: bytes) -> ServoPacket:
    if len(data) < _HEADER.size:
        raise BadPacket(f"servo packet of {len(data)} bytes, shorter than its {_HEADER.size}-byte header")
    magic, frame_rate_hz, frame_count = _HEADER.unpack_from(data)
    if magic not in _CHANNELS:
        raise BadPacket(f"servo packet magic {magic}, expected {MAGIC_16} (16 channels) or {MAGIC_32} (32)")
    size = _HEADER.size + 2 * _CHANNELS[magic]
    if len(data) != size:
        raise BadPacket(f"servo packet with magic {magic} of {len(data)} bytes, expected {size}")
    if frame_rate_hz == 0:
        raise BadPacket("servo packet with frame rate 0 Hz")
    return ServoPacket(frame_rate_hz, frame_count, struct.unpack_from(f"<{_CHANNELS[magic]}H", data, _HEADER.size))


def servo_packet(frame_rate_hz: int, frame_count: int, pwm_us) -> bytes:
    """The packet SITL sends (16 or 32 channels by the length of pwm_us): for tests and probes."""
    magic = {16: MAGIC_16, 32: MAGIC_32}[len(pwm_us)]
    return _HEADER.pack(magic, frame_rate_hz, frame_count) + struct.pack(f"<{len(pwm_us)}H", *pwm_us)


def motor_throttles(packet: ServoPacket) -> list[float]:
    """Throttle 0..1 of motors 1..4 (PWM clamped to MOT_PWM_MIN..MAX)."""
    span = PWM_MAX_US - PWM_MIN_US
    return [min(max((packet.channel(c) - PWM_MIN_US) / span, 0.0), 1.0) for c in MOTOR_CHANNELS]


def hip_goals_rad(packet: ServoPacket, af: Airframe) -> list[float]:
    """Goal angle (rad) of hips 1..4; NaN where the channel carries no command."""
    lo, hi = PWM_VALID_US
    span = PWM_MAX_US - PWM_MIN_US
    goals = []
    for c in HIP_CHANNELS:
        pwm = packet.channel(c)
        fraction = min(max((pwm - PWM_MIN_US) / span, 0.0), 1.0)
        goals.append(af.hip_min_rad + fraction * (af.hip_max_rad - af.hip_min_rad) if lo <= pwm <= hi else np.nan)
    return goals


def sensor_line(time_s: float, gyro_frd_rad_s, accel_frd_m_s2, pos_ned_m, vel_ned_m_s, quat_wxyz,
                battery_v: float, battery_a: float) -> bytes:
    """The answer to one servo packet: one JSON object and a newline."""
    def floats(v) -> list[float]:
        return [float(x) for x in v]

    return (json.dumps({"timestamp": time_s,
                        "imu": {"gyro": floats(gyro_frd_rad_s), "accel_body": floats(accel_frd_m_s2)},
                        "position": floats(pos_ned_m), "velocity": floats(vel_ned_m_s),
                        "quaternion": floats(quat_wxyz),
                        "battery": {"voltage": float(battery_v), "current": float(battery_a)}},
                       separators=(",", ":"))      # SITL's parser wants the value right after the colon
            + "\n").encode()
