"""The one place where MuJoCo's z-up frames meet the project's NED/FRD frames.

The MJCF (sitl/mjcf.py) uses world = NWU (x north, y west, z up) and body = FLU (x forward,
y left, z up). Both flips are the same rotation by pi about x, diag(1, -1, -1):
    v_ned = FLIP v_nwu,   v_frd = FLIP v_flu,   R_ned_frd = FLIP R_nwu_flu FLIP.
For a quaternion (w, x, y, z) that conjugation negates y and z. Quaternions are scalar first.
"""

from __future__ import annotations

import math

import numpy as np

FLIP = np.array([1.0, -1.0, -1.0])
_QUAT_FLIP = np.array([1.0, 1.0, -1.0, -1.0])


def flip_vector(v) -> np.ndarray:
    """NWU <-> NED, FLU <-> FRD (the flip is its own inverse)."""
    return FLIP * np.asarray(v, dtype=float)


def flip_quat_wxyz(q) -> np.ndarray:
    """Rotation FLU -> NWU as a quaternion <-> rotation FRD -> NED (its own inverse)."""
    return _QUAT_FLIP * np.asarray(q, dtype=float)


def euler_from_quat_wxyz(q) -> np.ndarray:
    """(roll, pitch, yaw), ZYX convention, of the rotation body -> world given by q."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.array([roll, pitch, yaw])


def quat_wxyz_from_euler(euler) -> np.ndarray:
    """Quaternion of R = Rz(yaw) Ry(pitch) Rx(roll) (body -> world), scalar first."""
    cr, sr = math.cos(euler[0] / 2), math.sin(euler[0] / 2)
    cp, sp = math.cos(euler[1] / 2), math.sin(euler[1] / 2)
    cy, sy = math.cos(euler[2] / 2), math.sin(euler[2] / 2)
    return np.array([cr * cp * cy + sr * sp * sy,
                     sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy])
