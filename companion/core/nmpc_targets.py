"""Offset-free targets: the attitude and thrust a hover needs under the estimated disturbance.

Offset-free MPC needs more than a disturbance in the model: the cost must not pull towards a
state and input that cannot be held. A level attitude and the nominal hover thrust cannot
be held against a steady wind or with a heavier robot, and a cost that pulls towards them
trades a small position offset for a smaller attitude and thrust error. So the roll, pitch
and thrust the cost tracks are those of the equilibrium under the disturbance estimate:
the thrust must cancel weight plus disturbance force, which fixes its size and the
direction of the body z axis; with the yaw (free, possibly spinning) extrapolated along
the horizon, that direction gives roll and pitch at every stage.
"""

from __future__ import annotations

import math

import numpy as np

from m4.airframe import ROTOR_COUNT, Airframe
from companion.core import rom

ROLL, PITCH, YAW = rom.EULER.start, rom.EULER.start + 1, rom.EULER.start + 2
YAW_RATE = rom.RATES.start + 2


def hover_targets(af: Airframe, x0: np.ndarray, x_ref: np.ndarray, d: np.ndarray, dt_s: float,
                  hip_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """(reference (N+1, 20), input reference (N, 8)) consistent with the disturbance d.

    Position, velocity, yaw and the rest come from x_ref; hips are set to hip_rad; roll and
    pitch are the equilibrium tilt; each rotor's thrust reference is a quarter of the
    equilibrium thrust (hip accelerations: 0).
    """
    horizon = x_ref.shape[0] - 1
    ref = np.array(x_ref, dtype=float)
    ref[:, rom.HIP] = hip_rad
    need = d[:3] + (0.0, 0.0, af.total_mass_kg * af.gravity_m_s2)   # what the thrust must cancel
    total = math.sqrt(need.dot(need))                                 # np.linalg.norm's own sum
    z_n, z_e, z_d = (need / total).tolist() if total > 1e-9 else (0.0, 0.0, 1.0)    # body z
    yaw = x0[YAW] + x0[YAW_RATE] * dt_s * np.arange(horizon + 1)
    c, s = np.cos(yaw), np.sin(yaw)
    along = c * z_n + s * z_e                        # body z in the yawed frame: (s_p c_r, -s_r, c_p c_r)
    across = -s * z_n + c * z_e
    ref[:, ROLL] = -np.arcsin(np.minimum(np.maximum(across, -1.0), 1.0))
    ref[:, PITCH] = np.arctan2(along, z_d)
    u_ref = np.zeros((horizon, rom.NU))
    u_ref[:, rom.THRUST] = total / ROTOR_COUNT
    return ref, u_ref
