"""Attitude conversions shared by the companion and the simulator (numpy only, no CasADi).

Quaternions are scalar first (w, x, y, z); Euler angles are (roll, pitch, yaw) in the ZYX
convention, R = Rz(yaw) Ry(pitch) Rx(roll), rotating body FRD into world NED.
"""

from __future__ import annotations

import math

import numpy as np


def euler_from_quat_wxyz(q) -> np.ndarray:
    """(roll, pitch, yaw), ZYX, of the rotation body FRD -> NED given by the unit quaternion q."""
    w, x, y, z = (np.asarray(q, dtype=float) / np.linalg.norm(q)).tolist()      # Python floats: cheaper
    sin_pitch = min(max(2.0 * (w * y - x * z), -1.0), 1.0)
    return np.array([math.atan2(2.0 * (w * x + y * z), w * w - x * x - y * y + z * z),
                     math.asin(sin_pitch),
                     math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)])


def quat_wxyz_from_euler(euler) -> np.ndarray:
    """Quaternion of R = Rz(yaw) Ry(pitch) Rx(roll) (body -> world), scalar first."""
    cr, sr = math.cos(euler[0] / 2), math.sin(euler[0] / 2)
    cp, sp = math.cos(euler[1] / 2), math.sin(euler[1] / 2)
    cy, sy = math.cos(euler[2] / 2), math.sin(euler[2] / 2)
    return np.array([cr * cp * cy + sr * sp * sy,
                     sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy])


def rotation_rows(cr, sr, cp, sp, cy, sy) -> list:
    """The rows of R = Rz(yaw) Ry(pitch) Rx(roll) from the cosines and sines of roll, pitch
    and yaw (any number type: numpy here, CasADi symbols in the ROM)."""
    return [[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr]]


def rotation_ned_from_frd(euler_rad) -> np.ndarray:
    """(3, 3) rotation body FRD -> NED of the ZYX Euler angles (roll, pitch, yaw)."""
    return np.array(rotation_rows(*(f(a) for a in np.asarray(euler_rad, dtype=float)[:3] for f in (np.cos, np.sin))))


def rotation_ned_from_quat_wxyz(q) -> np.ndarray:
    """(3, 3) rotation body FRD -> NED of the unit quaternion q (scalar first)."""
    w, x, y, z = (float(c) for c in q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
