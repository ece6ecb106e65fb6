"""The one place where MuJoCo's z-up frames meet the project's NED/FRD frames.

The MJCF (sitl/plant/mjcf.py) uses world = NWU (x north, y west, z up) and body = FLU (x forward,
y left, z up). Both flips are the same rotation by pi about x, diag(1, -1, -1):
    v_ned = FLIP v_nwu,   v_frd = FLIP v_flu,   R_ned_frd = FLIP R_nwu_flu FLIP.
For a quaternion (w, x, y, z) that conjugation negates y and z. Quaternions are scalar first.
"""

from __future__ import annotations

import numpy as np

FLIP = np.array([1.0, -1.0, -1.0])
_QUAT_FLIP = np.array([1.0, 1.0, -1.0, -1.0])


def flip_vector(v) -> np.ndarray:
    """NWU <-> NED, FLU <-> FRD (the flip is its own inverse)."""
    return FLIP * np.asarray(v, dtype=float)


def flip_quat_wxyz(q) -> np.ndarray:
    """Rotation FLU -> NWU as a quaternion <-> rotation FRD -> NED (its own inverse)."""
    return _QUAT_FLIP * np.asarray(q, dtype=float)


